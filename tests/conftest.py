"""Test-session set-up: a compilation cache shared by the tests of one session, so programs
with identical HLO (the same small config built twice) are compiled once."""

import tempfile

import jax

_CACHE = tempfile.mkdtemp(prefix="cognet-jax-test-cache-")
jax.config.update("jax_compilation_cache_dir", _CACHE)
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
