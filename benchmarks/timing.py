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
    #: XLA's cost analysis of the compiled program (``time_jax``): "flops", "bytes accessed", ...
    cost: dict | None = None

    def row(self) -> str:
        return f"{self.median_s * 1e3:.2f} ms ({self.min_s * 1e3:.2f}-{self.max_s * 1e3:.2f})"


#: Before timing, calls are repeated until at least this much wall time has passed (after the
#: ``warmup`` calls): on this 2-core VM a process that was idle for a few seconds runs its
#: next ~0.1 s of calls up to 1.6x slower (benchmarks/NOTES.md, "Fifth pass"). Both the JAX
#: and the torch measurements warm up this way.
WARMUP_S = 0.5


def warm_up(fn: Callable[[], object], calls: int = 1, seconds: float = WARMUP_S) -> None:
    """Call ``fn()`` ``calls`` times, then again until ``seconds`` of wall time have passed."""
    t0 = time.perf_counter()
    for _ in range(calls):
        jax.block_until_ready(fn())
    while time.perf_counter() - t0 < seconds:
        jax.block_until_ready(fn())


def time_calls(fn: Callable[[], object], runs: int = 5, warmup: int = 1) -> Timing:
    """Median / min / max wall time of ``fn()`` (outputs blocked until ready), after
    ``warmup`` calls and at least ``WARMUP_S`` seconds of calls (``warmup=0``: none)."""
    if warmup:
        warm_up(fn, warmup)
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - t0)
    return Timing(statistics.median(times), min(times), max(times), runs)


def time_jax(fn, *args, runs: int = 5) -> Timing:
    """Compile ``jax.jit(fn)`` ahead of time (timed apart, its cost analysis kept), then time
    calls on ``args``."""
    t0 = time.perf_counter()
    compiled = jax.jit(fn).lower(*args).compile()
    compile_s = time.perf_counter() - t0
    timing = time_calls(lambda: compiled(*args), runs=runs)
    timing.compile_s, timing.cost = compile_s, compiled.cost_analysis()
    return timing


def peak_rss_mib() -> float:
    """Peak resident memory of this process so far (MiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
