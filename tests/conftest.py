"""Test-session set-up.

**A compilation cache per test process**, so a program with the same HLO (the same small config
built in two tests of a file, or in a test and the ``cognet-jax`` process it starts: the
environment of ``shared_files.compile_cache_env``, set for every process a test starts) is
compiled once. One folder per process, not one for all xdist workers: JAX writes cache entries
without a lock unless a size bound is set, and with one it lists the folder at every write,
which made the suite slower than compiling twice. (One folder shared by both workers without a
bound, tried 2026-11-27: as many compiles, about 3,700, and no faster; of the 2,183 programs the
two workers kept in one later run (the cache key made independent of the folder: JAX's
``jax_persistent_cache_enable_xla_caches = 'none'``), 190 were the same in both, 7 s of
compiling.) The folder is removed at the end of the session.

**Most optimisations off for the tests**: JAX's own ``jax_disable_most_optimizations`` (XLA's
backend at optimisation level 0 and LLVM's expensive passes off), set in this process and,
through ``JAX_DISABLE_MOST_OPTIMIZATIONS``, in the ``cognet-jax`` processes the tests start.
Most tests compile far more than they run: on the 2-core CPU, backend compiles took 927 s of
the 1,613 s the tests spent (summed over both workers), and level 0 halves them (509 s). It
changes how LLVM optimises the machine code, not what it computes: every test passes with it,
the bit-for-bit comparisons of runs included. Compiled code then runs up to 27x slower (one
COGNet-DICE thesis iteration: 8 ms -> 213 ms; 61-65 ms with the two flags below), so the few
tests whose time is execution are marked ``optimised``: for them the flag is off, in this
process and in the processes they start (``pytest_runtest_call`` below), so they compile at
the optimisation level the XLA flags below set: 1, with LLVM's expensive passes off. On the
programs measured it runs as fast as XLA's default level and compiles 1.2-3x faster (Dec-Tiger
G-DICE iteration: 2.3 s and 71 ms against 6.9 s and 69 ms; level 0: 0.9 s and 360 ms). The
driver's programs are kept per optimisation setting (``cognet_jax.traced``); a function jitted
earlier in the worker may keep its code when called again (the same numbers, slower).

**XLA flags** (``shared_files.SUITE_XLA_FLAGS``, in ``XLA_FLAGS`` here and in the processes
the tests start): XLA's CPU backend without its MLIR fusion emitters, each program in one LLVM
module instead of split for parallel code generation, and optimisation level 1 without LLVM's
expensive passes where JAX's flag is off (``optimised`` tests). At level 0 the first two
compile the default COGNet-DICE iteration in 2.2-2.6 s instead of 3.2-3.6 s, and it then runs
in 61-65 ms instead of 190-250 ms (2-core CPU; the suite went 519 s -> 414-460 s; with the
optimised tests at level 1 and every program of a run compiled once per worker, 285-389 s).
The older emitters may round differently where two forms of one computation are compared bit
for bit: such a test compiles its programs with XLA's default emitters (a compiler option,
tests/test_neural.py).
"""

import gc
import os
import shutil
import tempfile
from pathlib import Path

import pytest
from shared_files import compile_cache_env, with_suite_xla_flags

#: JAX's flag (and its environment variable, read when JAX is imported and by subprocesses)
FAST_COMPILE = "JAX_DISABLE_MOST_OPTIMIZATIONS"
os.environ[FAST_COMPILE] = "1"
os.environ.update(with_suite_xla_flags(dict(os.environ)))

import jax  # noqa: E402

from cognet_jax.cli import GC_THRESHOLDS  # noqa: E402

jax.config.update("jax_disable_most_optimizations", True)  # (should JAX be imported already)
_CACHE = Path(tempfile.mkdtemp(prefix="cognet-jax-test-cache-"))
jax.config.update("jax_compilation_cache_dir", str(_CACHE))
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
# every process a test starts uses this folder too, unless the test chooses (the command line's
# own default, ~/.cache/cognet-jax, is never read or written: a warm one would make the suite
# faster here than on a fresh machine)
os.environ.update(compile_cache_env())
os.environ["COGNET_JAX_CACHE"] = str(_CACHE)

# Python's garbage collector as seldom as in the executable (``cli.GC_THRESHOLDS``): three
# heavy test files (test_engine, test_polish, test_heatmap_cognet) ran 4-6 % faster, beside
# the old thresholds on the other core; the whole suite on one worker each, both at once,
# took 396 s of CPU with them (and two smaller tests) against 422 s. It changes no number.
gc.set_threshold(*GC_THRESHOLDS)


#: the test files taking 5 s or more, longest first (seconds of test time, both workers, on the
#: 2-core CPU, 2026-12-02, ``pytest --durations=0``; the three marked were cut after it): run
#: in this order, the rest after them. With ``--dist loadfile`` and ``--no-loadscope-reorder``
#: (pyproject.toml) xdist hands the files out in this order (the next one to a worker with at
#: most 2 of its tests left), so the long files start early and short ones fill the end; by
#: default it orders them by their number of tests, and a long file with few tests could start
#: last (the list of 2026-11-27 had grown stale: the fuzz, listed at 6 s, took 125 s).
LONGEST_FIRST = {
    name: rank
    for rank, name in enumerate(
        (
            "test_sweep.py",  # 198
            "test_cognet_weights.py",  # 147
            "test_compile_cache.py",  # 140 (cut: one first run for the file)
            "test_fuzz.py",  # 125 (cut: every field of a section's kind once, 88 s -> 45 s)
            "test_run_folder.py",  # 53
            "test_signals.py",  # 45
            "test_gdice_defaults.py",  # 45
            "test_one_truth.py",  # 44
            "test_engine.py",  # 44
            "test_cognet_thesis.py",  # 41
            "test_config_cli.py",  # 55 (cut: the suite's experiments loaded in one file only)
            "test_torch_reference.py",  # 39
            "test_suite_envs.py",  # 39
            "test_weight_polish.py",  # 36
            "test_memory.py",  # 36
            "test_neural.py",  # 36
            "test_checkpoint.py",  # 35
            "test_polish.py",  # 35
            "test_models.py",  # 35
            "test_torch_weights.py",  # 34
            "test_registry.py",  # 31
            "test_cli_errors.py",  # 30
            "test_heatmap_cognet.py",  # 28
            "test_vae.py",  # 27
            "test_build_once.py",  # 27
            "test_plugin.py",  # 25
            "test_hostile_round7.py",  # 24
            "test_hostile_inputs.py",  # 22
            "test_rollout.py",  # 22
            "test_controller_step.py",  # 21
            "test_prng.py",  # 20
            "test_shard_rollouts.py",  # 20
            "test_gdice.py",  # 12
            "test_cogdice.py",  # 9
            "test_best_response.py",  # 7
            "test_tabular_env.py",  # 7
            "test_heatmap.py",  # 6
            "test_large_dpomdp.py",  # 5
        )
    )
}


def pytest_collection_modifyitems(items):
    """The files in ``LONGEST_FIRST`` order (a stable sort: each file's tests keep theirs)."""
    items.sort(key=lambda item: LONGEST_FIRST.get(item.path.name, len(LONGEST_FIRST)))


def pytest_configure(config):
    config.addinivalue_line(
        "markers",
        "optimised: its time is execution, not compilation: compiled at XLA's optimisation "
        "level 1 (conftest.py)",
    )


@pytest.hookimpl(wrapper=True)
def pytest_runtest_call(item):
    """An ``optimised`` test compiles at the level ``SUITE_XLA_FLAGS`` set (1, without LLVM's
    expensive passes), here and in its subprocesses."""
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


@pytest.fixture(autouse=True)
def _foreign_code_per_test():
    """A test that runs ``--import`` in this process records the module as foreign code
    (``registry.note_foreign_code``: no kept programs, policies record it); the record is
    the test's own, so later tests of the worker keep their programs as a fresh process does."""
    from cognet_jax import registry

    saved, late = dict(registry._FOREIGN_CODE), list(registry.LATE_IMPORTS)
    saved_late = dict(registry._LATE_CODE)
    yield
    registry._FOREIGN_CODE.clear()
    registry._FOREIGN_CODE.update(saved)
    registry._LATE_CODE.clear()
    registry._LATE_CODE.update(saved_late)
    registry.LATE_IMPORTS[:] = late  # (the scan of modules imported after an --import)
