"""The command line keeps compiled programs in JAX's persistent compilation cache: the folder
it picks, a repeated run in a fresh process that loads instead of compiling, and the switch
that turns it off (docs/reference.md, "Compiled programs are kept")."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from cognet_jax.compile_cache import compile_cache_dir

ROOT = Path(__file__).resolve().parents[1]
TINY = [
    "algorithm.iterations=3",
    "algorithm.rollouts=40",
    "algorithm.top=8",
    "algorithm.keep=3",
    "algorithm.eval_rollouts=8",
    "evaluation.rollouts=100",
    "run.plots=false",
]


def test_the_folder_is_the_variable_else_xdg_else_home(monkeypatch, tmp_path):
    monkeypatch.setenv("COGNET_JAX_CACHE", str(tmp_path / "mine"))
    assert compile_cache_dir() == tmp_path / "mine"
    for off in ("off", "0", "false", "None"):
        monkeypatch.setenv("COGNET_JAX_CACHE", off)
        assert compile_cache_dir() is None
    monkeypatch.delenv("COGNET_JAX_CACHE")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert compile_cache_dir() == tmp_path / "xdg" / "cognet-jax" / "xla"
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert compile_cache_dir() == tmp_path / "home" / ".cache" / "cognet-jax" / "xla"


#: the suite's cache settings (conftest.py), left out of the processes these tests start
_JAX_CACHE_VARIABLES = ("JAX_COMPILATION_CACHE", "JAX_PERSISTENT_CACHE")


def _cli(cache: Path, *args: str) -> str:
    """``cognet-jax ARGS`` in a fresh process whose only cache setting is ``COGNET_JAX_CACHE``
    (the suite's optimisation settings kept: conftest.py); returns its stderr."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(_JAX_CACHE_VARIABLES)}
    env.update(COGNET_JAX_CACHE=str(cache), PYTHONPATH=str(ROOT))
    proc = subprocess.run(
        [sys.executable, "-m", "cognet_jax", *args],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stderr


def _train(out: Path, cache: Path) -> tuple[dict, str]:
    args = ["train", "tagging-thesis-spec-n3", "--seed", "1", "--out", str(out), "--no-progress"]
    log = _cli(cache, *args, *[x for s in TINY for x in ("--set", s)])
    return json.loads((out / "results.json").read_text()), log


@pytest.fixture(scope="module")
def first_run(tmp_path_factory) -> tuple[dict, str, Path]:
    """The first run in a fresh cache (its results, its log, the cache), made once for the
    file, with a copy of the cache as the run left it: each test starts from that state
    (``_cache_after_first``) without compiling again."""
    tmp = tmp_path_factory.mktemp("first")
    first, log = _train(tmp / "a", tmp / "cache")
    for suffix in ("", "-traced"):  # the traced programs are kept beside the cache
        if (tmp / f"cache{suffix}").exists():
            shutil.copytree(tmp / f"cache{suffix}", tmp / f"left{suffix}")
    return first, log, tmp / "cache"


def _cache_after_first(first_run) -> Path:
    """The first run's cache folder as that run left it (restored from the copy). In place,
    not a copy elsewhere: runs on a copy of the entries in another folder compiled as long as
    the first run (tried 2026-12-02), so the folder is part of what a program is kept by."""
    cache = first_run[2]
    for suffix in ("", "-traced"):
        folder, left = (cache.with_name(name + suffix) for name in (cache.name, "left"))
        shutil.rmtree(folder, ignore_errors=True)
        if left.exists():
            shutil.copytree(left, folder)
    return cache


def test_a_repeated_run_loads_its_programs_and_off_keeps_none(first_run, tmp_path):
    """The first run says it compiles and how long that took; the same run again in a fresh
    process loads its programs: ``compile_s`` (the initial state's and the iteration's
    programs) under a third of the first run's, and the same numbers. (Alone on the 2-core CPU
    the second run's ``compile_s`` is 0.4 s against 2.7 s, with two busy loops beside it 0.66 s
    against 4.4 s, so an absolute bound would depend on the suite's load; a run without the
    cache compiles as long as the first.) With ``--no-compile-cache`` nothing is written."""
    first, log, _ = first_run
    cache = _cache_after_first(first_run)
    assert "compiling tagging-thesis-spec-n3" in log and "compiled tagging-thesis-spec-n3 in" in log
    assert any(cache.iterdir())
    second, _ = _train(tmp_path / "b", cache)
    assert second["compile_s"] < first["compile_s"] / 3, (first["compile_s"], second["compile_s"])
    assert second["final_value"] == first["final_value"]
    assert second["values_per_iteration"] == first["values_per_iteration"]
    unused = tmp_path / "unused"
    shutil.copytree(first_run[2].parent / "a", tmp_path / "a")
    _cli(unused, "evaluate", str(tmp_path / "a"), "--rollouts", "50", "--no-compile-cache")
    assert not unused.exists() or not any(unused.iterdir())


def _entries(cache: Path, prefix: str = "") -> list[Path]:
    return sorted(cache.glob(f"{prefix}*-cache"))


def test_damaged_compilation_cache_entries_are_removed_not_blocking(first_run, tmp_path):
    """Entries of JAX's compilation cache swapped between programs (they load, then fail) or
    with flipped bytes (they do not decompress): the run still gives its numbers, says one
    line, and leaves the cache whole again -- the next run has nothing to say."""
    first = first_run[0]
    cache = _cache_after_first(first_run)
    programs = _entries(cache, "jit_call-")
    assert len(programs) >= 2
    blobs = [p.read_bytes() for p in programs]
    for path, blob in zip(programs, blobs[1:] + blobs[:1]):  # each holds another's program
        path.write_bytes(blob)
    swapped, log = _train(tmp_path / "b", cache)
    assert swapped["final_value"] == first["final_value"]
    assert sum(line.startswith("note:") for line in log.splitlines()) == 1, log
    for path in _entries(cache):  # 64 bytes flipped in the middle of every entry
        blob = bytearray(path.read_bytes())
        middle = len(blob) // 2
        blob[middle : middle + 64] = bytes(b ^ 0xFF for b in blob[middle : middle + 64])
        path.write_bytes(bytes(blob))
    flipped, log = _train(tmp_path / "c", cache)
    assert flipped["final_value"] == first["final_value"]
    assert sum(line.startswith("note:") for line in log.splitlines()) == 1, log
    again, log = _train(tmp_path / "d", cache)
    assert again["final_value"] == first["final_value"] and "note:" not in log, log


def test_an_entry_swapped_with_a_sweeps_program_is_compiled_afresh(first_run, tmp_path):
    """An entry holding another command's program (a sweep's, sharded over two devices) under
    the key of a train program: every entry is sealed to its key, so it is removed and
    compiled afresh with one note (XLA aborted the process on loading it before)."""
    first = first_run[0]
    cache = _cache_after_first(first_run)
    trains = set(_entries(cache, "jit_call-"))
    sweep = ["sweep", "tagging-thesis-spec-n3", "--seeds", "2", "--out", str(tmp_path / "s")]
    _cli(
        cache,
        *sweep,
        "--no-progress",
        "--cpu-devices",
        "2",
        *[x for s in TINY for x in ("--set", s)],
    )
    sweeps = set(_entries(cache, "jit_call-")) - trains
    assert trains and sweeps
    mine = max(trains, key=lambda p: p.stat().st_size)
    theirs = max(sweeps, key=lambda p: p.stat().st_size)
    blob_mine, blob_theirs = mine.read_bytes(), theirs.read_bytes()
    mine.write_bytes(blob_theirs)
    theirs.write_bytes(blob_mine)
    swapped, log = _train(tmp_path / "b", cache)
    assert swapped["final_value"] == first["final_value"]
    assert sum(line.startswith("note:") for line in log.splitlines()) == 1, log
    again, log = _train(tmp_path / "c", cache)
    assert again["final_value"] == first["final_value"] and "note:" not in log, log


def test_a_folder_of_other_files_is_not_used_as_the_cache(first_run, tmp_path):
    """COGNET_JAX_CACHE pointed at a folder of the user's own (names like a cache's entries):
    nothing in it is removed or added, one note says programs are not kept there."""
    mine = tmp_path / "project"
    (mine / "build-cache").mkdir(parents=True)
    (mine / "build-cache" / "data.txt").write_text("mine")
    (mine / "report-atime").write_text("mine")
    (mine / "data-cache").write_text("mine")
    before = sorted(p.relative_to(mine) for p in mine.rglob("*"))
    _, log = _train(tmp_path / "a", mine)
    assert sorted(p.relative_to(mine) for p in mine.rglob("*")) == before
    assert "not compiled programs" in log and "build-cache" in log, log
    # a folder under an entry's name in a cache in use (a run folder put there) is kept too
    cache = _cache_after_first(first_run)  # a cache in use
    run = cache / f"run-{'a' * 64}-cache"
    _train(run, cache)
    _, log = _train(tmp_path / "c", cache)
    assert (run / "results.json").is_file() and "not compiled programs" in log, log


def test_a_cache_folder_that_cannot_be_made_is_said_once_and_the_run_goes_on(tmp_path):
    """``COGNET_JAX_CACHE`` naming a link to nothing, or a path under a file: one note naming
    the variable and why (it blamed a cache entry before), and the command runs."""
    (tmp_path / "dangling").symlink_to(tmp_path / "missing" / "x")
    (tmp_path / "afile").write_text("")
    for cache, why in (
        (tmp_path / "dangling", "a link to nothing"),
        (tmp_path / "afile" / "sub", "Not a directory"),
    ):
        err = _cli(cache, "check", "tagging-thesis-n3").splitlines()
        notes = [line for line in err if line.startswith("note:")]
        assert notes == [
            f"note: COGNET_JAX_CACHE={cache}: cannot be made ({why}); programs are not kept"
        ]
