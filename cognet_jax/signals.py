"""Stop signals: SIGINT (Ctrl-C), SIGTERM (``timeout``, schedulers) and SIGHUP (a closed
terminal or ssh session), except those the process was started ignoring (``nohup``). Standard
library only, so the command line installs the handlers before JAX loads.

Outside a search loop a stop signal raises ``Stopped`` (the command ends with one line and
status ``128 + signal``); inside one (``deferred_stop``) the first signal only sets a flag, so
the driver finishes the current iteration and keeps its checkpoint and best policies, and a
second signal raises ``Stopped`` at once.

A signal repeated within ``REPEAT_S`` of the one before is the same stop, not a second one:
``timeout`` sends its signal to the command and then to the command's process group (so the
command receives it twice), as do process managers that signal a whole group. Only a signal
that comes later (a second Ctrl-C) cuts the stop short.
"""

from __future__ import annotations

import contextlib
import queue
import signal
import threading
import time

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
#: a stop signal this soon after the one before repeats it (seconds)
REPEAT_S = 1.0
_last_stop = {"time": -float("inf"), "signum": None}


def _fresh(signum: int | None = None) -> bool:
    """Whether a stop signal arriving now is a new one (not a repeat within ``REPEAT_S``); a
    new one is remembered."""
    now = time.monotonic()
    if now - _last_stop["time"] <= REPEAT_S:
        return False
    _last_stop["time"] = now
    _last_stop["signum"] = signum
    return True


def stop_received() -> int | None:
    """The last stop signal this process received, or None. A ``Stopped`` raised while the
    main thread was inside a compiled call reaches the caller as that library's own error
    (JAX: "Error dispatching computation"); the command line reads this to report the stop
    as a stop."""
    return _last_stop["signum"]


def _heeded() -> list:
    """The stop signals this process heeds: not those it was started ignoring (``nohup``
    ignores SIGHUP; a shell's background job ignores SIGINT)."""
    return [sig for sig in STOP_SIGNALS if signal.getsignal(sig) is not signal.SIG_IGN]


class Stopped(KeyboardInterrupt):
    """A stop signal arrived where nothing is kept; ``signum`` is the signal, ``after`` what
    was done before it was heeded (e.g. "the run's results were written"), said with it."""

    def __init__(self, signum: int, after: str = ""):
        self.signum, self.after = int(signum), after
        name = signal.Signals(self.signum).name
        super().__init__(f"{name} after {after}" if after else name)


def heed_while_starting() -> None:
    """The executable's first step, before JAX's seconds of import: until
    ``install_stop_handlers`` a stop signal ends the process at once, with one line and status
    ``128 + signal`` (nothing has started that could be kept)."""
    if threading.current_thread() is not threading.main_thread():
        return

    def handler(signum, frame):
        import os
        import sys

        with contextlib.suppress(OSError, ValueError):
            name = signal.Signals(signum).name
            print(f"error: stopped by {name} while starting", file=sys.stderr, flush=True)
        os._exit(128 + int(signum))

    for sig in _heeded():
        signal.signal(sig, handler)


def _raise_stopped(signum, frame):
    if _fresh(signum):
        _start_deadline(signum)
        raise Stopped(signum)


#: seconds after a stop signal by which the executable has ended (``arm_stop_deadline``): a
#: ``Stopped`` raised where Python swallows exceptions (inside a garbage-collection callback,
#: which prints it as "Exception ignored" and runs on) would otherwise lose the stop
STOP_DEADLINE_S = 9.0
_DEADLINE: dict = {"armed": False, "timer": None}


def arm_stop_deadline() -> None:
    """From now on a stop signal that raises ``Stopped`` also starts a timer that ends the
    process ``STOP_DEADLINE_S`` later, with one line and status ``128 + signal``, if it is
    still running then. The executable's (``cli.run``); a program that uses the library
    handles its stops itself."""
    _DEADLINE["armed"] = True


def _start_deadline(signum: int) -> None:
    if not _DEADLINE["armed"] or _DEADLINE["timer"] is not None:
        return

    def end():
        import os
        import sys

        with contextlib.suppress(OSError, ValueError):
            name = signal.Signals(signum).name
            print(f"error: stopped by {name}", file=sys.stderr, flush=True)
        os._exit(128 + int(signum))

    timer = threading.Timer(STOP_DEADLINE_S, end)
    timer.daemon = True
    timer.start()
    _DEADLINE["timer"] = timer


#: the stop signals heeded when the handlers were installed (before any ``--import``)
_INSTALLED: list = []


def install_stop_handlers() -> None:
    """Every stop signal raises ``Stopped`` (main thread only; the command line calls it, once
    per command: no stop received yet)."""
    _last_stop["signum"] = None
    if threading.current_thread() is threading.main_thread():
        _INSTALLED[:] = _heeded()
        for sig in _INSTALLED:
            signal.signal(sig, _raise_stopped)


def restore_stop_handlers() -> list[str]:
    """Install ``Stopped`` again on the signals ``install_stop_handlers`` took, where code run
    since (an ``--import`` module) replaced or ignored it; returns those signals' names."""
    if threading.current_thread() is not threading.main_thread():
        return []
    changed = [sig for sig in _INSTALLED if signal.getsignal(sig) is not _raise_stopped]
    for sig in changed:
        signal.signal(sig, _raise_stopped)
    return [signal.Signals(sig).name for sig in changed]


def exit_on_stop() -> None:
    """Once a command's work is done: a stop signal ends the process at once, status ``128 +
    signal``, with one line saying the command had finished (raising ``Stopped`` then could
    only land in the interpreter's shutdown or in a callback that prints it as an ignored
    exception)."""
    if threading.current_thread() is not threading.main_thread():
        return

    def handler(signum, frame):
        import os
        import sys

        with contextlib.suppress(OSError, ValueError):
            sys.stdout.flush()
        with contextlib.suppress(OSError, ValueError):
            name = signal.Signals(signum).name
            print(
                f"error: stopped by {name} after the command finished (its output is complete)",
                file=sys.stderr,
                flush=True,
            )
        os._exit(128 + int(signum))

    for sig in _heeded():
        signal.signal(sig, handler)


@contextlib.contextmanager
def deferred_stop():
    """Inside the block the first stop signal only sets ``flag["signum"]``; a second one
    raises ``Stopped``. The previous handlers are restored after it. No-op outside the main
    thread."""
    flag: dict[str, int | None] = {"signum": None}
    if threading.current_thread() is not threading.main_thread():
        yield flag
        return

    heeded = _heeded()

    def handler(signum, frame):
        if not _fresh(signum):
            return
        flag["signum"] = int(signum)
        for sig in heeded:
            signal.signal(sig, _raise_stopped)

    previous = {sig: signal.signal(sig, handler) for sig in heeded}
    try:
        yield flag
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)


def in_background(fn, poll: float = 0.05):
    """``fn()`` run in a worker thread while the main thread waits in short steps, so that a
    stop signal is handled at once (a compile or a long compiled call holds the main thread
    for as long as it runs otherwise); returns its value or raises its exception. On a stop
    the worker is left running: the command exits without waiting for it
    (``cli.run``)."""
    if threading.current_thread() is not threading.main_thread():
        return fn()
    box: dict = {}

    def target():
        try:
            box["value"] = fn()
        except BaseException as err:  # handed to the main thread
            box["error"] = err

    worker = threading.Thread(target=target, daemon=True)
    worker.start()
    while worker.is_alive():
        worker.join(poll)
    if "error" in box:
        raise box["error"]
    return box["value"]


#: how often a wait (``wait_for``) looks at the stop flag and its timeout (seconds)
POLL_S = 0.05


class _Waiter:
    """One daemon thread that runs blocking calls (``block(arg)``) handed to it in order and
    marks each done, so that the main thread can wait on an event instead of blocking: an event
    wait lets signal handlers run, a blocking call into a C extension does not."""

    def __init__(self):
        self.jobs: queue.SimpleQueue = queue.SimpleQueue()
        self.thread: threading.Thread | None = None

    def _serve(self):
        while True:
            block, arg, done = self.jobs.get()
            try:
                block(arg)
            except BaseException:  # the caller sees the error when it uses the result
                pass
            done.set()

    def wait(self, block, arg, flag=None, timeout: float | None = None) -> bool:
        if self.thread is None:
            self.thread = threading.Thread(target=self._serve, daemon=True)
            self.thread.start()
        done = threading.Event()
        self.jobs.put((block, arg, done))
        t0 = time.monotonic()
        while not done.wait(POLL_S):
            if flag is not None and flag["signum"] is not None:
                return False
            if timeout is not None and time.monotonic() - t0 > timeout:
                return False
        return True


_WAITER = _Waiter()


def wait_for(block, arg, flag=None, timeout: float | None = None) -> bool:
    """``block(arg)`` (e.g. ``jax.block_until_ready``) run in a waiter thread while this thread
    waits on an event: ``True`` once it returned, ``False`` when ``flag["signum"]`` is set (a
    stop signal, seen within ``POLL_S``) or ``timeout`` seconds pass first. Calls run one after
    the other, in the order given."""
    return _WAITER.wait(block, arg, flag, timeout)
