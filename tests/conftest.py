"""Test-session set-up: a compilation cache per test process, so a program with the same HLO
(the same small config built in two tests of a file, or in a test and the ``cognet-jax``
process it starts: ``shared_files.compile_cache_env``) is compiled once.

One folder per process, not one for all xdist workers: JAX writes cache entries without a
lock unless a size bound is set, and with one it lists the folder at every write, which made
the suite slower than compiling twice. The folder is removed at the end of the session."""

import shutil
import tempfile
from pathlib import Path

import jax

_CACHE = Path(tempfile.mkdtemp(prefix="cognet-jax-test-cache-"))
jax.config.update("jax_compilation_cache_dir", str(_CACHE))
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)


def pytest_sessionfinish(session):
    shutil.rmtree(_CACHE, ignore_errors=True)
    # the traced programs kept beside it (cognet_jax.traced.trace_cache_dir)
    shutil.rmtree(_CACHE.with_name(_CACHE.name + "-traced"), ignore_errors=True)
