"""Claiming a run folder for one writer: nothing a user ran before is lost.

``claim(out, resume=..., overwrite=...)`` is what ``cognet-jax train`` and ``sweep`` hold while
they write ``out``:

* ``out`` must name a folder (``--out ''`` is refused: it would write into the working folder);
* a folder that already holds a run (``results.json``, ``runs.json`` or a checkpoint) is
  refused unless the command continues it (``--resume``) or replaces it (``--overwrite``);
* an exclusive lock (``flock`` on ``out/.lock``, released by the kernel when the process ends,
  however it ends) makes a second writer of the same folder fail at once, naming the process
  that holds it;
* creating the lock file checks that the folder can be written before the search starts.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

from cognet_jax.errors import UsageError

#: files whose presence means the folder holds a run (single run, sweep, or a stopped one)
RUN_FILES = ("results.json", "runs.json", "checkpoint.msgpack", "sweep.json")
#: of those, the files (and non-empty folders) of a sweep's folder; the others are a ``train``'s
SWEEP_FILES = ("runs.json", "sweep.json", "runs", "sweep-state")
LOCK_NAME = ".lock"


def check_out(out: str | None) -> None:
    """Refuse an empty ``--out`` (it would write into the current folder)."""
    if out is not None and not str(out).strip():
        raise UsageError("--out '': give a folder name (the run's files go into that folder)")


def held_run(out: Path) -> str | None:
    """The first of ``RUN_FILES`` present in ``out`` as a file, or a sweep's folder
    (``sweep-state/`` not empty, ``runs/`` holding ``setting*`` run folders); None when there
    is none."""
    found = next((n for n in RUN_FILES if (out / n).is_file()), None)
    if found is None and (out / "sweep-state").is_dir() and any((out / "sweep-state").iterdir()):
        found = "sweep-state"
    if found is None and (out / "runs").is_dir() and any((out / "runs").glob("setting*")):
        found = "runs"  # a sweep's run folders (``runs/settingS-seedN``)
    return found


@contextlib.contextmanager
def claim(out: Path, *, resume: bool = False, overwrite: bool = False, kind: str = "train"):
    """Hold ``out`` for this process while the block runs (see the module docstring);
    ``kind``: the command that writes it, ``"train"`` or ``"sweep"`` (a folder of the other
    kind cannot be continued by it)."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {out}: exists and is not a folder")
    found = held_run(out) if out.is_dir() else None
    if found and not resume and not overwrite:
        other = "sweep" if found in SWEEP_FILES else "train"
        if other == kind and found != "runs":
            advice = f"continue it with --resume {out}, or replace it with --overwrite"
        else:
            advice = f"`{kind}` cannot continue it: give another --out, or "
            advice += "replace it with --overwrite"
            if other == kind:  # run folders without a sweep's state: nothing to resume
                advice = "no sweep state to resume: give another --out, or replace it with "
                advice += "--overwrite"
        raise UsageError(f"{out} already holds a run of `{other}` ({found}); {advice}")
    for name in (*RUN_FILES, "policy.msgpack"):
        if (out / name).is_dir():
            raise UsageError(f"{out / name} is a folder; the run writes a file of that name")
    try:
        out.mkdir(parents=True, exist_ok=True)
        fd = os.open(out / LOCK_NAME, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as err:
        raise UsageError(f"{out}: cannot write there ({err.strerror})") from None
    try:
        _lock(fd, out)
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        yield out
    finally:
        os.close(fd)  # releases the lock


def _lock(fd: int, out: Path) -> None:
    """Exclusive, non-blocking ``flock`` on ``fd``; ``UsageError`` naming the holder's pid."""
    try:
        import fcntl
    except ImportError:  # not a POSIX system: no lock
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
        raise UsageError(
            f"{out} is being written by another cognet-jax process (pid {holder}); wait for "
            "it or choose another --out"
        ) from None
