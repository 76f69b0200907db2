"""How a run's programs are compiled and kept: the arrays of a run's params that are arguments
rather than constants (``hoist_large``), the context its iterations compile in
(``rollout_mesh``), what its programs depend on (``program_identity``: the key they are kept
under, ``traced.compile_kept``), and ``compiled_program``, which checks each against the memory
budget before and after compiling."""

from __future__ import annotations

import contextlib
import functools
import hashlib
from pathlib import Path

import jax
import numpy as np
from jax.sharding import Mesh

from cognet_jax.config import OPTIONAL_SECTIONS, Config
from cognet_jax.errors import ResourceError
from cognet_jax.memory import SIZES, budget_bytes, check_compiled, trace_checked
from cognet_jax.registry import (
    algorithm_entry,
    env_entry,
    foreign_code,
    is_builtin,
)
from cognet_jax.traced import compile_kept, program_key

#: arrays of a single run's params larger than this are arguments of its compiled programs,
#: not constants: each program holds its own copy of a constant (a 2025-state model's 262 MB
#: transition table, once in the step, once in the finish, once in the evaluation)
CONSTANT_BYTES = 16 * 2**20


def hoist_large(params):
    """``(held, rebuild)``: the array leaves of ``params`` larger than ``CONSTANT_BYTES`` and
    ``rebuild(held) -> params`` with them put back (traced arguments inside a program); the
    other leaves stay constants."""
    leaves, treedef = jax.tree.flatten(params)
    where = [i for i, x in enumerate(leaves) if _held(x)]

    def rebuild(held):
        out = list(leaves)
        for i, x in zip(where, held, strict=True):
            out[i] = x
        return jax.tree.unflatten(treedef, out)

    return tuple(leaves[i] for i in where), rebuild


def _held(x) -> bool:
    return getattr(x, "nbytes", 0) > CONSTANT_BYTES


def baked_constants(params) -> list:
    """The array leaves of ``params`` that ``hoist_large`` leaves as constants."""
    return [x for x in jax.tree.leaves(params) if not _held(x)]


def rollout_mesh(config: Config):
    """The context a run's iterations are compiled in: with ``run.shard_rollouts`` a 1-D mesh
    ``("rollouts",)`` over the local devices is set (``jax.set_mesh``), and the rollout
    engine lays every batch of rollouts (and so the candidates' evaluations) over it
    (``rollout.shard_rollouts``); otherwise nothing changes."""
    if not config.run.shard_rollouts:
        return contextlib.nullcontext()
    return jax.set_mesh(Mesh(np.array(jax.local_devices()), ("rollouts",)))


#: ``run`` fields that only drive a run (progress, plots, checkpoints): left out of the keys of
#: its programs, which do not depend on them
DRIVING_FIELDS = ("progress", "plots", "checkpoint_every", "checkpoint_seconds", "probe_seconds")


def program_identity(config: Config, search: bool = False, **extra) -> dict:
    """What a program of ``config`` depends on besides its constants and argument shapes: the
    config without its ``DRIVING_FIELDS`` (and without its ``evaluation`` section for the
    ``search``'s own programs, which never read it), the bytes of the files it reads
    (``Config.input_files``: a model, a VAE, whose weights may be baked in), its memory budget
    in bytes, and ``extra``."""
    sections = config.to_dict()
    sections["run"] = {k: v for k, v in sections["run"].items() if k not in DRIVING_FIELDS}
    if search:
        del sections["evaluation"]
    digests = [file_digest(Path(f).expanduser()) for f in config.input_files()]
    memory = budget_bytes(config.run.memory_gb)
    return {"config": sections, "files": digests, "memory": memory, **extra}


def file_digest(path: Path) -> str:
    """SHA-256 of a file's bytes (computed once per size and modification time); "" for a
    missing file."""
    try:
        path = path.resolve()
        stat = path.stat()
    except OSError:
        return ""
    if not path.is_file():  # a folder a field names: no bytes of its own
        return "not a file"
    return _digest_of(path, stat.st_size, stat.st_mtime_ns)


@functools.lru_cache(maxsize=64)
def _digest_of(path: Path, size: int, mtime_ns: int) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def compiled_program(
    config: Config, what: str, fn, args: tuple, constants, identity: dict, before_compile=None
):
    """``fn(*args)`` compiled once (``traced.compile_kept``: kept in this process and, traced,
    between processes, while the compilation cache is on), ``what`` naming it in the memory
    check's refusal (``before_compile()`` is called once the check passed, when it is
    compiled afresh); ``constants`` are the arrays of ``config``'s params baked into it. A
    simulator or algorithm registered from outside the package is compiled afresh each time
    (its source is not in the key)."""
    before_compile = before_compile or (lambda: None)
    builtin = (
        not foreign_code()
        and is_builtin(env_entry(config.env.name))
        and is_builtin(algorithm_entry(config.experiment.algorithm))
    )
    key = program_key(what, identity, constants, args) if builtin else None
    memory = budget_bytes(config.run.memory_gb)

    def check(jitted, leaves):
        with sizes_named(config):
            trace_checked(jitted, leaves, memory, what)
        before_compile()

    def check_after(compiled):
        with sizes_named(config):
            check_compiled(compiled, memory, what)

    return compile_kept(fn, args, key, check, check_after)


#: the words of config fields that set array sizes (a memory refusal names them)
SIZE_WORDS = ("nodes", "samples", "candidates", "rollouts", "horizon", "hidden", "restarts")


def size_fields(config: Config, most: int = 5) -> str:
    """``config``'s fields that set array sizes, largest value first (``"problem.horizon =
    100000, algorithm.samples = 1000"``): integers above 1 whose names hold a ``SIZE_WORDS``
    word, in the sections the simulator or the algorithm reads; "" when none does."""
    try:
        reads = set(env_entry(config.env.name).reads)
        reads |= set(algorithm_entry(config.experiment.algorithm).reads)
    except Exception:  # a simulator given as an object (``api.make_algorithm``): every section
        reads = set(OPTIONAL_SECTIONS)
    unread = {"run", "experiment", *(set(OPTIONAL_SECTIONS) - reads)}
    found = [
        (value, f"{section}.{name}")
        for section, fields in config.to_dict().items()
        if section not in unread and isinstance(fields, dict)
        for name, value in fields.items()
        if type(value) is int and value > 1 and any(w in name for w in SIZE_WORDS)
    ]
    found.sort(key=lambda f: (-f[0], f[1]))
    return ", ".join(f"{name} = {value}" for value, name in found[:most])


@contextlib.contextmanager
def sizes_named(config: Config):
    """A memory refusal (``ResourceError``) raised inside names ``config``'s own size fields
    (``size_fields``) where it named the generic ``memory.SIZES``."""
    try:
        yield
    except ResourceError as err:
        named = size_fields(config)
        text = str(err)
        if named and f"({SIZES})" in text:
            err.args = (text.replace(f"({SIZES})", f"({named})"),)
        raise
