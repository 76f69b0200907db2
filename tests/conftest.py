"""Test-session set-up.

**A compilation cache per test process**, so a program with the same HLO (the same small config
built in two tests of a file, or in a test and the ``cognet-jax`` process it starts:
``shared_files.compile_cache_env``) is compiled once. One folder per process, not one for all
xdist workers: JAX writes cache entries without a lock unless a size bound is set, and with one
it lists the folder at every write, which made the suite slower than compiling twice. The folder
is removed at the end of the session.

**XLA's backend at optimisation level 0** (``--xla_backend_optimization_level=0`` in
``XLA_FLAGS``, inherited by the ``cognet-jax`` processes the tests start). Most tests compile
far more than they run: on the 2-core CPU, backend compiles took 927 s of the 1,613 s the tests
spent (summed over both workers), and level 0 halves them (509 s). The flag changes how LLVM
optimises the machine code, not what it computes: every test passes with it, the bit-for-bit
comparisons of runs included. Compiled code then runs up to 27x slower (one
COGNet-DICE thesis iteration: 8 ms -> 213 ms), so the few tests whose time is execution are
marked ``optimised``: each runs in a child pytest with the machine's own ``XLA_FLAGS``
(``pytest_pyfunc_call`` below), as a user's run compiles it.
"""

import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest
from shared_files import LEVEL_0, without_level_0

#: set in the child pytest that runs an ``optimised`` test
_CHILD = "COGNET_JAX_TEST_OPTIMISED"
# (an xdist worker inherits the flag from the pytest process that started it)
_USER_XLA_FLAGS = without_level_0(os.environ.get("XLA_FLAGS", ""))
if not os.environ.get(_CHILD):
    os.environ["XLA_FLAGS"] = f"{_USER_XLA_FLAGS} {LEVEL_0}".strip()

import jax  # noqa: E402

_CACHE = Path(tempfile.mkdtemp(prefix="cognet-jax-test-cache-"))
jax.config.update("jax_compilation_cache_dir", str(_CACHE))
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)


def pytest_configure(config):
    config.addinivalue_line(
        "markers",
        "optimised: its time is execution, not compilation: run in a child pytest with XLA's "
        "default optimisation (conftest.py)",
    )


def pytest_pyfunc_call(pyfuncitem):
    """An ``optimised`` test runs in a child pytest without the level-0 flag; its result is
    the child's (the child's output is shown when it fails)."""
    if os.environ.get(_CHILD) or pyfuncitem.get_closest_marker("optimised") is None:
        return None
    root = Path(__file__).resolve().parents[1]
    env = dict(os.environ, XLA_FLAGS=_USER_XLA_FLAGS, **{_CHILD: "1"})
    command = [sys.executable, "-m", "pytest", "-q", "-n", "0", "-p", "no:cacheprovider"]
    done = subprocess.run(
        [*command, pyfuncitem.nodeid], cwd=root, env=env, capture_output=True, text=True
    )
    if done.returncode != 0:
        pytest.fail(f"the optimised child run failed:\n{done.stdout[-6000:]}{done.stderr[-2000:]}")
    return True


def pytest_sessionfinish(session):
    shutil.rmtree(_CACHE, ignore_errors=True)
    # the traced programs kept beside it (cognet_jax.traced.trace_cache_dir)
    shutil.rmtree(_CACHE.with_name(_CACHE.name + "-traced"), ignore_errors=True)
