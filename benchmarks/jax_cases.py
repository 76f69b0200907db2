"""What the benchmark runner measures on the JAX side (cognet_jax): rollout throughput, one
search iteration of each algorithm, a full run, and iteration time / memory at other sizes."""

from __future__ import annotations

import time
from pathlib import Path

import jax

from benchmarks.timing import Timing, time_calls, time_jax

HERE = Path(__file__).resolve().parent


def _rollout_case(nodes: int, num: int, prng: str):
    """``(fn, args, agent-steps)`` of the rollout benchmark: ``fn(*args)`` runs ``num``
    rollouts of a random ``nodes``-node neural controller on tagging (thesis setting, h 3)
    from a ``prng`` key (``run.prng_impl``)."""
    from cognet_jax.controllers.neural import NeuralController
    from cognet_jax.envs.tagging import make_tagging
    from cognet_jax.prng import make_key
    from cognet_jax.rollout import rollouts

    env, params = make_tagging("thesis")
    ctrl = NeuralController(env.num_agents, nodes, env.num_actions)
    policy = ctrl.init(jax.random.key(0))
    # the policy is an argument of the compiled program, as in the search (a constant would let
    # XLA fold it into the program)
    fn = lambda k, pol: rollouts(env, ctrl, k, num, params, pol)  # noqa: E731
    return fn, (make_key(1, prng), policy), num * env.horizon * env.num_agents


def rollout_throughput(
    nodes: int, num: int, runs: int, prng: str = "threefry2x32"
) -> tuple[Timing, float]:
    """Timing of ``num`` rollouts of a random ``nodes``-node neural controller on tagging
    (thesis setting, h 3), and agent-steps per second (``num * horizon * agents / median``);
    the policy is passed to the compiled program as an argument.
    ``prng``: the ``run.prng_impl`` whose key drives the rollouts."""
    fn, args, steps = _rollout_case(nodes, num, prng)
    timing = time_jax(fn, *args, runs=runs)
    return timing, steps / timing.median_s


def rollout_call(nodes: int, num: int, prng: str = "threefry2x32"):
    """``call()``: one compiled call of ``rollout_throughput``'s program (outputs ready)."""
    fn, args, _ = _rollout_case(nodes, num, prng)
    compiled = jax.jit(fn).lower(*args).compile()
    return lambda: jax.block_until_ready(compiled(*args))


#: controller kind -> (experiment whose controller and env are used, overrides): tagging with
#: the thesis horizon 3; the tabular controller reads the observation discretised by 1
CONTROLLER_KINDS = {
    "neural (COGNet-DICE)": ("tagging-thesis-spec-n3", []),
    "regions (COG-DICE)": ("tagging-thesis-cogdice-n3", []),
    "tabular (G-DICE, d = 1)": ("tagging-paper-gdice-d1", ["env.horizon=3"]),
}


def controller_case(kind: str, nodes: int):
    """``(env, params, controller, policy)`` of one controller kind of ``CONTROLLER_KINDS``:
    one controller drawn from the algorithm's initial distribution."""
    from cognet_jax.api import build_algorithm
    from cognet_jax.registry import load_config

    experiment, sets = CONTROLLER_KINDS[kind]
    algorithm, search_params = build_algorithm(
        load_config(experiment, [*sets, f"algorithm.nodes={nodes}"])
    )
    env, params, ctrl = algorithm.env, search_params.env, algorithm.controller
    if kind.startswith("neural"):
        policy = ctrl.init(jax.random.key(0))
    elif kind.startswith("regions"):
        sample = algorithm.draw(jax.random.key(0), algorithm.init_distribution(), 1)
        policy = jax.tree.map(lambda x: x[0], sample.policy)
    else:
        policy = ctrl.sample(jax.random.key(0), ctrl.init_distribution())
    return env, params, ctrl, policy


def controller_throughput(kind: str, nodes: int, num: int, runs: int) -> tuple[Timing, float]:
    """Like ``rollout_throughput`` for each controller kind of ``CONTROLLER_KINDS``: ``num``
    rollouts of one controller drawn from the algorithm's initial distribution (an argument
    of the compiled program)."""
    from cognet_jax.rollout import rollouts

    env, params, ctrl, policy = controller_case(kind, nodes)
    timing = time_jax(
        lambda k, pol: rollouts(env, ctrl, k, num, params, pol),
        jax.random.key(1),
        policy,
        runs=runs,
    )
    return timing, num * env.horizon * env.num_agents / timing.median_s


def iteration(experiment: str, sets: list[str], runs: int) -> tuple[Timing, dict]:
    """Timing of one compiled search iteration of ``experiment`` (with ``--set`` overrides),
    compile time apart; the state is carried from call to call as in a real run. Also returns
    the compiled program's XLA buffer sizes (bytes: arguments, outputs, temporaries)."""
    from cognet_jax.api import make_step
    from cognet_jax.registry import load_config

    config = load_config(experiment, sets)
    algorithm, params, step = make_step(config)
    state = algorithm.init(jax.random.key(0), params)
    key = jax.random.key(1)
    t0 = time.perf_counter()
    # the params are constants of the program, as the command line compiles it
    compiled = jax.jit(lambda k, s: step(k, s, params)).lower(key, state).compile()
    compile_s = time.perf_counter() - t0
    holder = {"state": state}

    def one():
        holder["state"], metrics = compiled(key, holder["state"])
        return metrics

    timing = time_calls(one, runs=runs)
    timing.compile_s = compile_s
    memory = {}
    stats = compiled.memory_analysis()
    if stats is not None:
        memory = dict(
            argument_bytes=int(stats.argument_size_in_bytes),
            output_bytes=int(stats.output_size_in_bytes),
            temp_bytes=int(stats.temp_size_in_bytes),
        )
    return timing, memory


def sweep_ratio(
    seeds: int = 32, repeats: int = 3, experiment: str = "tagging-thesis-spec-n3"
) -> dict:
    """Process wall seconds of ``cognet-jax sweep EXPERIMENT --seeds 1`` and ``--seeds N``
    (fresh processes, as a user runs them: imports, compile, all iterations, honest evaluation
    and outputs included), ``repeats`` times each, alternating; the medians and their ratio.

    The target's measure compiles in every process (``COGNET_JAX_CACHE=off``), as every
    process did when the target was set (issue 7, before the persistent compilation cache).
    ``warm`` repeats the measurement with a compilation cache of its own, filled by one run of
    each first: the processes then compile nothing, and the ratio is that of the iterations
    themselves (32 runs' work against one run's) plus the start-up of a process."""
    import os
    import statistics
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        cold = _sweep_walls(seeds, repeats, experiment, f"{tmp}/cold", {"COGNET_JAX_CACHE": "off"})
        env = {"COGNET_JAX_CACHE": os.path.join(tmp, "cache")}
        _sweep_walls(seeds, 1, experiment, f"{tmp}/prime", env)
        warm = _sweep_walls(seeds, repeats, experiment, f"{tmp}/warm", env)

    def summary(walls: dict[int, list[float]]) -> dict:
        one, many = statistics.median(walls[1]), statistics.median(walls[seeds])
        return dict(
            walls_one=walls[1],
            walls_many=walls[seeds],
            median_one_s=one,
            median_many_s=many,
            ratio=many / one,
        )

    return dict(
        experiment=experiment, seeds=seeds, cache="off", **summary(cold), warm=summary(warm)
    )


def _sweep_walls(seeds: int, repeats: int, experiment: str, out: str, env: dict) -> dict:
    """``{1: [walls], seeds: [walls]}`` of ``repeats`` alternating sweep processes run with
    ``env`` added to the environment."""
    import os
    import subprocess
    import sys

    walls: dict[int, list[float]] = {1: [], seeds: []}
    for r in range(repeats):
        for n in (1, seeds):
            cmd = [sys.executable, "-m", "cognet_jax", "sweep", experiment, "--seeds", str(n)]
            cmd += ["--no-progress", "--out", f"{out}/s{n}-{r}"]
            t0 = time.perf_counter()
            subprocess.run(cmd, check=True, capture_output=True, env={**os.environ, **env})
            walls[n].append(time.perf_counter() - t0)
    return walls


def full_run(experiment: str = "tagging-thesis-spec-n3") -> tuple[float, dict]:
    """Wall seconds of ``cognet-jax train EXPERIMENT`` without plots (compile, all iterations
    and the honest 10,000-rollout evaluation included) and its results dict."""
    from cognet_jax.driver import train
    from cognet_jax.registry import load_config

    config = load_config(experiment, ["run.plots=false", "run.progress=false"])
    t0 = time.perf_counter()
    results = train(config, 0, HERE / ".last_full_run", log=lambda *_: None)
    return time.perf_counter() - t0, results


def machine_peak(runs: int = 5) -> dict:
    """This machine's measured peaks, for the roofline estimate: float32 matmul GFLOP/s
    (2048 x 2048 x 2048) and streaming bandwidth GB/s (``y = 2 x + 1`` over 2^26 floats:
    256 MiB read + 256 MiB written)."""
    import jax.numpy as jnp

    a = jnp.ones((2048, 2048), jnp.float32)
    mm = time_jax(lambda x: x @ x, a, runs=runs)
    x = jnp.ones((1 << 26,), jnp.float32)
    bw = time_jax(lambda v: 2.0 * v + 1.0, x, runs=runs)
    return dict(
        matmul_gflops=2 * 2048**3 / mm.median_s / 1e9,
        bandwidth_gbs=2 * x.nbytes / bw.median_s / 1e9,
    )


def rollout_cost(kind: str, nodes: int, num: int = 1_000) -> dict:
    """XLA's own cost analysis of the rollout program of one controller kind, per agent-step:
    flops and bytes moved between the compiled kernels. XLA counts a ``while`` (``lax.scan``)
    body once, so the program's totals are one time step plus the reset; dividing by ``num *
    agents`` gives the per agent-step figures (the reset is under 1 %)."""
    from cognet_jax.rollout import rollouts

    env, params, ctrl, policy = controller_case(kind, nodes)
    compiled = (
        jax.jit(lambda k, pol: rollouts(env, ctrl, k, num, params, pol))
        .lower(jax.random.key(1), policy)
        .compile()
    )
    cost = compiled.cost_analysis()
    per = num * env.num_agents
    return dict(
        kind=kind, nodes=nodes, flops=cost["flops"] / per, bytes=cost["bytes accessed"] / per
    )
