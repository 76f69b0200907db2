"""What the benchmark runner measures on the PyTorch side: the two references of
``benchmarks/torch_reference`` (loop and vectorised) on the same work as the JAX cases.

``torch.set_num_threads`` is left at torch's default (all cores). The loop version is timed at
1,000 rollouts only: its cost is a Python loop per rollout and per step, so its per-rollout time
does not depend on the batch size, and larger sizes are extrapolated from it (marked so).
"""

from __future__ import annotations

import statistics
import time

from benchmarks.timing import Timing


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
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return Timing(statistics.median(times), min(times), max(times), runs)


def _reference(impl: str, nodes: int):
    from benchmarks.torch_reference import CognetSettings, TorchCognetLoop, TorchCognetVectorized

    cls = TorchCognetLoop if impl == "torch-loop" else TorchCognetVectorized
    settings = CognetSettings(
        nodes=nodes, rollouts=1000, top=100, keep=10, eval_rollouts=100, hidden=10
    )
    return cls(settings, seed=0)


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
