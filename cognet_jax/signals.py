"""Stop signals: SIGINT (Ctrl-C), SIGTERM (``timeout``, schedulers) and SIGHUP (a closed
terminal or ssh session). Standard library only, so the command line installs the handlers
before JAX loads.

Outside a search loop a stop signal raises ``Stopped`` (the command ends with one line and
status ``128 + signal``); inside one (``deferred_stop``) the first signal only sets a flag, so
the driver finishes the current iteration and keeps its checkpoint and best policies, and a
second signal raises ``Stopped`` at once.
"""

from __future__ import annotations

import contextlib
import signal
import threading

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


class Stopped(KeyboardInterrupt):
    """A stop signal arrived where nothing is kept; ``signum`` is the signal."""

    def __init__(self, signum: int):
        self.signum = int(signum)
        super().__init__(signal.Signals(self.signum).name)


def _raise_stopped(signum, frame):
    raise Stopped(signum)


def install_stop_handlers() -> None:
    """Every stop signal raises ``Stopped`` (main thread only; the command line calls it)."""
    if threading.current_thread() is threading.main_thread():
        for sig in STOP_SIGNALS:
            signal.signal(sig, _raise_stopped)


@contextlib.contextmanager
def deferred_stop():
    """Inside the block the first stop signal only sets ``flag["signum"]``; a second one
    raises ``Stopped``. The previous handlers are restored after it. No-op outside the main
    thread."""
    flag: dict[str, int | None] = {"signum": None}
    if threading.current_thread() is not threading.main_thread():
        yield flag
        return

    def handler(signum, frame):
        flag["signum"] = int(signum)
        for sig in STOP_SIGNALS:
            signal.signal(sig, _raise_stopped)

    previous = {sig: signal.signal(sig, handler) for sig in STOP_SIGNALS}
    try:
        yield flag
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)
