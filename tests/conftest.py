"""Test-session set-up.

**A compilation cache per test process**, so a program with the same HLO (the same small config
built in two tests of a file, or in a test and the ``cognet-jax`` process it starts:
``shared_files.compile_cache_env``) is compiled once. One folder per process, not one for all
xdist workers: JAX writes cache entries without a lock unless a size bound is set, and with one
it lists the folder at every write, which made the suite slower than compiling twice. The folder
is removed at the end of the session.

**Most optimisations off for the tests**: JAX's own ``jax_disable_most_optimizations`` (XLA's
backend at optimisation level 0 and LLVM's expensive passes off), set in this process and,
through ``JAX_DISABLE_MOST_OPTIMIZATIONS``, in the ``cognet-jax`` processes the tests start.
Most tests compile far more than they run: on the 2-core CPU, backend compiles took 927 s of
the 1,613 s the tests spent (summed over both workers), and level 0 halves them (509 s). It
changes how LLVM optimises the machine code, not what it computes: every test passes with it,
the bit-for-bit comparisons of runs included. Compiled code then runs up to 27x slower (one
COGNet-DICE thesis iteration: 8 ms -> 213 ms), so the few tests whose time is execution are
marked ``optimised``: for them the flag is off, in this process and in the processes they
start (``pytest_runtest_call`` below), as a user's run compiles them. Fixtures are set up
with the flag on: a program compiled then and called again keeps its code (the same numbers,
slower).
"""

import os
import shutil
import tempfile
from pathlib import Path

import pytest

#: JAX's flag (and its environment variable, read when JAX is imported and by subprocesses)
FAST_COMPILE = "JAX_DISABLE_MOST_OPTIMIZATIONS"
os.environ[FAST_COMPILE] = "1"

import jax  # noqa: E402

jax.config.update("jax_disable_most_optimizations", True)  # (should JAX be imported already)
_CACHE = Path(tempfile.mkdtemp(prefix="cognet-jax-test-cache-"))
jax.config.update("jax_compilation_cache_dir", str(_CACHE))
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)


def pytest_configure(config):
    config.addinivalue_line(
        "markers",
        "optimised: its time is execution, not compilation: run with XLA's default "
        "optimisation (conftest.py)",
    )


@pytest.hookimpl(wrapper=True)
def pytest_runtest_call(item):
    """An ``optimised`` test runs with XLA's default optimisation, here and in its subprocesses."""
    if item.get_closest_marker("optimised") is None:
        return (yield)
    jax.config.update("jax_disable_most_optimizations", False)
    os.environ[FAST_COMPILE] = "0"
    try:
        return (yield)
    finally:
        os.environ[FAST_COMPILE] = "1"
        jax.config.update("jax_disable_most_optimizations", True)


def pytest_sessionfinish(session):
    shutil.rmtree(_CACHE, ignore_errors=True)
    # the traced programs kept beside it (cognet_jax.traced.trace_cache_dir)
    shutil.rmtree(_CACHE.with_name(_CACHE.name + "-traced"), ignore_errors=True)
