"""Cycles per agent-step of each part of a rollout, alone and together, for the paper-budget
and 3-node rooflines of benchmarks/NOTES.md.

    python -m benchmarks.paper_roofline                 # COGNet-DICE and COG-DICE, paper setting
    python -m benchmarks.paper_roofline --rollouts 3 6  # the rollout benchmark (h 3, 1e5)

Each part runs alone as a compiled ``lax.scan`` over the horizon on the batch the search rolls
out (candidates x rollouts, or the rollout benchmark's 1e5), with what it reads carried from
step to step so that XLA cannot hoist it out of the loop:

- **random numbers**: the per-step block of uniforms ``[rollouts, 2 agents + noise]`` the
  rollouts draw (``rollout.rollouts``; shared by all candidates, common random numbers);
- **action draw**: ``controller.act`` for every agent;
- **network and node draw**: ``controller.next_node`` (COGNet-DICE: the current node's network,
  its weights picked from the members, up to ``neural.AGENTS_MAJOR_MAX_NODES`` nodes, or every
  member network of the agent beyond; softmax, inverse-CDF draw; COG-DICE: the region of the
  observation and its next node);
- **simulator**: the tagging step;
- **rollouts**: the real thing (``rollout.evaluate_candidates``), and **iteration**: one
  compiled ``step`` of the search (the rest is selection and update).

Cycles are ``seconds x logical CPUs x clock / agent-steps`` at the clock /proc/cpuinfo reports.
The parts alone need not add up to the rollouts: in the rollouts XLA fuses them (less memory
traffic) and schedules them on both cores together. Beside each part: the operations XLA's
cost analysis counts per agent-step and the cycles they take at the float32 matmul peak
measured first (``jax_cases.machine_peak``, fused multiply-adds counted as 2), the compute
bound of those operations. XLA counts a loop's body once: one time step of the scan over the
horizon (and, where a controller scans over its members, one member network instead of all of
them).
Likewise the bytes XLA counts between its kernels per agent-step, and the cycles they take at
the streaming bandwidth (every byte from main memory). The whole iteration, loops in loops,
has none of these columns.
"""

from __future__ import annotations

import argparse
import os

import jax
import jax.numpy as jnp

from benchmarks.jax_cases import machine_peak
from benchmarks.timing import time_jax

#: (label, experiment): one chunk of candidates of each -full experiment as its iteration
#: evaluates them (run.memory_gb)
EXPERIMENTS = [
    ("COGNet-DICE", "tagging-paper-cognet-full"),
    ("COG-DICE", "tagging-paper-cogdice-full"),
]


def clock_hz() -> float:
    """The clock /proc/cpuinfo reports (first core), 0 when unknown."""
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("cpu MHz"):
                return float(line.split(":")[1]) * 1e6
    except OSError:
        pass
    return 0.0


def parts(env, ctrl, params, policies, candidates: int, num: int) -> dict:
    """Functions ``key -> result`` of each part alone, over ``candidates x num`` rollouts
    (``policies``: leading ``[candidates]`` axis, or one policy when ``candidates`` is 0)."""
    from cognet_jax.prng import fast_key
    from cognet_jax.rollout import evaluate_candidates, rollouts

    n, h = env.num_agents, env.horizon
    width = 2 * n + env.step_noise
    batch = (candidates,) if candidates else ()

    def batched(f, axes):
        """``f`` over rollouts (``axes``), then over candidates (the uniforms shared)."""
        f = jax.vmap(f, axes)
        if candidates:
            f = jax.vmap(f, (None,) + (0,) * (len(axes) - 1))
        return f

    def scan(body, init, key):
        return jax.lax.scan(lambda c, k: (body(c, k), None), init, jax.random.split(key, h))[0]

    u = jax.random.uniform(jax.random.key(7), (num, width))  # shared by the candidates
    reset_u = jax.random.uniform(jax.random.key(8), (num, env.reset_noise))
    states = jax.vmap(env.reset, (0, None))(reset_u, params)
    states = jax.tree.map(lambda x: jnp.broadcast_to(x, (*batch, *x.shape)), states)
    zeros = jnp.zeros((*batch, num, n), jnp.int32)
    obs = jnp.broadcast_to(u[:, n : 2 * n] - 0.5, (*batch, num, n))

    def act(nodes, k):
        f = batched(ctrl.act, (0, None, 0))
        return f(u[:, :n], policies, nodes) % ctrl.num_nodes

    def next_node(carry, k):
        nodes, o = carry
        f = batched(ctrl.next_node, (0, None, 0, 0))
        return f(u[:, n : 2 * n], policies, nodes, o), -o

    def simulate(carry, k):
        s, actions = carry
        f = batched(lambda uu, st, a: env.step(uu, st, a, params), (0, 0, 0))
        s, _, reward = f(u[:, 2 * n :], s, actions)
        return s, (actions + 1 + (reward > 0)[..., None]) % env.num_actions

    def draw(block, k):
        return jax.random.uniform(fast_key(k), (num, width)) + block[0, 0] * 0

    def roll(k):
        if candidates:
            return evaluate_candidates(env, ctrl, k, num, params, policies, memory=2**62)
        return rollouts(env, ctrl, k, num, params, policies)

    return {
        "random numbers": lambda k: scan(draw, jnp.zeros((num, width)), k),
        "action draw": lambda k: scan(act, zeros, k),
        "network and node draw": lambda k: scan(next_node, (zeros, obs), k),
        "simulator": lambda k: scan(simulate, (states, zeros), k),
        "rollouts": roll,
    }


def cycles(seconds: float, steps: float, hz: float) -> str:
    """``seconds`` of both CPUs as cycles per agent-step ("-" when the clock is unknown)."""
    return f"{seconds * (os.cpu_count() or 1) * hz / steps:.1f}" if hz else "-"


def timed_row(name: str, fn, args: tuple, steps: int, calls: int, hz: float, cost=None) -> str:
    """``| name | ms | cycles per agent-step | flops | their cycles | bytes | their cycles |``
    of the median call of ``jax.jit(fn)`` (after the benchmark runner's warm-up,
    ``timing.time_jax``), printed as it is measured: XLA's counts per agent-step and the
    cycles they take at the machine's peaks. ``cost``: ``(agent-steps of one loop body,
    machine_peak())``, or None for no cost columns."""
    timing = time_jax(fn, *args, runs=calls)
    seconds = timing.median_s
    counts = ["-"] * 4
    if cost is not None:
        per_body, peak = cost
        flops = timing.cost["flops"] / per_body
        moved = timing.cost["bytes accessed"] / per_body
        counts = [
            f"{flops:.0f}",
            cycles(flops / (peak["matmul_gflops"] * 1e9), 1, hz),
            f"{moved:.0f}",
            cycles(moved / (peak["bandwidth_gbs"] * 1e9), 1, hz),
        ]
    row = f"| {name} | {seconds * 1e3:.1f} | {cycles(seconds, steps, hz)} | {' | '.join(counts)} |"
    print(f"  {row}", flush=True)
    return row


def measure_parts(
    label, env, ctrl, params, policies, candidates, num, calls, hz, peak
) -> list[str]:
    """Table rows of every part (``timed_row``; ``peak``: ``jax_cases.machine_peak()``)."""
    per_body = max(candidates, 1) * num * env.num_agents  # agent-steps of one time step
    steps = per_body * env.horizon
    return [
        timed_row(f"{label}: {name}", fn, (jax.random.key(1),), steps, calls, hz, (per_body, peak))
        for name, fn in parts(env, ctrl, params, policies, candidates, num).items()
    ]


def paper_rows(
    label: str, experiment: str, sets: list[str], calls: int, hz: float, peak: dict
) -> list[str]:
    """Every part of one chunk of candidates of ``experiment``'s iteration, and the iteration."""
    from cognet_jax.api import build_algorithm
    from cognet_jax.memory import candidate_chunk
    from cognet_jax.registry import load_config
    from cognet_jax.rollout import rollouts

    algorithm, params = build_algorithm(load_config(experiment, sets))
    state = algorithm.init(jax.random.key(0), params)
    _, policies = algorithm.ask(jax.random.key(1), state, params)
    env, ctrl, s = algorithm.env, algorithm.controller, algorithm.settings
    count = jax.tree.leaves(policies)[0].shape[0]
    chunk = candidate_chunk(
        lambda k, p, n, e: rollouts(env, ctrl, k, n, e, p),
        params.env,
        jax.tree.map(lambda x: x[0], policies),
        count,
        s.eval_rollouts,
        algorithm.memory,
    )
    chunk = min(chunk, count)
    sub = jax.tree.map(lambda x: x[:chunk], policies)
    rows = measure_parts(
        f"{label} ({chunk} candidates x {s.eval_rollouts})",
        env,
        ctrl,
        params.env,
        sub,
        chunk,
        s.eval_rollouts,
        calls,
        hz,
        peak,
    )
    steps = algorithm.rollouts_per_iteration * env.horizon * env.num_agents
    iteration = lambda k, st: algorithm.step(k, st, params)  # noqa: E731
    name = f"{label}: whole iteration ({count} candidates)"
    rows.append(timed_row(name, iteration, (jax.random.key(1), state), steps, calls, hz))
    return rows


def rollout_rows(nodes: int, calls: int, hz: float, peak: dict) -> list[str]:
    """Every part of the rollout benchmark's case (benchmarks.jax_cases.rollout_throughput)."""
    from cognet_jax.controllers.neural import NeuralController
    from cognet_jax.envs.tagging import make_tagging

    env, params = make_tagging("thesis")
    ctrl = NeuralController(env.num_agents, nodes, env.num_actions)
    policy = ctrl.init(jax.random.key(0))
    label = f"rollouts, {nodes} nodes, h 3, 1e5"
    return measure_parts(label, env, ctrl, params, policy, 0, 100_000, calls, hz, peak)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=5)
    parser.add_argument("--set", action="append", default=[], help="a config override, both")
    parser.add_argument("--rollouts", type=int, nargs="+", metavar="NODES")
    args = parser.parse_args()
    hz = clock_hz()
    peak = machine_peak()
    print(
        f"float32 matmul peak {peak['matmul_gflops']:.0f} GFLOP/s, "
        f"streaming bandwidth {peak['bandwidth_gbs']:.1f} GB/s",
        flush=True,
    )
    lines = [
        "| part | ms per call | cycles per agent-step | XLA flops per agent-step "
        "| their cycles at the matmul peak | XLA bytes per agent-step "
        "| their cycles at the bandwidth |",
        "|---|---|---|---|---|---|---|",
    ]
    if args.rollouts:
        for nodes in args.rollouts:
            lines += rollout_rows(nodes, max(args.calls, 15), hz, peak)
    else:
        for label, experiment in EXPERIMENTS:
            lines += paper_rows(label, experiment, args.set, args.calls, hz, peak)
    print(f"\n{os.cpu_count()} logical CPUs at {hz / 1e9:.2f} GHz (/proc/cpuinfo)\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
