"""What a user runs, JAX against torch in paired rounds: one whole search iteration of each
algorithm and setting, and rollouts at 1e4 (``benchmarks.paired``).

Cases (``CASES``): the thesis variant (``cognet-dice-thesis``) and the default ``cognet-dice``
(library defaults: tied structures, restarts, the pool of best policies) at the thesis setting
with 3 and 6 nodes, and the default at the paper setting (h 150, respawn) with 200 candidates x
1000 rollouts, a tenth of the paper's 2000 x 1000 iteration. JAX runs the compiled iteration of
the experiment (state carried from call to call, as in a run); torch runs the same algorithm
and sizes in ``benchmarks/torch_reference`` (eager and ``torch.compile``d; the ratio is against
the faster of the two in each round).
"""

from __future__ import annotations

import time

import jax

from benchmarks import jax_cases, paired, torch_cases

#: the library's defaults on an experiment that pins the search its rows were measured with,
#: as they were when benchmarks/README.md was measured: without the refine phase, which the
#: torch reference leaves out (it recentres the distribution at a few iterations: no more work),
#: and with the earlier restart threshold and default-vote scale (the pinned experiment's scale
#: 1; a restart and a different initial Gaussian cost the same work)
LIBRARY_DEFAULTS = [
    "algorithm.tie_structure=true",
    "algorithm.restart_tol=0.02",
    "algorithm.best_pool=4",
]
PAPER_TENTH = [
    "algorithm.candidates=200",
    "algorithm.eval_rollouts=1000",
    "algorithm.elites=10",
    "algorithm.iterations=100",
]

#: (label, kind, experiment, overrides, rounds, calls per round); kind "thesis" or "weights"
CASES = [
    ("thesis variant, 3 nodes", "thesis", "tagging-thesis-spec-n3", [], 11, 3),
    ("thesis variant, 6 nodes", "thesis", "tagging-thesis-spec-n6", [], 11, 3),
    ("default, 3 nodes", "weights", "tagging-thesis-n3", LIBRARY_DEFAULTS, 11, 3),
    ("default, 6 nodes", "weights", "tagging-thesis-n6", LIBRARY_DEFAULTS, 11, 3),
    (
        "default, paper setting (h 150), 200 x 1000 (1/10 of the paper's iteration)",
        "weights",
        "tagging-paper-auto",
        PAPER_TENTH,
        5,
        1,
    ),
]
ROLLOUT_SIZE = 10_000


def jax_iteration_call(experiment: str, sets: list[str]):
    """``(call, compile_s, agent-steps per call)``: one compiled iteration of the experiment
    per ``call()``, the state carried over (outputs ready on return). As a run calls it
    (``Program.compile_step``): the same run key every call, the step folding in the
    iteration it reads from the state (``api.iteration_step``); a key folded outside the
    compiled program is one more dispatch per call, which no run makes (50-100 us, 5-10% of
    the thesis iteration; benchmarks/NOTES.md)."""
    from cognet_jax.api import make_step
    from cognet_jax.registry import load_config

    algorithm, params, step = make_step(load_config(experiment, sets))
    holder = {"state": algorithm.init(jax.random.key(0), params)}
    key = jax.random.key(1)
    t0 = time.perf_counter()
    compiled = jax.jit(lambda k, s: step(k, s, params)).lower(key, holder["state"]).compile()
    compile_s = time.perf_counter() - t0

    def call():
        holder["state"], metrics = compiled(key, holder["state"])
        return jax.block_until_ready(metrics)

    env = algorithm.env
    return call, compile_s, algorithm.rollouts_per_iteration * env.horizon * env.num_agents


def torch_iteration_call(impl: str, kind: str, experiment: str, sets: list[str]):
    """``call()``: one iteration of the torch reference ``impl`` of the case, with the sizes
    of the experiment's config."""
    from benchmarks.torch_reference.weights import (
        TorchWeightsCompiled,
        TorchWeightsSearch,
        env_from_config,
        settings_from_config,
    )
    from cognet_jax.registry import load_config

    config = load_config(experiment, sets)
    if kind == "thesis":
        return torch_cases._reference(impl, config.algorithm.nodes).step
    cls = TorchWeightsCompiled if impl == "torch-compiled" else TorchWeightsSearch
    return cls(settings_from_config(config), env_from_config(config), seed=0).step


def measure(log, cases=None) -> list[dict]:
    """Paired rounds of every case, and of rollouts at ``ROLLOUT_SIZE`` (3 and 6 nodes):
    per case the JAX implementation against the faster torch reference of each round."""
    rows = []
    impls = ("torch-vectorized", "torch-compiled")
    for label, kind, experiment, sets, rounds, per_round in cases or CASES:
        call, compile_s, steps = jax_iteration_call(experiment, sets)
        t0 = time.perf_counter()
        torch_calls = {i: torch_iteration_call(i, kind, experiment, sets) for i in impls}
        torch_calls["torch-compiled"]()  # its compile, timed apart
        torch_compile_s = time.perf_counter() - t0
        seconds = paired.paired_rounds({"jax": call, **torch_calls}, rounds, per_round)
        s = paired.summary(seconds, "jax", list(impls))
        rows.append(
            dict(
                case=f"iteration: {label}",
                experiment=experiment,
                sets=sets,
                agent_steps=steps,
                rounds=rounds,
                calls_per_round=per_round,
                jax_compile_s=compile_s,
                torch_setup_s=torch_compile_s,
                seconds=seconds,
                **s,
            )
        )
        log(_line(rows[-1]))
    for nodes in (3, 6):
        calls = {
            "jax": jax_cases.rollout_call(nodes, ROLLOUT_SIZE),
            **{i: torch_cases.rollout_call(i, nodes, ROLLOUT_SIZE) for i in impls},
        }
        seconds = paired.paired_rounds(calls)
        s = paired.summary(seconds, "jax", list(impls))
        rows.append(
            dict(
                case=f"rollouts: {ROLLOUT_SIZE:.0e}, {nodes} nodes",
                agent_steps=ROLLOUT_SIZE * 3 * 2,
                rounds=len(seconds["jax"]),
                calls_per_round=paired.CALLS_PER_ROUND,
                seconds=seconds,
                **s,
            )
        )
        log(_line(rows[-1]))
    return rows


def _line(row: dict) -> str:
    ms = ", ".join(f"{k} {v * 1e3:.2f} ms" for k, v in row["median_s"].items())
    return (
        f"paired {row['case']}: {row['ratio']:.2f}x the best torch (rounds "
        f"{row['ratio_min']:.2f}-{row['ratio_max']:.2f}x; {ms})"
    )
