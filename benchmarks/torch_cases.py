"""What the benchmark runner measures on the PyTorch side: the two references of
``benchmarks/torch_reference`` (loop and vectorised) on the same work as the JAX cases.

``torch.set_num_threads`` is left at torch's default (all cores). Three references: eager
vectorised, the same with each time step compiled by ``torch.compile`` (inductor), and the loop
version, timed up to 1e4 rollouts (its cost is a Python loop per rollout and per step, so larger
batches are extrapolated from 1e4, marked so in the report).
"""

from __future__ import annotations

import statistics
import time

from benchmarks.timing import Timing, warm_up


def available() -> bool:
    try:
        import torch  # noqa: F401
    except ImportError:
        return False
    return True


def version() -> str:
    import torch

    return f"torch {torch.__version__} ({torch.get_num_threads()} threads)"


def _time(fn, runs: int, warmup: int = 1) -> Timing:
    """Median of ``runs`` calls after ``warmup`` calls and at least ``WARMUP_S`` seconds of
    further calls (as on the JAX side); ``compile_s`` is the first warm-up call's time minus
    the median (``torch.compile``'s compilation happens there)."""
    t0 = time.perf_counter()
    for _ in range(warmup):
        fn()
    first = time.perf_counter() - t0
    if warmup:
        warm_up(fn, calls=0)
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    median = statistics.median(times)
    compile_s = max(first / warmup - median, 0.0) if warmup else None
    return Timing(median, min(times), max(times), runs, compile_s)


def _reference(impl: str, nodes: int):
    from benchmarks.torch_reference import (
        CognetSettings,
        TorchCognetCompiled,
        TorchCognetLoop,
        TorchCognetVectorized,
    )

    cls = {
        "torch-loop": TorchCognetLoop,
        "torch-vectorized": TorchCognetVectorized,
        "torch-compiled": TorchCognetCompiled,
    }[impl]
    settings = CognetSettings(
        nodes=nodes, rollouts=1000, top=100, keep=10, eval_rollouts=100, hidden=10
    )
    return cls(settings, seed=0)


def rollout_call(impl: str, nodes: int, num: int):
    """``call()``: ``rollout_throughput``'s work once (the first call compiles)."""
    algo = _reference(impl, nodes)
    return lambda: algo.rollout_returns(num)


def rollout_throughput(impl: str, nodes: int, num: int, runs: int) -> tuple[Timing, float]:
    """Timing of ``num`` rollouts of the current policy (tagging, thesis setting, h 3) and
    agent-steps per second."""
    from benchmarks.torch_reference import make_tagging

    env = make_tagging("thesis")
    algo = _reference(impl, nodes)
    timing = _time(lambda: algo.rollout_returns(num), runs)
    return timing, num * env.horizon * env.num_agents / timing.median_s


def iteration(impl: str, nodes: int, runs: int) -> Timing:
    """Timing of one full COGNet-DICE iteration at the thesis settings (the loop version:
    ``runs`` iterations without warm-up, each takes seconds)."""
    algo = _reference(impl, nodes)
    return _time(algo.step, runs, warmup=0 if impl == "torch-loop" else 1)
