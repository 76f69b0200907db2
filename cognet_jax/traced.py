"""Programs kept traced between processes, so a repeated run neither traces nor lowers again.

JAX's persistent compilation cache (turned on by the command line,
``compile_cache.use_compile_cache``) skips XLA's compilation of a program it has seen, but not the
Python tracing and the lowering that come first and give the cache its key, most of what a warm
``cognet-jax train`` spends before its loop (benchmarks/NOTES.md, "Measurements behind code
choices"). This module keeps the traced program as well, with JAX's own serialization
(:mod:`jax.export`): the first run traces the program, exports it to
``<cache folder>-traced/<key>.bin`` and compiles the exported program; a later run with the same
key reads that file and compiles the same exported program, which JAX's compilation cache then
loads. First and later runs compile the very same program, so they give the same numbers.

The key is a SHA-256 of everything the traced program depends on: the source of every module
of the package, the JAX, jaxlib and Python versions, the JAX settings that change tracing
(64-bit mode, the PRNG implementation and its partitioning), the mesh it is traced under and
the number of local devices, the config and the files it reads (``compiled.program_identity``),
the model arrays baked in as constants, the memory budget the program was checked against,
and the shapes, types and layouts of the arguments. A program of a simulator or algorithm
registered from outside the package (``--import``) is never kept: its source is not in the
key. Off together with the
compilation cache (``--no-compile-cache``, ``COGNET_JAX_CACHE=off``). A file that cannot be
read is traced afresh and written again.

Within one process a kept program is compiled once: the compiled program is kept in memory by
its key and JAX's settings that change compilation (``COMPILE_SETTINGS``), so a second run of
the same program in the process (a resumed run, an evaluation after ``train`` in one Python
session) neither traces, nor lowers, nor reads the compilation cache. The ``KEPT_IN_PROCESS``
programs used last are kept. A program that is not kept (no key, or the cache off) is traced
and compiled at every request.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import json
import os
import pickle
import platform
import shutil
import sys
import threading
from collections import OrderedDict
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import numpy as np

from cognet_jax.compile_cache import ENTRY_MAX_BYTES, cache_note, compiled_despite_cache

#: programs whose constants (model arrays baked in) take more bytes than this are not kept:
#: exporting them holds further copies of the constants (the 2025-state fire fighting model's
#: 4.8 MB raised the run's peak RSS by about 0.1 GB), and tracing is a small part of such runs
KEPT_CONSTANT_BYTES = 2**20
#: JAX settings that change what a function traces to, keyed by name; every other JAX setting is
#: keyed too (``trace_settings``) except those whose names hold one of ``UNKEYED_WORDS``
#: (caches, logging, timeouts: how a program is stored or reported, not what it computes)
TRACE_SETTINGS = ("jax_enable_x64", "jax_default_prng_impl", "jax_threefry_partitionable")
UNKEYED_WORDS = ("cache", "log", "timeout", "explain")
#: JAX settings that change how a traced program is compiled (keys of the in-process programs)
COMPILE_SETTINGS = (
    "jax_disable_most_optimizations",
    "jax_exec_time_optimization_effort",
    "jax_memory_fitting_effort",
    "jax_optimization_level",
    "jax_memory_fitting_level",
    "jax_compiler_enable_remat_pass",
    "jax_use_shardy_partitioner",
)
#: compiled programs kept in one process (the ones used last)
KEPT_IN_PROCESS = 64
_COMPILED: OrderedDict[str, Callable] = OrderedDict()
_COMPILED_LOCK = threading.Lock()  # (a stopped command's worker thread may still compile)


def trace_cache_dir() -> Path | None:
    """``<JAX's compilation cache folder>-traced``, or None when that cache is off."""
    folder = jax.config.jax_compilation_cache_dir
    if not folder:
        return None
    folder = Path(folder)
    return folder.with_name(folder.name + "-traced")


@functools.cache
def source_digest() -> str:
    """SHA-256 of every ``.py`` file of the package (names and bytes), computed once."""
    root = Path(__file__).resolve().parent
    h = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        h.update(str(path.relative_to(root)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def _array_digest(tree) -> str:
    """SHA-256 of a pytree's structure and its array leaves' dtypes, shapes and bytes."""
    leaves, treedef = jax.tree.flatten(tree)
    h = hashlib.sha256(str(treedef).encode())
    for x in leaves:
        if jax.dtypes.issubdtype(getattr(x, "dtype", None), jax.dtypes.prng_key):
            x = jax.random.key_data(x)
        a = np.ascontiguousarray(x)  # a view of a CPU array: no copy
        h.update(f"{a.dtype}{a.shape}".encode())
        h.update(memoryview(a).cast("B"))
    return h.hexdigest()


def _avals(args) -> str:
    """The tree, and every leaf's dtype, shape, weak type and sharding (where it has one)."""
    leaves, treedef = jax.tree.flatten(args)
    shapes = [
        f"{getattr(x, 'dtype', type(x))}{getattr(x, 'shape', ())}"
        f"{'w' if getattr(x, 'weak_type', False) else ''}{getattr(x, 'sharding', '')}"
        for x in leaves
    ]
    return f"{treedef}|{','.join(shapes)}"


def trace_settings() -> dict[str, str]:
    """The JAX settings a kept program is keyed by: ``TRACE_SETTINGS`` and every other setting
    of ``jax.config`` but those named by ``UNKEYED_WORDS``, so a program traced under a
    setting a module changed (matmul precision, rank promotion, x64, ...) is never read back
    under another."""
    values = getattr(jax.config, "values", {})
    keyed = {k: str(v) for k, v in values.items() if not any(w in k for w in UNKEYED_WORDS)}
    keyed.update({s: str(getattr(jax.config, s)) for s in TRACE_SETTINGS})
    return keyed


def program_key(what: str, identity: dict, constants, args) -> str | None:
    """The file name (hex digest) of a program ``what`` traced from ``identity`` (a JSON-able
    dict: config, budget, ...), ``constants`` (the pytree of arrays baked into the program) and
    arguments shaped like ``args``; None (not to be kept) when the constants take more than
    ``KEPT_CONSTANT_BYTES``."""
    size = sum(getattr(x, "nbytes", 0) for x in jax.tree.leaves(constants))
    if size > KEPT_CONSTANT_BYTES:
        return None
    settings = trace_settings()
    # the mesh a program is traced under (``run.shard_rollouts``) and the devices it may use
    settings["mesh"] = str(jax.sharding.get_abstract_mesh())
    settings["devices"] = str(jax.local_device_count())
    versions = [jax.__version__, jax.lib.__version__, platform.python_version(), sys.platform]
    h = hashlib.sha256()
    for part in (
        what,
        source_digest(),
        json.dumps(versions),
        json.dumps(settings, sort_keys=True),
        json.dumps(identity, sort_keys=True, default=str),
        _array_digest(constants),
        _avals(args),
    ):
        h.update(part.encode())
        h.update(b"\0")
    return h.hexdigest()


def _load(path: Path):
    """``(exported, out_tree)`` from ``path``, or None when it is missing, unreadable, kept
    under another key or its bytes differ from the digest written with them."""
    try:
        if not path.is_file():  # missing, or no regular file (a folder, a pipe: never opened)
            return None
        with path.open("rb") as f:
            key, digest, blob, out_tree = pickle.load(f)
        if key != path.stem:  # a file copied or moved from another key
            return None
        if hashlib.sha256(blob).hexdigest() != digest:  # flipped bytes
            return None
        return jax.export.deserialize(blob), out_tree
    except Exception:  # missing, torn or foreign: trace afresh and write it again
        return None


def _save(path: Path, exported, out_tree) -> None:
    """Written to a temporary name first, so a reader never sees half a file."""
    tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with tmp.open("wb") as f:
            blob = exported.serialize()
            pickle.dump((path.stem, hashlib.sha256(blob).hexdigest(), blob, out_tree), f)
        os.replace(tmp, path)
    except Exception:  # a read-only or full disk, no flatbuffers, a type JAX cannot serialize
        with contextlib.suppress(OSError):  # (a PRNG implementation of one's own): not kept
            tmp.unlink(missing_ok=True)


def _flat(fn: Callable, args: tuple):
    """``(jitted, leaves, out_trees)``: ``fn`` jitted as a function of ``args``' flat leaves
    returning flat leaves; ``out_trees`` receives the output's tree when it is traced."""
    leaves, in_tree = jax.tree.flatten(args)
    out_trees = []

    def flat(*xs):
        out_leaves, out_tree = jax.tree.flatten(fn(*jax.tree.unflatten(in_tree, xs)))
        out_trees.append(out_tree)
        return out_leaves

    return jax.jit(flat), tuple(leaves), out_trees


def _export(jitted, leaves: tuple):
    """JAX's export of ``jitted`` at ``leaves``, or None when JAX cannot export it."""
    try:
        return jax.export.export(jitted)(*leaves)
    except Exception:
        return None


def _caller(compiled, out_tree) -> Callable:
    """``call(*args)`` of a compiled flat program, with ``call.out_shapes``: its output's
    shapes (``jax.ShapeDtypeStruct`` leaves)."""

    def call(*args):
        return jax.tree.unflatten(out_tree, compiled(*jax.tree.leaves(args)))

    call.out_shapes = jax.tree.unflatten(out_tree, compiled.out_info)
    call.compiled = compiled
    return call


def compile_kept(
    fn: Callable,
    args: tuple,
    key: str | None,
    check: Callable[[Callable, tuple], None],
    check_compiled: Callable[[Any], None] = lambda compiled: None,
) -> Callable:
    """``fn(*args)`` compiled ahead of time, as ``call(*args) -> fn(*args)`` (with
    ``call.out_shapes``, the output's shapes).

    ``key``: the program's ``program_key`` (None: not kept; traced and compiled as usual).
    ``check(jitted, leaves)`` runs before a program is traced afresh (the memory check), with
    ``fn`` jitted as a function of the flat leaves of ``args``; a kept program passed it when it
    was traced. When ``check`` traces (the memory check does), the export reads that trace
    (JAX keeps it with the jitted function) instead of tracing again. ``check_compiled`` sees
    every program compiled or loaded here (XLA's memory analysis: the memory check after
    compiling) before it is returned. A program compiled earlier in this process is returned as
    it is (see the module docstring)."""
    folder = trace_cache_dir()
    keep = key is not None and folder is not None
    if not keep:
        jitted, leaves, out_trees = _flat(fn, args)
        check(jitted, leaves)
        caller = _caller(_compile(jitted, leaves), out_trees[0])
        check_compiled(caller.compiled)
        return caller
    in_process = _in_process_key(key)
    with _COMPILED_LOCK:
        if in_process in _COMPILED:
            _COMPILED.move_to_end(in_process)
            return _COMPILED[in_process]
    caller = _compiled_from_file(fn, args, folder / f"{key}.bin", check)
    check_compiled(caller.compiled)
    with _COMPILED_LOCK:
        _COMPILED[in_process] = caller
        while len(_COMPILED) > KEPT_IN_PROCESS:
            _COMPILED.popitem(last=False)
    return caller


def _in_process_key(key: str) -> str:
    """``key`` and the JAX settings that change how it compiles."""
    settings = [str(jax.config.values.get(s)) for s in COMPILE_SETTINGS]
    return "|".join([key, *settings])


def _compiled_from_file(fn: Callable, args: tuple, path: Path, check) -> Callable:
    """The program kept in ``path`` compiled (JAX's compilation cache may hold it); traced,
    checked and exported to ``path`` first when ``path`` holds none. Not written when several
    processes run together (``jax.distributed``), which trace their own (a file written
    earlier by a single process is read all the same: its key names the devices). A file that
    cannot be read, does not fit the arguments or does not compile (torn, edited, swapped
    between keys) is removed with one line on stderr, and the program traced afresh."""
    size = path.stat().st_size if path.is_file() else 0
    if size > ENTRY_MAX_BYTES:  # no program this library keeps: removed unread
        _discard(path, ValueError(f"{size} bytes, too large to be read"))
    kept = _load(path)
    if kept is None and (path.exists() or path.is_symlink()):
        _discard(path, ValueError("cannot be read"))
    if kept is not None:
        exported, out_tree = kept
        try:
            if not _fits(exported, out_tree, args):
                raise ValueError("its arguments or outputs differ from the program's")
            compiled = _compile(jax.jit(exported.call), tuple(jax.tree.leaves(args)))
            return _caller(compiled, out_tree)
        except Exception as err:
            _discard(path, err)
    jitted, leaves, out_trees = _flat(fn, args)
    check(jitted, leaves)
    exported = _export(jitted, leaves) if jax.process_count() == 1 else None
    if exported is None:  # not exportable: compiled as usual
        return _caller(_compile(jitted, leaves), out_trees[0])
    _save(path, exported, out_trees[0])
    return _caller(_compile(jax.jit(exported.call), leaves), out_trees[0])


def _compile(jitted, leaves: tuple):
    """``jitted`` lowered at ``leaves`` and compiled; an entry of JAX's compilation cache that
    loads but fails is removed and the program compiled afresh (``compiled_despite_cache``)."""
    return compiled_despite_cache(lambda: jitted.lower(*leaves).compile())


def _fits(exported, out_tree, args) -> bool:
    """Whether a kept program takes as many arguments as ``args`` has leaves and returns as
    many leaves as ``out_tree`` holds (``exported.call`` checks the shapes and dtypes): a file
    kept under another key (copied, swapped) does not."""
    n_in = len(jax.tree.leaves(args))
    return n_in == len(exported.in_avals) and out_tree.num_leaves == len(exported.out_avals)


def _discard(path: Path, err: BaseException) -> None:
    """Remove an unusable kept program; reported in one line, the only line a process says
    about its caches (``compile_cache.cache_note``)."""
    with contextlib.suppress(OSError):
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path)
        else:
            path.unlink()
    reason = " ".join(str(err).split())[:100] or type(err).__name__
    cache_note(
        f"unusable kept programs in {path.parent} are removed and traced afresh "
        f"({path.name[:12]}: {reason})"
    )


__all__ = ["compile_kept", "program_key", "source_digest", "trace_cache_dir"]
