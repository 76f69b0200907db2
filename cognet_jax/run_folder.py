"""Claiming a run folder for one writer: nothing a user ran before is lost.

``claim(out, resume=..., overwrite=...)`` is what ``cognet-jax train`` and ``sweep`` hold while
they write ``out``:

* ``out`` must name a folder (``--out ''`` is refused: it would write into the working folder);
* a folder that already holds a run (``results.json``, ``runs.json``, a checkpoint or a
  policy) is refused unless the command continues it (``--resume``) or replaces it
  (``--overwrite``: once the new run has finished, what the replaced run left and the new one
  did not write again -- ``STALE_FILES``, its policy and checkpoint, a sweep's earlier run
  folders -- is removed; a stop before then leaves the old run's results as they were, and
  ``REPLACING_NAME`` says that the checkpoint beside them is the new run's, for ``--resume``);
* an exclusive lock (``flock`` on ``out/.lock``, released by the kernel when the process ends,
  however it ends) makes a second writer of the same folder fail at once, naming the process
  that holds it;
* the lock file is a regular file of the folder (never followed through a link), and a probe
  file created and removed there checks that the folder can be written before the search
  starts.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
from pathlib import Path

from cognet_jax.errors import UsageError

#: files whose presence means the folder holds a run (single run, sweep, or a stopped one)
RUN_FILES = ("results.json", "runs.json", "checkpoint.msgpack", "sweep.json", "policy.msgpack")
#: of those, the files (and non-empty folders) of a sweep's folder; the others are a ``train``'s
SWEEP_FILES = ("runs.json", "sweep.json", "runs", "sweep-state")
LOCK_NAME = ".lock"
#: written while ``--overwrite`` replaces a run (removed when the new run finishes): a
#: checkpoint of another run beside the old results.json is then the new run's, to resume
REPLACING_NAME = ".replacing"
#: files of a replaced run (``--overwrite``) that describe it and that a new run may not write
STALE_FILES = ("evaluations.jsonl", "results.json", "runs.json", "runs.csv", "summary.md")


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
        sweep_of = sweep_holding(out)
        if sweep_of is not None:  # a run folder of a sweep: the sweep continues it
            advice = f"a run of the sweep in {sweep_of}: continue it with `sweep --resume "
            advice += f"{sweep_of}`, or replace this run with --overwrite"
        elif other == kind and found not in ("runs", "policy.msgpack"):
            advice = f"continue it with --resume {out}, or replace it with --overwrite"
        else:
            advice = f"`{kind}` cannot continue it: give another --out, or "
            advice += "replace it with --overwrite"
            if other == kind:  # run folders without a sweep's state, a lone policy
                missing = "sweep state" if found == "runs" else "checkpoint"
                advice = f"no {missing} to resume: give another --out, or replace it with "
                advice += "--overwrite"
        raise UsageError(f"{out} already holds a run of `{other}` ({found}); {advice}")
    if not found and not overwrite and out.is_dir():
        theirs = _files_a_run_writes(out)
        if theirs:
            raise UsageError(
                f"{out} holds no run but files a run writes ({', '.join(theirs[:3])}): give "
                "another --out, or replace them with --overwrite"
            )
    for name in RUN_FILES:
        if (out / name).is_dir():
            raise UsageError(f"{out / name} is a folder; the run writes a file of that name")
    lock = _checked_lock_file(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
        fd = _open_lock(lock)
    except OSError as err:
        raise UsageError(f"{out}: cannot write there ({_why_not(out, err)})") from None
    try:
        _lock(fd, out)
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        _check_writable(out)
        _refuse_linked_runs(out)
        for sub in ("runs", "sweep-state"):  # a sweep's folders, where they are already
            if (out / sub).is_dir():
                _check_writable(out / sub)
        replaced = _replaced_files(out, kind) if found and overwrite else {}
        if resume and (out / REPLACING_NAME).exists():  # continues a replacing run: the old
            replaced = _recorded_replaced(out, kind)  # run's files go when it finishes
        if replaced and not resume:  # what is replaced, for a --resume after a stop
            record = {str(p.relative_to(out)): m for p, m in replaced.items()}
            (out / REPLACING_NAME).write_text(json.dumps(record))
        try:
            yield out
        except BaseException:
            if replaced and not _new_state_written(out, replaced):
                (out / REPLACING_NAME).unlink(missing_ok=True)  # stopped before a checkpoint
            raise
        _remove_unwritten(replaced)  # the block finished: what it did not write again is stale
        (out / REPLACING_NAME).unlink(missing_ok=True)  # a replacing run (or its resume) ended
    finally:
        os.close(fd)  # releases the lock


def _files_a_run_writes(out: Path) -> list[str]:
    """The names in ``out`` a run would write over: its tables (``STALE_FILES``) and figures
    (``*.png``: every search draws its own), sorted."""
    try:
        names = [p.name for p in out.iterdir() if p.is_file()]
    except OSError:
        return []
    return sorted(n for n in names if n in STALE_FILES or n.endswith(".png"))


def worth_keeping(out: Path) -> bool:
    """Whether a failed command left something in ``out`` to continue or read: results, a
    checkpoint, a sweep's group checkpoint, finished group or run (a sweep's spec alone,
    written before it compiles, is not)."""
    if any((out / k).exists() for k in ("results.json", "checkpoint.msgpack", "runs.json")):
        return True
    state = out / "sweep-state"
    if any(state.glob("*.checkpoint.msgpack")) or any(state.glob("*.rows.json")):
        return True
    return any((out / "runs").glob("setting*/results.json"))


def sweep_holding(out: Path) -> Path | None:
    """The sweep folder whose run folder ``out`` is (``SWEEP/runs/settingS-seedN`` beside the
    sweep's state), or None."""
    sweep = out.parent.parent
    if out.parent.name == "runs" and out.name.startswith("setting"):
        if (sweep / "sweep-state").is_dir() or (sweep / "runs.json").is_file():
            return sweep
    return None


def _why_not(out: Path, err: OSError) -> str:
    """Why ``out`` cannot be made or written, in words: a symbolic link that leads nowhere is
    named as one (its error is "File exists", which misleads)."""
    if out.is_symlink():
        try:
            out.resolve(strict=True)
        except (OSError, RuntimeError):  # RuntimeError: a loop, before Python 3.13
            return "a symbolic link that leads nowhere: a loop, or a target that does not exist"
    return err.strerror or str(err)


def _check_writable(out: Path) -> None:
    """``UsageError`` unless a file can be created and removed in ``out`` (the run's files are
    written as new files renamed into place)."""
    probe = out / f".write-check-{os.getpid()}"
    try:
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as err:
        raise UsageError(f"{out}: cannot write there ({err.strerror})") from None


def _refuse_linked_runs(out: Path) -> None:
    """``UsageError`` for a sweep's run folder that is a symbolic link: the sweep writes its
    run folders itself, and writing through a link would replace files outside ``out``."""
    for sub in ("runs", "sweep-state"):
        if (out / sub).is_symlink():
            raise UsageError(
                f"{out / sub} is a symbolic link (to {os.readlink(out / sub)}); a sweep writes "
                "its folders itself: remove the link"
            )
    for path in sorted((out / "runs").glob("setting*")) if (out / "runs").is_dir() else []:
        if path.is_symlink():
            raise UsageError(
                f"{path} is a symbolic link (to {os.readlink(path)}); a sweep writes its run "
                "folders itself: remove the link"
            )


def _replaced_files(out: Path, kind: str) -> dict[Path, float]:
    """The files and run folders describing the run ``--overwrite`` replaces
    (``STALE_FILES``, its policy and checkpoint, a sweep's ``runs/setting*`` and group states),
    with their modification times."""
    paths = [out / n for n in (*STALE_FILES, "policy.msgpack", "checkpoint.msgpack")]
    # its figures: a run that writes none (or fails to) leaves none of the old run's behind
    paths += [p for p in sorted(out.glob("*.png")) if p.is_file() and not p.is_symlink()]
    # a sweep's run folders and state, whatever replaces it: a `train` written over a sweep
    # leaves no sweep for `sweep --resume` to continue over the new run
    # (a run folder: one that holds a run's files; a folder of the user's own there stays)
    paths += [p for p in sorted((out / "runs").glob("setting*")) if held_run(p)]
    paths += sorted((out / "sweep-state").glob("group*"))
    if kind != "sweep":
        paths += [out / "sweep-state", out / "runs"]
    return {p: _mtime(p) for p in paths if p.exists()}


def _recorded_replaced(out: Path, kind: str) -> dict[Path, float]:
    """The replaced run's files as ``REPLACING_NAME`` recorded them when ``--overwrite``
    started, those still as they were (the stopped new run's own files -- a sweep's group
    states and run folders, a checkpoint -- are not among them, so they stay). A record of
    an earlier version (the process id alone): the replaced files found now, but the
    checkpoint."""
    text = (out / REPLACING_NAME).read_text()
    try:
        record = json.loads(text)
    except ValueError:
        record = None
    if not isinstance(record, dict):
        replaced = _replaced_files(out, kind)
        replaced.pop(out / "checkpoint.msgpack", None)
        return replaced
    # only what a replaced run can hold, as it was: never a path the record names elsewhere
    current = _replaced_files(out, kind)
    kept = {out / n: m for n, m in record.items() if current.get(out / n) == m}
    # the tables and the evaluations log there now are the replaced run's (an evaluate of it
    # after the stop appended to the log): the new run writes its own when it finishes
    stale = [out / n for n in STALE_FILES if (out / n).is_file()]
    return {**kept, **{p: _mtime(p) for p in stale}}


def _new_state_written(out: Path, replaced: dict[Path, float]) -> bool:
    """Whether the new run wrote a state to continue from: a train's checkpoint, or a group
    state or run folder of a sweep, other than the replaced run's."""
    news = [out / "checkpoint.msgpack", *(out / "sweep-state").glob("group*")]
    news += [p for p in (out / "runs").glob("setting*") if p.is_dir()]
    return any(p.exists() and _mtime(p) != replaced.get(p, 0) for p in news)


def replacing(folder: Path) -> bool:
    """Whether ``folder`` (a train's run folder, or a run folder ``runs/setting*`` of a sweep)
    is written by a run that replaces another (``--overwrite``) and has not finished: a stop
    then writes no results over the replaced run's."""
    folder = Path(folder)
    sweep = folder.parent.parent if folder.parent.name == "runs" else None
    return (folder / REPLACING_NAME).exists() or (
        sweep is not None and (sweep / REPLACING_NAME).exists()
    )


def _mtime(path: Path) -> int:
    """Modification time of ``path`` (of its ``results.json`` for a run folder); 0 if none."""
    target = path / "results.json" if path.is_dir() else path
    return target.stat().st_mtime_ns if target.exists() else 0


def _remove_unwritten(replaced: dict[Path, float]) -> None:
    """Remove what the replaced run left and the new run did not write again (its time
    unchanged), once the new run finished: a stop before then leaves the old run as it was."""
    for path, mtime in replaced.items():
        if not path.exists() or _mtime(path) != mtime:
            continue
        if path.name == "runs":  # the sweep's run folders went above; a user's stays
            with contextlib.suppress(OSError):
                path.rmdir()
        elif path.is_dir():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)


def _lock(fd: int, out: Path) -> None:
    """Exclusive, non-blocking ``flock`` on ``fd``; ``UsageError`` naming the holder's pid
    (a writer's; an ``evaluate`` that reads the folder holds a shared lock, ``reading``)."""
    try:
        import fcntl
    except ImportError:  # not a POSIX system: no lock
        return
    _flock(
        fd,
        fcntl.LOCK_EX,
        f"{out} is being written by another cognet-jax process (pid {{pid}}), or read by a "
        "`cognet-jax evaluate`; wait for it or choose another --out",
    )


def _flock(fd: int, mode: int, refusal: str) -> None:
    """Non-blocking ``flock`` of ``mode`` on ``fd``; ``UsageError(refusal)`` when another
    process holds it, ``{pid}`` in ``refusal`` the pid its last writer wrote there."""
    import fcntl

    try:
        fcntl.flock(fd, mode | fcntl.LOCK_NB)
    except OSError:
        pid = os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
        raise UsageError(refusal.replace("{pid}", pid, 1)) from None


def _checked_lock_file(out: Path) -> Path:
    """``out``'s lock file; ``UsageError`` when it is a link or no regular file."""
    lock = out / LOCK_NAME
    if lock.is_symlink() or (lock.exists() and not lock.is_file()):
        raise UsageError(f"{lock}: not a regular file (the run's lock); remove it")
    return lock


def _open_lock(lock: Path) -> int:
    """The lock file opened (made when missing), never through a link."""
    return os.open(lock, os.O_RDWR | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0), 0o644)


@contextlib.contextmanager
def reading(out: Path):
    """Hold a shared lock on the run folder ``out`` while ``evaluate`` reads it and appends
    to its evaluations log: refused at once (``UsageError``) while a ``train`` or ``sweep``
    writes it, and a writer that starts meanwhile (``--overwrite``) is refused until it ends,
    so no evaluation of a replaced policy lands beside a new run. A folder without results, or
    where no lock file can be made (read-only: nothing can write it either), is read without
    one."""
    out = Path(out)
    try:
        import fcntl
    except ImportError:  # not a POSIX system: no lock
        yield out
        return
    if not (out / "results.json").is_file():  # no run to read: the evaluation says so
        yield out
        return
    lock = _checked_lock_file(out)
    try:
        fd = _open_lock(lock)
    except OSError:
        yield out
        return
    try:
        _flock(
            fd,
            fcntl.LOCK_SH,
            f"{out} is being written by another cognet-jax process (pid {{pid}}); evaluate it "
            "when that has finished",
        )
        yield out
    finally:
        os.close(fd)
