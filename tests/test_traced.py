"""Programs kept traced between processes (cognet_jax/traced.py): a kept program is read back
instead of traced, gives the same numbers, and every input of the trace is in its key."""

from __future__ import annotations

import os
from collections import OrderedDict
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cognet_jax import traced


@pytest.fixture
def cache(tmp_path, monkeypatch):
    """A fresh folder of kept programs, and none compiled in this process yet."""
    folder = tmp_path / "xla-traced"
    monkeypatch.setattr(traced, "trace_cache_dir", lambda: folder)
    monkeypatch.setattr(traced, "_COMPILED", OrderedDict())
    return folder


def _program(traces: list, table):
    def fn(key, x):
        traces.append(1)  # runs only while tracing
        noise = jax.random.normal(key, x.shape)
        return {"y": jnp.cumsum(x * table[0] + noise), "n": jnp.sum(x)}

    return fn


def _no_check(jitted, args):
    return None


def test_kept_program_is_read_back_not_traced_and_gives_the_same_numbers(cache):
    table = jnp.arange(3.0) + 0.5
    args = (jax.random.key(3), jnp.linspace(0.0, 1.0, 64))
    key = traced.program_key("p", {"a": 1}, table, args)
    traces: list = []
    checked = lambda jitted, leaves: jitted.trace(*leaves)  # noqa: E731 (as the memory check)
    first = traced.compile_kept(_program(traces, table), args, key, checked)(*args)
    assert len(traces) == 1 and (cache / f"{key}.bin").is_file()  # the export reads the check's
    traced._COMPILED.clear()  # as in a new process: read back from the file
    before = len(traces)
    checks: list = []
    again = traced.compile_kept(_program(traces, table), args, key, lambda j, a: checks.append(1))(
        *args
    )
    assert len(traces) == before and not checks  # neither traced nor checked again
    direct = jax.jit(_program([], table))(*args)
    for out in (first, again):
        assert set(out) == {"y", "n"}
        np.testing.assert_array_equal(np.asarray(out["y"]), np.asarray(direct["y"]))
        assert float(out["n"]) == float(direct["n"])


def test_every_input_of_the_trace_changes_the_key():
    table = jnp.arange(3.0)
    args = (jax.random.key(0), jnp.zeros(8))
    base = traced.program_key("p", {"a": 1}, table, args)
    assert base == traced.program_key("p", {"a": 1}, jnp.arange(3.0), args)
    others = [
        traced.program_key("q", {"a": 1}, table, args),
        traced.program_key("p", {"a": 2}, table, args),
        traced.program_key("p", {"a": 1}, table.at[1].set(7.0), args),
        traced.program_key("p", {"a": 1}, table, (jax.random.key(0), jnp.zeros(9))),
        traced.program_key("p", {"a": 1}, table, (jax.random.key(0), jnp.zeros(8, jnp.int32))),
    ]
    assert len({base, *others}) == len(others) + 1
    # another key's value is an argument, not part of the program: the same key
    assert base == traced.program_key("p", {"a": 1}, table, (jax.random.key(5), jnp.ones(8)))


def test_a_torn_file_is_traced_again_and_rewritten(cache):
    table = jnp.ones(3)
    args = (jax.random.key(1), jnp.ones(4))
    key = traced.program_key("p", {}, table, args)
    cache.mkdir(parents=True)
    (cache / f"{key}.bin").write_bytes(b"not a program")
    traces: list = []
    out = traced.compile_kept(_program(traces, table), args, key, _no_check)(*args)
    assert traces and np.all(np.isfinite(np.asarray(out["y"])))
    assert (cache / f"{key}.bin").stat().st_size > 100


def test_the_kept_programs_sit_beside_the_compilation_cache(monkeypatch):
    folder = jax.config.jax_compilation_cache_dir  # the test session's (tests/conftest.py)
    assert traced.trace_cache_dir() == Path(folder).with_name(Path(folder).name + "-traced")


def test_without_a_compilation_cache_nothing_is_kept(monkeypatch):
    monkeypatch.setattr(traced, "trace_cache_dir", lambda: None)
    checks: list = []
    args = (jax.random.key(1), jnp.ones(4))
    traced.compile_kept(_program([], jnp.ones(3)), args, "k", lambda j, a: checks.append(1))
    assert checks == [1]


def test_programs_with_large_constants_are_not_kept():
    args = (jax.random.key(0), jnp.zeros(8))
    small = jnp.zeros(traced.KEPT_CONSTANT_BYTES // 4, jnp.float32)
    assert traced.program_key("p", {}, small, args) is not None
    assert traced.program_key("p", {}, jnp.zeros(small.size + 1), args) is None


def test_a_program_jax_cannot_serialize_still_runs(cache):
    """A key type of one's own PRNG implementation (tests/test_prng.py's hash): the export
    cannot be written, the run goes on with the same numbers."""
    from cognet_jax.prng import HASH_IMPL

    args = (jax.random.key(1, impl=HASH_IMPL), jnp.ones(4))
    key = traced.program_key("p", {}, jnp.ones(3), args)
    out = traced.compile_kept(_program([], jnp.ones(3)), args, key, _no_check)(*args)
    direct = jax.jit(_program([], jnp.ones(3)))(*args)
    np.testing.assert_array_equal(np.asarray(out["y"]), np.asarray(direct["y"]))


def test_in_one_process_a_kept_program_is_compiled_once(cache):
    """The second request in the process gets the compiled program itself (the kept file is
    not even read); other compile settings compile it again."""
    table = jnp.arange(4.0)
    args = (jax.random.key(2), jnp.ones(5))
    key = traced.program_key("memo", {}, table, args)
    traces: list = []
    first = traced.compile_kept(_program(traces, table), args, key, _no_check)
    (cache / f"{key}.bin").unlink()
    again = traced.compile_kept(_program(traces, table), args, key, _no_check)
    assert again is first and len(traces) == 1 and not (cache / f"{key}.bin").exists()
    assert jax.tree.map(lambda s: s.shape, first.out_shapes) == {"y": (5,), "n": ()}
    setting = jax.config.values["jax_disable_most_optimizations"]
    jax.config.update("jax_disable_most_optimizations", not setting)
    try:
        other = traced.compile_kept(_program(traces, table), args, key, _no_check)
    finally:
        jax.config.update("jax_disable_most_optimizations", setting)
    assert other is not first and len(traces) == 2
    np.testing.assert_array_equal(np.asarray(other(*args)["y"]), np.asarray(first(*args)["y"]))


def test_the_identity_of_a_program_holds_the_bytes_of_the_files_it_reads(tmp_path):
    """A VAE (or model) file rewritten in place gives another key: its weights may be baked
    into the program."""
    import os

    from cognet_jax.compiled import program_identity
    from cognet_jax.registry import load_config

    vae = tmp_path / "vae.msgpack"
    vae.write_bytes(b"first")
    config = load_config("tagging-thesis-n3", [f"network.vae_path={str(vae)!r}"])
    first = program_identity(config)
    assert program_identity(config) == first
    vae.write_bytes(b"other")
    os.utime(vae, ns=(1, 1))  # (a rewrite within the clock's resolution is still seen)
    assert program_identity(config) != first


def _kept_then_damaged(cache, damage):
    """A program kept in ``cache``, its file damaged by ``damage(path, other_path)``, then
    compiled again as a new process would: returns ``(traces after, output, key)``."""
    table = jnp.arange(3.0)
    args = (jax.random.key(2), jnp.linspace(0.0, 1.0, 16))
    key = traced.program_key("p", {"d": 1}, table, args)
    other_args = (jax.random.key(2), jnp.ones(5))
    other = traced.program_key("p", {"d": 2}, table, other_args)
    traced.compile_kept(_program([], table), args, key, _no_check)
    traced.compile_kept(_program([], table), other_args, other, _no_check)
    damage(cache / f"{key}.bin", cache / f"{other}.bin")
    traced._COMPILED.clear()
    traces: list = []
    out = traced.compile_kept(_program(traces, table), args, key, _no_check)(*args)
    return traces, out, jax.jit(_program([], table))(*args)


def _flip(path, _other):
    data = bytearray(path.read_bytes())
    for i in range(len(data) // 2, len(data) // 2 + 8):
        data[i] ^= 0xFF
    path.write_bytes(bytes(data))


def _swap(path, other):
    a, b = path.read_bytes(), other.read_bytes()
    path.write_bytes(b)
    other.write_bytes(a)


def _grow(path, _other):
    """Past ``ENTRY_MAX_BYTES`` (sparse: no disk is used): removed unread."""
    from cognet_jax.compile_cache import ENTRY_MAX_BYTES

    os.truncate(path, ENTRY_MAX_BYTES + 1)


@pytest.mark.parametrize(
    "damage", [_flip, _swap, _grow], ids=["flipped-bytes", "swapped-between-keys", "too-large"]
)
def test_a_damaged_or_swapped_file_is_traced_afresh_with_one_line(cache, damage, capsys):
    from cognet_jax import compile_cache

    monkey_told = compile_cache._CACHE_TOLD.copy()
    compile_cache._CACHE_TOLD.clear()
    try:
        traces, out, direct = _kept_then_damaged(cache, damage)
    finally:
        compile_cache._CACHE_TOLD[:] = monkey_told
    assert traces  # not read from the damaged file
    np.testing.assert_array_equal(np.asarray(out["y"]), np.asarray(direct["y"]))
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "traced afresh" in err[0], err


def test_a_cache_folder_filled_without_the_size_bound_is_repaired(tmp_path):
    """Entries without JAX's access-time files get one (time 0), orphan access-time files go:
    without them JAX warns at every write and never stores a new entry."""
    from cognet_jax.compile_cache import repair_cache_folder

    H = "0" * 64  # entry names as JAX writes them: <program>-<sha256 hex>-cache
    (tmp_path / f"a-{H}-cache").write_bytes(b"x")
    (tmp_path / f"b-{H}-cache").write_bytes(b"y")
    (tmp_path / f"b-{H}-atime").write_bytes(b"12345678")
    (tmp_path / f"c-{H}-atime").write_bytes(b"12345678")
    repair_cache_folder(tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        f"a-{H}-atime",
        f"a-{H}-cache",
        f"b-{H}-atime",
        f"b-{H}-cache",
    ]
    assert (tmp_path / f"a-{H}-atime").read_bytes() == bytes(8)
    assert (tmp_path / f"b-{H}-atime").read_bytes() == b"12345678"
    from cognet_jax.compile_cache import ENTRY_MAX_BYTES

    huge = tmp_path / f"d-{H}-cache"  # sparse: no disk is used; removed unread
    huge.write_bytes(b"")
    os.truncate(huge, ENTRY_MAX_BYTES + 1)
    repair_cache_folder(tmp_path)
    assert not huge.exists() and not (tmp_path / f"d-{H}-atime").exists()
    repair_cache_folder(tmp_path / "absent")  # nothing to repair: no error
    (tmp_path / "build-cache").mkdir()  # names that are no entry of JAX's are never touched
    (tmp_path / "notes-atime").write_text("mine")
    repair_cache_folder(tmp_path)
    assert (tmp_path / "build-cache").is_dir() and (tmp_path / "notes-atime").is_file()


def test_a_run_says_at_most_one_line_about_its_caches(capsys, monkeypatch):
    from cognet_jax import compile_cache

    monkeypatch.setattr(compile_cache, "_CACHE_TOLD", [])
    compile_cache.cache_note("compilation cache /x: cannot write")
    traced._discard(Path("/nonexistent/abc.bin"), ValueError("bad"))
    assert capsys.readouterr().err.splitlines() == ["note: compilation cache /x: cannot write"]


def test_a_program_traced_under_another_jax_setting_is_keyed_apart():
    """A module that changes a JAX setting beyond the three named ones (here the default
    matmul precision) gets other keys: its programs are never read back in a run without it."""
    import jax

    args = (jnp.ones(3),)
    before = traced.program_key("p", {"a": 1}, None, args)
    with jax.default_matmul_precision("highest"):
        during = traced.program_key("p", {"a": 1}, None, args)
    assert during != before and traced.program_key("p", {"a": 1}, None, args) == before
