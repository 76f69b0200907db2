"""``--import``: a user's module (a simulator or algorithm registered from outside the package)
imported with its failures named -- an error with its file and line, an exit, a hang -- and
recorded as foreign code (``registry.note_foreign_code``). Also the one-line form of an error."""

from __future__ import annotations

import contextlib
import functools
import importlib
import importlib.util
import math
import os
import select
import signal
import site
import sys
import threading
import traceback
from pathlib import Path

from cognet_jax.errors import UsageError
from cognet_jax.registry import LATE_IMPORTS, note_foreign_code


def one_line(err: BaseException) -> str:
    """The message of a user-facing error on one line."""
    if isinstance(err, OSError) and err.strerror:
        where = err.filename if err.filename is not None else ""
        text = f"{where}: {err.strerror}" if where else err.strerror
    else:
        text = str(err) or type(err).__name__
    return " ".join(text.split())


def where_raised(err: BaseException, path: str | None) -> str:
    """``file:line`` of the user module's line that raised ``err`` (the last frame in
    ``path``, or the last frame at all)."""
    if isinstance(err, SyntaxError):
        return f"{err.filename}:{err.lineno}"
    frames = traceback.extract_tb(err.__traceback__)
    own = [f for f in frames if path and Path(f.filename).resolve() == Path(path).resolve()]
    frame = (own or frames or [None])[-1]
    return f"{frame.filename}:{frame.lineno}" if frame else "?"


#: seconds an ``--import`` module may take to import (``COGNET_JAX_IMPORT_TIMEOUT`` sets
#: another); a module still importing then is reported as hanging
IMPORT_TIMEOUT_S = 120.0
#: seconds after that time when a watchdog thread ends the process (a module ignoring SIGALRM)
IMPORT_GRACE_S = 5.0


class _ImportEnded(BaseException):
    """Raised inside an ``--import`` module's import: it called ``os._exit`` or ran out of
    time (``IMPORT_TIMEOUT_S``). A ``BaseException``, so the module's own ``except
    Exception`` does not swallow it."""


def _end_process(line: str, code: int, real_exit) -> None:
    """Print ``line`` on stderr and end the process at once with ``real_exit`` (the real
    ``os._exit``: no code of the module importing now can catch it)."""
    try:
        print(line, file=sys.stderr, flush=True)
    finally:
        real_exit(code)


def _import_timeout() -> float:
    """``COGNET_JAX_IMPORT_TIMEOUT`` (seconds, > 0), or ``IMPORT_TIMEOUT_S``; ``UsageError``
    naming the variable for any other value."""
    text = os.environ.get("COGNET_JAX_IMPORT_TIMEOUT")
    if text is None:
        return IMPORT_TIMEOUT_S
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not (math.isfinite(value) and 0 < value <= 1e6):
        raise UsageError(
            f"COGNET_JAX_IMPORT_TIMEOUT={text!r}: seconds an --import may take, in (0, 1e6]"
        )
    return value


class _StopWatcher:
    """While an import runs in the main thread: a thread that sees stop signals as they
    arrive (``signal.set_wakeup_fd``) and runs ``stop`` itself when ``stop`` is still their
    handler. A Python handler runs only between the main thread's bytecodes, so a module
    inside one long compiled call (a large matmul at import) would otherwise hold a stop
    for as long as that call runs."""

    def __init__(self, stop, real_exit):
        self.stop, self.closed = stop, threading.Event()
        self.read_fd, write_fd = os.pipe()
        os.set_blocking(write_fd, False)
        self.write_fd = write_fd
        self.previous = signal.set_wakeup_fd(write_fd, warn_on_full_buffer=False)
        self.thread = threading.Thread(target=self._watch, daemon=True)
        self.thread.start()

    def _watch(self) -> None:
        while not self.closed.is_set():
            ready, _, _ = select.select([self.read_fd], [], [], 0.1)
            if not ready or self.closed.is_set():
                continue
            for signum in os.read(self.read_fd, 64):
                if signum in STOP_NUMBERS and signal.getsignal(signum) is self.stop:
                    self.stop(signum, None)  # ends the process

    def close(self) -> None:
        self.closed.set()
        signal.set_wakeup_fd(self.previous)
        self.thread.join(1.0)
        os.close(self.write_fd)
        os.close(self.read_fd)


#: the stop signals' numbers (``_StopWatcher``)
STOP_NUMBERS = (int(signal.SIGINT), int(signal.SIGTERM), int(signal.SIGHUP))


@contextlib.contextmanager
def _guarded_import(name: str):
    """While a module imports: ``os._exit(n)`` raises instead of ending the process, and an
    alarm ends an import that takes longer than ``IMPORT_TIMEOUT_S`` (main thread only)."""
    timeout = _import_timeout()
    real_exit, pid, importer = os._exit, os.getpid(), threading.current_thread()

    def exit_instead(code=0):
        if os.getpid() != pid or threading.current_thread() is not importer:
            real_exit(code)  # a process the module forked, or a thread of its own
        raise _ImportEnded(f"--import {name} exited with status {code}")

    said = f"--import {name}: still importing after {timeout:g} s (a hang?)"
    alarms = []

    def out_of_time(signum, frame):
        alarms.append(signum)
        if len(alarms) > 1:  # the module swallowed the first: end here, from outside it
            _end_process(f"error: {said}", 2, real_exit)
        raise _ImportEnded(said)

    def stop(signum, frame):  # a module's code may swallow any exception a handler raises
        said_stop = f"error: stopped by {signal.Signals(signum).name} while importing {name}"
        _end_process(said_stop, 128 + signum, real_exit)

    main = importer is threading.main_thread()
    previous = signal.signal(signal.SIGALRM, out_of_time) if main else None
    stops = {}
    if main:
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
            if signal.getsignal(sig) not in (signal.SIG_IGN, None):
                stops[sig] = signal.signal(sig, stop)
    os._exit = exit_instead
    watcher = _StopWatcher(stop, real_exit) if stops else None
    # the last resort, which no module can turn off (it may ignore SIGALRM): a thread that
    # ends the process a little after the alarm's time
    watchdog = threading.Timer(
        timeout + IMPORT_GRACE_S, _end_process, (f"error: {said}", 2, real_exit)
    )
    watchdog.daemon = True
    if main:  # (as the alarm: an import in another thread is the host program's to time)
        watchdog.start()
    try:
        if main:  # repeats, so a module that catches the first alarm meets the next one
            signal.setitimer(signal.ITIMER_REAL, timeout, 1.0)
        yield
    finally:
        watchdog.cancel()
        if watcher is not None:
            watcher.close()
        os._exit = real_exit
        if main:
            try:
                signal.setitimer(signal.ITIMER_REAL, 0)
            finally:
                if previous is not None:
                    signal.signal(signal.SIGALRM, previous)
                for sig, handler in stops.items():
                    if signal.getsignal(sig) is stop:  # not replaced by the module itself
                        signal.signal(sig, handler)


def import_plugin(name: str) -> None:
    """Import a module by name, or a ``.py`` file by path (``--import``); an error of the
    module itself is a ``UsageError`` naming its file and line, and so is a module that exits
    (``sys.exit``, ``os._exit``) or hangs at import (``_guarded_import``)."""
    if not name or (name.startswith(".") and not name.endswith(".py")):  # ``.mod``: relative
        raise UsageError(f"--import {name!r}: give a module name or a .py file")
    path = Path(name)
    origin = str(path) if name.endswith(".py") else None
    try:
        if origin is None:  # a module name: its file, where its errors are looked for
            spec = importlib.util.find_spec(name)
            if spec is None:
                raise UsageError(f"--import {name}: no module of that name")
            origin = spec.origin
            path = Path(origin or name)
        before = set(sys.modules)
        if not LATE_IMPORTS:  # the modules a user module imports later are its helpers too
            LATE_IMPORTS.append(functools.partial(_note_helpers, frozenset(before)))
        limit = sys.getrecursionlimit()
        with _guarded_import(name):
            _import(name, path, origin if name.endswith(".py") else None)
        if sys.getrecursionlimit() < limit:  # JAX's tracing recurses deeper than a few dozen
            lowered = sys.getrecursionlimit()
            sys.setrecursionlimit(limit)
            raise UsageError(
                f"--import {name} lowered Python's recursion limit to {lowered} (it was "
                f"{limit}): tracing a search needs the deeper stack; leave "
                "sys.setrecursionlimit as it is"
            )
        note_foreign_code(name, origin)
        for helper, file in _user_modules(set(sys.modules) - before, origin):
            note_foreign_code(helper, file)  # its helpers change its numbers too
        if origin:
            _ORIGINS[str(Path(origin).resolve())] = name
    except UsageError:
        raise
    except _ImportEnded as err:
        raise UsageError(str(err)) from None
    except SystemExit as err:  # sys.exit() in the module's top level
        raise UsageError(f"--import {name} exited with status {err.code}") from None
    except KeyboardInterrupt as err:
        if type(err) is not KeyboardInterrupt:  # a stop signal (``signals.Stopped``)
            raise
        raise UsageError(f"--import {name} raised KeyboardInterrupt") from None
    except (ModuleNotFoundError, ValueError) as err:
        raise UsageError(f"--import {name}: {err}") from None
    except Exception as err:  # the module's own error: where, what
        raise UsageError(
            f"--import {name}: {where_raised(err, origin)}: {type(err).__name__}: {one_line(err)}"
        ) from None


#: resolved file of every ``--import`` module -> the name it was given by
_ORIGINS: dict[str, str] = {}


def user_code_error(err: BaseException) -> str | None:
    """The one-line report of ``err`` when it was raised in the code of an ``--import``
    module (a simulator's or algorithm's function, while tracing or running it): whose code,
    which function, where, and the error (JAX's message names the shapes or dtypes it
    expected and got); ``None`` when no frame of such a module is in its traceback."""
    frames = traceback.extract_tb(err.__traceback__)
    own = [f for f in frames if str(Path(f.filename).resolve()) in _ORIGINS]
    if not own:
        return None
    frame = own[-1]
    module = _ORIGINS[str(Path(frame.filename).resolve())]
    return (
        f"the code of --import {module} failed in {frame.name}() at {frame.filename}:"
        f"{frame.lineno}: {type(err).__name__}: {one_line(err)}"
    )


def _import(name: str, path: Path, origin: str | None) -> None:
    """Import the module ``name`` (a ``.py`` file when ``origin`` is its path)."""
    if origin is not None:
        if not path.is_file():
            what = "not a regular file" if path.exists() else "no such file"
            raise UsageError(f"--import {name}: {what}")
        module_name = _module_name(path)
        spec = importlib.util.spec_from_file_location(module_name, path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[module_name] = module
        spec.loader.exec_module(module)
    else:
        importlib.import_module(name)


def _module_name(path: Path) -> str:
    """The name a ``.py`` file is imported under: its stem, unless that names another module
    (a standard-library one such as ``json``, one already imported from elsewhere, or an
    installed one not imported yet, such as ``matplotlib``), which the file must not replace
    for the rest of the process: then ``cognet_import_<stem>``."""
    stem = path.stem
    other = sys.modules.get(stem)
    if other is not None and Path(getattr(other, "__file__", "") or "").resolve() == path.resolve():
        return stem  # the same file again
    if other is not None or stem in sys.stdlib_module_names or _installed(stem, path):
        return f"cognet_import_{stem}"
    return stem


def _installed(name: str, path: Path) -> bool:
    """Whether another file than ``path`` is importable as the top-level module ``name``."""
    try:
        spec = importlib.util.find_spec(name)
    except (ImportError, ValueError):
        return False
    found = getattr(spec, "origin", None) or ""
    return spec is not None and Path(found).resolve() != path.resolve()


def _note_helpers(before: frozenset) -> None:
    """Note every user module loaded since the first ``--import`` (``before``: the modules
    loaded then) as foreign code, with its digest now."""
    for helper, file in _user_modules(set(sys.modules) - before, None):
        note_foreign_code(helper, file, late=True)


def _user_modules(names, origin: str | None) -> list[tuple[str, str]]:
    """``(name, file)`` of the modules of ``names`` loaded from a ``.py`` file outside the
    Python installation and this package (a user's helper modules), ``origin`` aside."""
    roots = [sys.prefix, sys.base_prefix, sys.exec_prefix, *site.getsitepackages()]
    installed = {Path(p).resolve() for p in [*roots, site.getusersitepackages()]}
    package = Path(__file__).resolve().parent
    skip = Path(origin).resolve() if origin else None
    found = []
    for name in sorted(names):
        file = getattr(sys.modules.get(name), "__file__", None)
        if not file or not file.endswith(".py"):
            continue
        path = Path(file).resolve()
        inside = [package, *installed]
        if path == skip or any(path.is_relative_to(root) for root in inside):
            continue
        if {"site-packages", "dist-packages"} & set(path.parts):  # installed elsewhere
            continue
        found.append((name, str(path)))
    return found
