"""Benchmark runner: ``python -m benchmarks [--quick|--full]``.

Measures, in one process, JAX (cognet_jax) against the PyTorch references of
``benchmarks/torch_reference`` (when torch is installed) on the same machine and the same work,
then writes ``benchmarks/README.md`` (generated) and ``benchmarks/results.json``:

* rollout throughput (agent-steps/s) on tagging (thesis setting, h = 3) with 3- and 6-node neural
  controllers at 1e3, 1e4, 1e5 rollouts;
* one COGNet-DICE iteration at the thesis settings;
* time-to-value: a full ``tagging-thesis-n3`` run (500 iterations) vs the references'
  per-iteration time x 500 (extrapolated);
* scaling of the iteration time with rollouts, horizon and nodes (``--full``; PNG).

Every timing is the median of >= 5 runs after a warm-up, min-max beside it, compile time apart.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import jax

from benchmarks.timing import peak_rss_mib, time_calls, time_jax

HERE = Path(__file__).resolve().parent


def jax_rollout_throughput(nodes: int, num: int, runs: int):
    from cognet_jax.controllers.neural import NeuralController
    from cognet_jax.envs.tagging import make_tagging
    from cognet_jax.rollout import rollouts

    env, params = make_tagging("thesis")
    ctrl = NeuralController(env.num_agents, nodes, env.num_actions)
    policy = ctrl.init(jax.random.key(0))
    timing = time_jax(
        lambda k: rollouts(env, ctrl, k, num, params, policy), jax.random.key(1), runs=runs
    )
    agent_steps = num * env.horizon * env.num_agents
    return timing, agent_steps / timing.median_s


def jax_iteration(nodes: int, runs: int, **overrides):
    from cognet_jax.api import make_step
    from cognet_jax.config import load_config

    sets = [f"algorithm.nodes={nodes}"] + [f"{k}={v}" for k, v in overrides.items()]
    config = load_config("tagging-thesis-n3", sets)
    _, init, step = make_step(config)
    state = init(jax.random.key(0))
    key = jax.random.key(1)
    t0 = time.perf_counter()
    compiled = jax.jit(step).lower(key, state).compile()
    compile_s = time.perf_counter() - t0
    holder = {"state": state}

    def one():
        holder["state"], metrics = compiled(key, holder["state"])
        return metrics

    timing = time_calls(one, runs=runs)
    timing.compile_s = compile_s
    return timing


def jax_full_run():
    from cognet_jax.config import load_config
    from cognet_jax.runner import run_training

    config = load_config("tagging-thesis-n3", ["run.plots=false", "run.progress=false"])
    out = HERE / ".last_full_run"
    t0 = time.perf_counter()
    results = run_training(config, 0, out, log=lambda *_: None)
    return time.perf_counter() - t0, results


def machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    py = platform.python_version()
    return f"{cpu}, {os.cpu_count()} cores, Python {py}, jax {jax.__version__}"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description="cognet_jax benchmarks")
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--quick", action="store_true", help="fewer sizes and runs")
    mode.add_argument("--full", action="store_true", help="also the scaling curves")
    p.add_argument("--no-write", action="store_true", help="print only")
    args = p.parse_args(argv)
    runs = 5
    sizes = [1_000, 10_000] if args.quick else [1_000, 10_000, 100_000]
    out: dict = {
        "machine": machine(),
        "command": "python -m benchmarks"
        + (" --quick" if args.quick else " --full" if args.full else ""),
        "rollouts": [],
        "iteration": [],
    }

    for nodes in (3, 6):
        for num in sizes:
            timing, rate = jax_rollout_throughput(nodes, num, runs)
            row = dict(
                impl="jax",
                nodes=nodes,
                rollouts=num,
                median_s=timing.median_s,
                min_s=timing.min_s,
                max_s=timing.max_s,
                compile_s=timing.compile_s,
                agent_steps_per_s=rate,
            )
            out["rollouts"].append(row)
            print(
                f"rollouts jax nodes={nodes} R={num}: {timing.row()}, "
                f"{rate / 1e6:.2f} M agent-steps/s, compile {timing.compile_s:.2f} s"
            )
    for nodes in (3, 6):
        timing = jax_iteration(nodes, runs=10)
        out["iteration"].append(
            dict(
                impl="jax",
                nodes=nodes,
                median_s=timing.median_s,
                min_s=timing.min_s,
                max_s=timing.max_s,
                compile_s=timing.compile_s,
            )
        )
        print(f"iteration jax nodes={nodes}: {timing.row()}, compile {timing.compile_s:.2f} s")
    wall, results = jax_full_run()
    out["full_run"] = dict(
        impl="jax",
        wall_s=wall,
        compile_s=results["compile_s"],
        loop_s=results["loop_s"],
        final_value=results["final_value"],
    )
    print(
        f"full tagging-thesis-n3 run: {wall:.1f} s wall (compile {results['compile_s']:.1f} s, "
        f"500 iterations {results['loop_s']:.1f} s)"
    )
    out["peak_rss_mib"] = peak_rss_mib()
    if not args.no_write:
        (HERE / "results.json").write_text(json.dumps(out, indent=1))
        print(f"wrote {HERE / 'results.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
