"""Stand-alone timings of the PyTorch references (``python -m benchmarks.torch_reference.measure``).

* seconds per COGNet-DICE iteration at the thesis settings (3 nodes, rollouts 1000, top 100,
  keep 10, eval_rollouts 100, hidden 10, h = 3), loop and vectorised;
* rollout throughput (agent-steps/s = rollouts * horizon * agents / seconds) with 6-node
  controllers at 1e3 and 1e4 rollouts (the loop version at 1e3 only).

``torch.set_num_threads`` is left at its default unless ``--threads`` is given. Each timing is the
median of ``--runs`` calls after one warm-up call (the loop iteration: ``--loop-iters`` calls,
no warm-up beyond a small step).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time

import torch

from benchmarks.torch_reference import (
    CognetSettings,
    TorchCognetLoop,
    TorchCognetVectorized,
    make_tagging,
)

THESIS = CognetSettings(nodes=3, rollouts=1000, top=100, keep=10, eval_rollouts=100, hidden=10)


def _times(fn, runs: int, warmup: int = 1) -> list[float]:
    for _ in range(warmup):
        fn()
    out = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return out


def _summary(times: list[float]) -> dict:
    return dict(
        median_s=statistics.median(times), min_s=min(times), max_s=max(times), runs=len(times)
    )


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--threads", type=int, default=None, help="torch.set_num_threads (default: leave)"
    )
    ap.add_argument("--loop-iters", type=int, default=2)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--skip-loop", action="store_true")
    ap.add_argument("--json", default=None, help="write the results here")
    args = ap.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    env = make_tagging("thesis")
    agent_steps = env.horizon * env.num_agents
    res = dict(
        torch=torch.__version__,
        threads=torch.get_num_threads(),
        cpus=os.cpu_count(),
        load_avg_before=os.getloadavg(),
    )

    vec = TorchCognetVectorized(THESIS, seed=0)
    res["vectorized_iteration"] = _summary(_times(vec.step, args.runs))
    print("vectorized iteration", res["vectorized_iteration"], flush=True)

    six = CognetSettings(nodes=6, hidden=10)
    vec6 = TorchCognetVectorized(six, seed=0)
    for num in (1_000, 10_000):
        t = _summary(_times(lambda n=num: vec6.rollout_returns(n), args.runs))
        t["agent_steps_per_s"] = num * agent_steps / t["median_s"]
        res[f"vectorized_rollouts_{num}"] = t
        print(f"vectorized {num} rollouts", t, flush=True)

    if not args.skip_loop:
        loop6 = TorchCognetLoop(six, seed=0)
        t = _summary(_times(lambda: loop6.rollout_returns(1_000), max(1, args.runs // 2)))
        t["agent_steps_per_s"] = 1_000 * agent_steps / t["median_s"]
        t["extrapolated_10000_s"] = 10 * t["median_s"]
        res["loop_rollouts_1000"] = t
        print("loop 1000 rollouts", t, flush=True)

        loop = TorchCognetLoop(THESIS, seed=0)
        per_iter = _times(loop.step, args.loop_iters, warmup=0)
        res["loop_iteration"] = _summary(per_iter)
        res["loop_iteration"]["extrapolated_500_iterations_min"] = (
            500 * statistics.median(per_iter) / 60
        )
        print("loop iteration", res["loop_iteration"], flush=True)

    res["load_avg_after"] = os.getloadavg()
    if args.json:
        with open(args.json, "w") as f:
            json.dump(res, f, indent=2)
    return res


if __name__ == "__main__":
    main()
