"""Timing helpers: median of repeated runs after warm-up, compile time apart, peak memory."""

from __future__ import annotations

import resource
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass

import jax


@dataclass
class Timing:
    median_s: float
    min_s: float
    max_s: float
    runs: int
    compile_s: float | None = None

    def row(self) -> str:
        return f"{self.median_s * 1e3:.2f} ms ({self.min_s * 1e3:.2f}-{self.max_s * 1e3:.2f})"


def time_calls(fn: Callable[[], object], runs: int = 5, warmup: int = 1) -> Timing:
    """Median / min / max wall time of ``fn()`` (outputs blocked until ready)."""
    for _ in range(warmup):
        jax.block_until_ready(fn())
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - t0)
    return Timing(statistics.median(times), min(times), max(times), runs)


def time_jax(fn, *args, runs: int = 5) -> Timing:
    """Compile ``jax.jit(fn)`` ahead of time (timed apart), then time calls on ``args``."""
    t0 = time.perf_counter()
    compiled = jax.jit(fn).lower(*args).compile()
    compile_s = time.perf_counter() - t0
    timing = time_calls(lambda: compiled(*args), runs=runs)
    timing.compile_s = compile_s
    return timing


def peak_rss_mib() -> float:
    """Peak resident memory of this process so far (MiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
