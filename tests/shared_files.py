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
