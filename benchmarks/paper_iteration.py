"""One iteration at the COG-DICE paper setting (h 150, respawn) for the paper-budget notes in
benchmarks/NOTES.md: seconds per compiled iteration of COGNet-DICE and COG-DICE at 200 and 2000
candidates, with candidate chunks (``run.memory_gb``) and each random generator.

    python -m benchmarks.paper_iteration          # prints a markdown table (about 5 minutes)
"""

from __future__ import annotations

import statistics
import time

import jax

#: (label, experiment, overrides)
CASES = [
    (
        "COGNet-DICE, 200 candidates x 1000 rollouts",
        "tagging-paper-cognet",
        ["algorithm.candidates=200", "algorithm.eval_rollouts=1000", "algorithm.elites=10"],
    ),
    (
        "COG-DICE, 200 samples x 1000 rollouts",
        "tagging-paper-cogdice",
        ["algorithm.samples=200", "algorithm.eval_rollouts=1000", "algorithm.elites=10"],
    ),
    (
        "COGNet-DICE, 2000 x 1000, all candidates at once",
        "tagging-paper-cognet-full",
        ["run.memory_gb=0"],
    ),
    (
        "the same, `run.memory_gb = 0.05` (the experiment's setting)",
        "tagging-paper-cognet-full",
        [],
    ),
    ("the same, `run.memory_gb = 0.01`", "tagging-paper-cognet-full", ["run.memory_gb=0.01"]),
    (
        "`run.memory_gb = 0.05`, threefry2x32",
        "tagging-paper-cognet-full",
        ['run.prng_impl="threefry2x32"'],
    ),
    ("`run.memory_gb = 0.05`, hash", "tagging-paper-cognet-full", ['run.prng_impl="hash"']),
    (
        "COG-DICE, 2000 x 1000, all samples at once",
        "tagging-paper-cogdice-full",
        ["run.memory_gb=0"],
    ),
    (
        "COG-DICE, 2000 x 1000, `run.memory_gb = 0.02` (the experiment's setting)",
        "tagging-paper-cogdice-full",
        [],
    ),
    ("the same, `run.memory_gb = 0.05`", "tagging-paper-cogdice-full", ["run.memory_gb=0.05"]),
]


def seconds_per_iteration(experiment: str, sets: list[str], calls: int = 3) -> tuple[float, int]:
    """Median seconds of ``calls`` compiled iterations after a warm-up one, and the
    agent-steps one iteration simulates."""
    from cognet_jax.api import make_step
    from cognet_jax.registry import load_config

    algorithm, params, step = make_step(load_config(experiment, sets))
    state = algorithm.init(jax.random.key(0), params)
    # the params are constants of the program, as the command line compiles it
    compiled = jax.jit(lambda k, s: step(k, s, params)).lower(jax.random.key(1), state).compile()
    state, metrics = compiled(jax.random.key(1), state)
    jax.block_until_ready(metrics)
    times = []
    for i in range(calls):
        t0 = time.perf_counter()
        state, metrics = compiled(jax.random.key(2 + i), state)
        jax.block_until_ready(metrics)
        times.append(time.perf_counter() - t0)
    env = algorithm.env
    steps = algorithm.rollouts_per_iteration * env.horizon * env.num_agents
    return statistics.median(times), steps


def main() -> None:
    print("| case (one iteration, h 150) | s per iteration | M agent-steps/s |")
    print("|---|---|---|")
    for label, experiment, sets in CASES:
        seconds, steps = seconds_per_iteration(experiment, sets)
        print(f"| {label} | {seconds:.2f} | {steps / seconds / 1e6:.0f} |", flush=True)


if __name__ == "__main__":
    main()
