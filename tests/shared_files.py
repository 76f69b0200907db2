"""The standard benchmark problem files of ../shared/dpomdp, for tests (skipped when absent)."""

from pathlib import Path

import pytest

DPOMDP_DIR = Path(__file__).resolve().parents[2] / "shared" / "dpomdp"


def dpomdp_file(name: str) -> Path:
    """``../shared/dpomdp/NAME.dpomdp``, or skip the calling test when it is not there."""
    path = DPOMDP_DIR / f"{name}.dpomdp"
    if not path.is_file():
        pytest.skip(f"benchmark file not found at {path}")
    return path


def compile_cache_env() -> dict:
    """Environment variables that give a ``cognet-jax`` subprocess this session's compilation
    cache (``conftest.py``), with the same settings: every program kept."""
    import jax

    return {
        "JAX_COMPILATION_CACHE_DIR": jax.config.jax_compilation_cache_dir or "",
        "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0",
        "JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES": "0",
    }


#: XLA flags the suite adds to ``XLA_FLAGS`` (conftest.py): XLA's CPU backend without its MLIR
#: fusion emitters and with the whole program in one LLVM module, which at optimisation level
#: 0 compiles faster and runs faster than the default split; and the level an ``optimised``
#: test compiles at (the others: level 0, JAX's ``jax_disable_most_optimizations``)
SUITE_XLA_FLAGS = (
    "--xla_cpu_use_fusion_emitters=false",
    "--xla_cpu_parallel_codegen_split_count=1",
    "--xla_backend_optimization_level=1",
    "--xla_llvm_disable_expensive_passes=true",
)


def with_suite_xla_flags(env: dict) -> dict:
    """``env`` with ``SUITE_XLA_FLAGS`` added to its ``XLA_FLAGS`` (once)."""
    flags = env.get("XLA_FLAGS", "").split()
    return {**env, "XLA_FLAGS": " ".join([*flags, *(f for f in SUITE_XLA_FLAGS if f not in flags)])}


def without_suite_xla_flags(env: dict) -> dict:
    """``env`` without ``SUITE_XLA_FLAGS`` in its ``XLA_FLAGS``."""
    flags = [f for f in env.get("XLA_FLAGS", "").split() if f not in SUITE_XLA_FLAGS]
    return {**env, "XLA_FLAGS": " ".join(flags)}


def as_a_user(env: dict) -> dict:
    """``env`` as a user's process has it: no ``JAX_*`` variable (the suite's compilation
    cache and optimisation setting) and none of ``SUITE_XLA_FLAGS``."""
    return without_suite_xla_flags({k: v for k, v in env.items() if not k.startswith("JAX_")})


#: ``cognet-jax train`` flags of the default experiment at a size tests afford
TINY_TRAIN = [
    *("--set", "algorithm.iterations=2", "--set", "algorithm.candidates=8"),
    *("--set", "algorithm.eval_rollouts=4", "--set", "algorithm.elites=2"),
    *("--set", "algorithm.best_rollouts=10", "--set", "evaluation.rollouts=50"),
    *("--set", "run.plots=false", "--no-progress"),
]


#: the continuous suite's experiments, one per simulator, loaded (each sizing its search by a
#: noise pilot, 1-2 s apiece) by tests/test_suite_envs.py and so left out of
#: tests/test_config_cli.py's load of every built-in experiment
SUITE_EXPERIMENTS = ("hearing-tiger-n7", "beacon-n5", "bearing-chase-n5", "plume-n5", "box-push-n3")
