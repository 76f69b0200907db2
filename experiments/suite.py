"""The continuous-observation suite (issue 52): every simulator with its tuned hand-written
controller, its upper bound where one can be computed, and COGNet-DICE's defaults over 8
seeds; writes the ``suite`` block of experiments/README.md from the saved results.

    python experiments/suite.py                  # hand-written controllers, then every sweep
    python experiments/suite.py hand             # only the grid searches
    python experiments/suite.py cognet ROW ...   # only these COGNet-DICE sweeps
    python experiments/suite.py cogdice ROW ...  # COG-DICE's defaults (scalar observations)
    python experiments/suite.py reactive         # the paper setting's reactive controller
    python experiments/suite.py rescore [ROW ...] [--from DIR]  # kept policies, 200,000 rollouts
    python experiments/suite.py --table-only     # rebuild the table from saved results

The hand-written controller of a row is the simulator's ``hand_controller`` with the
thresholds of ``HAND_GRID`` (``cognet_jax.baselines.tune``: every point on 20,000 rollouts of
one key, the winner re-evaluated on 200,000 fresh ones). A COGNet-DICE cell is exactly
``cognet-jax sweep EXPERIMENT --seeds 8`` (the experiment sets only ``[env]`` and
``algorithm.nodes``; seed s uses the keys of ``cognet-jax train --seed s``); its value is the
8 seeds' mean of honest values (fresh 10,000-rollout evaluations) and their minimum.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

from _readme import finish_of, machine, replace_block
from cognet_sweeps import _agent_steps

from cognet_jax.reporting import in_loop_best_series

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results" / "suite"
SEEDS = 8
HAND_ROLLOUTS = 20_000
#: the tuned point's honest value: 10 times the tuning's rollouts, so the bar the searches are
#: held to has a standard error about a third of a COGNet-DICE seed's (10,000 rollouts)
HAND_HONEST_ROLLOUTS = 200_000

#: row -> (experiment, what it covers)
ROWS = {
    "hearing-tiger": ("hearing-tiger-n7", "scalar hearing, static tiger, coordination, h 10"),
    "hearing-tiger-noisy": (
        "hearing-tiger-noisy-n7",
        "as above, the noise dominating (std 3)",
    ),
    "beacon": ("beacon-n5", "2-D offsets (std 0.5), static beacon, 3 agents, h 30, gamma 0.95"),
    "beacon-clean": ("beacon-clean-n5", "as above without observation noise"),
    "bearing-chase": ("bearing-chase-n5", "bearings (0.3 rad), moving target, h 50, gamma 0.9"),
    "plume": ("plume-n5", "3 x 3 image patch (std 0.05), static source, h 20"),
    "box-push": ("box-push-n3", "range sensor (std 1), joint push only, h 100, gamma 0.9"),
    "readme-seek": (
        str(HERE / "readme-seek-n3.toml"),
        "the README's user simulator, loaded with --import (experiments/readme_seek.py): "
        "signed distance (std 0.3), static goal, h 20, gamma 0.95",
    ),
}
#: rows whose simulator is a module outside the package, imported as --import does
IMPORTS = {"readme-seek": HERE / "readme_seek.py"}


def _config(row: str):
    from cognet_jax.plugins import import_plugin
    from cognet_jax.registry import load_config

    if row in IMPORTS:
        import_plugin(str(IMPORTS[row]))
    return load_config(ROWS[row][0])


def run_hand(rows: list[str]) -> None:
    from cognet_jax.api import build_env
    from cognet_jax.baselines import tune

    RESULTS.mkdir(parents=True, exist_ok=True)
    for row in rows:
        config = _config(row)
        env, params = build_env(config)
        tuned = tune(config.env.name, env, params, HAND_ROLLOUTS, HAND_HONEST_ROLLOUTS)
        record = {
            "row": row,
            "simulator": config.env.name,
            "grid": tuned.grid,
            "values": [[theta, v] for theta, v in tuned.values],
            "best": tuned.best,
            "honest": tuned.honest,
            "rollouts": tuned.rollouts,
            "bound": _bound(config, env, params),
        }
        (RESULTS / f"hand-{row}.json").write_text(json.dumps(record, indent=1))
        print(f"{row}: hand-written {tuned.best} -> {tuned.honest[0]:.3f}", flush=True)


def _bound(config, env, params):
    """``[value, what]`` of the simulator's upper bound, or None."""
    from cognet_jax.envs import beacon, hearing_tiger, plume

    name = config.env.name
    if name == "hearing-tiger":
        value = hearing_tiger.upper_bound(env.horizon, float(params.discount))
        return [value, "the tiger's side known at every step"]
    if name == "plume" and float(params.discount) == 1.0:
        return [plume.upper_bound(env), "on the source from the first step its distance allows"]
    if name == "beacon" and float(params.motion_noise) == 0.0:
        mean, se = beacon.upper_bound(env, params)
        return [mean, f"inside the radius from the first step its distance allows (+- {se:.3f})"]
    return None


#: the library's defaults before the pool of best policies, where an experiment pins the
#: search its earlier rows were made with (those experiments also pin ``best_pool = 0``)
BEFORE_POOL = ["algorithm.tie_structure=true", "algorithm.restart_tol=0.02"]
#: the library's defaults before the refine phase, and with it
BEFORE_REFINE = [*BEFORE_POOL, "algorithm.best_pool=4"]
BEFORE_DISTINCT = [*BEFORE_REFINE, "algorithm.refine=0.25"]
#: the library's defaults: as before, with the actions drawn distinct where the rule says so
#: (the heatmap's TOML pins ``distinct_actions = false``)
NEW = [*BEFORE_DISTINCT, "algorithm.distinct_actions=auto"]
#: rows whose sweep before the refine phase ran the pool's first version (notes below the table)
FIRST_POOL = ("beacon", "bearing-chase", "readme-seek")
#: the heatmap experiments compare the best policy on paired fresh rollouts, which replaces the
#: pool: the defaults there turn that off
UNPAIRED = ["algorithm.paired_best=false"]
#: the sizes the default budget had before the noise pilot (``algorithms/sizing.py``): the
#: rows measured before it pin them (on beacon, chase, plume and the README simulator the pilot
#: keeps them)
BEFORE_PILOT = [
    "algorithm.iterations=400",
    "algorithm.candidates=200",
    "algorithm.eval_rollouts=375",
    "algorithm.elites=10",
    "algorithm.refine=0",
]
#: the same at 1/64 and 1/8 of the paper setting's budget
BEFORE_PILOT_PAPER = {
    "1of64": [
        "algorithm.iterations=312",
        "algorithm.candidates=200",
        "algorithm.eval_rollouts=250",
        "algorithm.elites=10",
    ],
    "1of8": [
        "algorithm.iterations=400",
        "algorithm.candidates=312",
        "algorithm.eval_rollouts=1000",
        "algorithm.elites=16",
    ],
    "full": [],
}
#: the exploring searches' fields as they were before the horizon rule decided them
#: (``cognet_weights_settings.resolve_search``): every row on an experiment that does not pin
#: the search, measured before the rule, pins them (``before_rule``)
BEFORE_RULE = [
    "algorithm.default_vote_scale=1",
    "algorithm.restart_tol=0.02",
    "algorithm.refine_tol=0.2",
]
#: the defaults without the pool (the search of the rows measured before it)
NO_POOL = ["algorithm.best_pool=0", *BEFORE_PILOT]
#: further sweeps: folder -> (experiment, overrides, seeds, what it tests, earlier sweep to
#: compare with (experiments/results/sweeps/NAME, else a folder of this suite) or None)
EXTRA = {
    **{
        f"cognet-{row}-nopool": (
            experiment,
            NO_POOL,
            SEEDS,
            "ablation: the defaults without the pool of best policies (the defaults before it)",
            None,
        )
        for row, (experiment, _) in ROWS.items()
    },
    **{
        f"cognet-{row}-before-rule": (
            experiment,
            [],
            SEEDS,
            "the defaults before the horizon rule: the default vote at 1, exploring searches "
            "until 0.02 of the initial spread, the refine phase's until 0.2 of its own",
            None,
        )
        for row, (experiment, _) in ROWS.items()
    },
    **{
        f"cognet-{row}-before-refine": (
            experiment,
            ["algorithm.refine=0"],
            SEEDS,
            "the defaults before the refine phase"
            + (" (with the pool's first version)" if row in FIRST_POOL else ""),
            None,
        )
        for row, (experiment, _) in ROWS.items()
        if row != "plume"
    },
    **{
        f"cognet-{row}-before-pilot": (
            ROWS[row][0],
            BEFORE_PILOT,
            SEEDS,
            "the defaults before the noise pilot sized the search (with the pool's first version)",
            None,
        )
        for row in ("hearing-tiger", "hearing-tiger-noisy", "box-push")
    },
    "beacon-k1000": (
        "beacon-n5",
        [
            "algorithm.iterations=150",
            "algorithm.candidates=200",
            "algorithm.eval_rollouts=1000",
            "algorithm.elites=10",
            "algorithm.refine=0",
        ],
        SEEDS,
        "rejected rule: the pilot's rollouts per candidate (1000 on beacon) paid for with "
        "iterations",
        None,
    ),
    "hearing-tiger-norestart": (
        "hearing-tiger-n7",
        ["algorithm.restart_tol=0", *NO_POOL],
        SEEDS,
        "ablation of the defaults before the pool: no restart of a converged distribution",
        None,
    ),
    "tagging-thesis-n3-defaults": (
        "tagging-thesis-n3",
        NEW,
        SEEDS,
        "the library's defaults",
        "tagging-thesis-n3",
    ),
    "tagging-thesis-n3-defaults-before-refine": (
        "tagging-thesis-n3",
        BEFORE_REFINE,
        SEEDS,
        "the library's defaults before the refine phase",
        "tagging-thesis-n3",
    ),
    "tagging-thesis-n3": (
        "tagging-thesis-n3",
        BEFORE_POOL,
        SEEDS,
        "the defaults before the pool",
        "tagging-thesis-n3",
    ),
    "tagging-thesis-n3-notie": (
        "tagging-thesis-n3",
        ["algorithm.tie_structure=false", "algorithm.restart_tol=0.02"],
        SEEDS,
        "the defaults before the pool, without tied structures",
        "tagging-thesis-n3",
    ),
    "tagging-thesis-n3-norestart": (
        "tagging-thesis-n3",
        ["algorithm.tie_structure=true", "algorithm.restart_tol=0"],
        SEEDS,
        "the defaults before the pool, without restarts",
        "tagging-thesis-n3",
    ),
    **{
        f"{experiment}{suffix}": (experiment, overrides, SEEDS, what, experiment)
        for experiment, paired in (("tagging-thesis-n6", []), ("heatmap-2d-n4", UNPAIRED))
        for suffix, overrides, what in (
            ("-defaults", [*NEW, *paired], "the library's defaults"),
            (
                "-defaults-before-distinct",
                [*BEFORE_DISTINCT, *paired],
                "the library's defaults before distinct_actions",
            ),
            (
                "-defaults-before-refine",
                [*BEFORE_REFINE, *paired],
                "the library's defaults before the refine phase",
            ),
            ("", BEFORE_POOL, "the defaults before the pool"),
        )
    },
    **{
        f"paper-budget-{name}{suffix}": (
            "tagging-paper-auto",
            [f"algorithm.budget={budget}", "run.probe_seconds=10", *extra],
            3,
            f"{label} of the paper's 3e11 agent-steps{what}",
            None,
        )
        for name, budget, label in (
            ("1of64", "4.6875e9", "1/64"),
            ("1of8", "3.75e10", "1/8"),
            ("full", "3e11", "all"),
        )
        for suffix, extra, what in (
            ("", [], ""),
            ("-before-refine", ["algorithm.refine=0"], ", before the refine phase"),
            (
                "-before-pilot",
                [*BEFORE_PILOT_PAPER[name], "algorithm.refine=0"],
                ", sized as before the noise pilot (with the pool's first version)",
            ),
            (
                "-nopool",
                ["algorithm.best_pool=0", *BEFORE_PILOT_PAPER[name], "algorithm.refine=0"],
                ", without the pool, sized as before the noise pilot",
            ),
        )
        if suffix != "-before-pilot" or BEFORE_PILOT_PAPER[name]
    },
    "paper-budget-1of64-notie": (
        "tagging-paper-auto",
        [
            "algorithm.budget=4.6875e9",
            "run.probe_seconds=10",
            "algorithm.tie_structure=false",
            "algorithm.refine=0",
        ],
        3,
        "1/64 of the paper's budget, the defaults without tied structures",
        None,
    ),
    "paper-cognet-builtin": (
        "tagging-paper-cognet",
        ["run.probe_seconds=10"],
        3,
        "the built-in tagging-paper-cognet (1000 x 800 x 50, no tied structures, restarts or "
        "pool; 1/25 of the paper's budget), whose seed 0 alone gave 109.985",
        None,
    ),
    "paper-budget-1of64-c800": (
        "tagging-paper-auto",
        [
            "algorithm.budget=4.6875e9",
            "run.probe_seconds=10",
            "algorithm.candidates=800",
            "algorithm.eval_rollouts=50",
            "algorithm.iterations=390",
            "algorithm.refine=0",
        ],
        3,
        "1/64 of the paper's budget split as the built-in tagging-paper-cognet splits it: "
        "more candidates, fewer rollouts each",
        None,
    ),
    **{
        name: (
            experiment,
            overrides,
            SEEDS,
            "the pool after its fix, sized as before the noise pilot",
            None,
        )
        for name, experiment, overrides in (
            ("tagging-thesis-n3-pool-fixed", "tagging-thesis-n3", BEFORE_REFINE),
            ("hearing-tiger-pool-fixed", "hearing-tiger-n7", BEFORE_PILOT),
            ("readme-seek-pool-fixed", str(HERE / "readme-seek-n3.toml"), BEFORE_PILOT),
        )
    },
    "hearing-tiger-noisy-refine-half": (
        "hearing-tiger-noisy-n7",
        ["algorithm.refine=0.5"],
        SEEDS,
        "the defaults with half of the iterations refining instead of a quarter",
        None,
    ),
    **{
        f"beacon-starts{n}": (
            "beacon-n5",
            [f"algorithm.starts={n}"],
            SEEDS,
            f"the defaults with the iterations before the refine phase as {n} independent searches",
            None,
        )
        for n in (2, 3)
    },
    "beacon-i600": (
        "beacon-n5",
        ["algorithm.iterations=600", "algorithm.eval_rollouts=250", "algorithm.refine=0"],
        SEEDS,
        "the default budget as 1.5x the iterations (more restarts) with fewer rollouts each",
        None,
    ),
    "box-push-c1000": (
        "box-push-n3",
        [
            "algorithm.candidates=1000",
            "algorithm.eval_rollouts=75",
            "algorithm.iterations=400",
            "algorithm.refine=0",
        ],
        SEEDS,
        "the default budget as 5x the candidates with fewer rollouts each",
        None,
    ),
}
#: the default vote at the scale of a unit's vote, with exploring searches until 0.1 of the
#: initial spread (the refine phase's until 0.1 of its own): the candidate defaults swept on
#: the suite (not adopted: tagging n3 lost)
VOTE10 = [
    "algorithm.restart_tol=0.1",
    "algorithm.refine_tol=0.1",
    "algorithm.default_vote_scale=10",
]
#: a portfolio of exploring searches: the first and every other one with the default vote at
#: the units' scale, converging at 0.2 of the initial spread, the others as the defaults
PORTFOLIO = [
    "algorithm.default_vote_scale=10",
    "algorithm.vote_alternate=true",
    "algorithm.vote_first=true",
    "algorithm.vote_restart_tol=0.2",
]


def replaced(overrides: list[str], changes: list[str]) -> list[str]:
    """``overrides`` with the fields that ``changes`` sets replaced by them."""
    fields = {c.split("=")[0] for c in changes}
    return [o for o in overrides if o.split("=")[0] not in fields] + changes


PORTFOLIO_WHAT = (
    "candidate: exploring searches alternate, the first and every other one short with the "
    "default vote at the units' scale"
)
TIED_WHAT = (
    "candidate: the default vote of tied (reactive) candidates at the units' scale "
    "(tied_vote_scale 10), the others' at 1"
)
#: the defaults' other fields on the experiments that pin the search (tagging, heatmap)
TAG_BASE = ["algorithm.tie_structure=true", "algorithm.best_pool=4", "algorithm.refine=0.25"]
VOTE10_WHAT = "candidate defaults: default vote at the units' scale, shorter exploring searches"
EXTRA.update(
    {
        **{
            f"{experiment}-vote10{'-16seeds' if seeds == 16 else ''}": (
                experiment,
                [*TAG_BASE, *VOTE10, *paired],
                seeds,
                f"{VOTE10_WHAT} (the library's defaults otherwise)",
                None,
            )
            for experiment, paired, seeds in (
                ("tagging-thesis-n3", [], SEEDS),
                ("tagging-thesis-n3", [], 16),
                ("tagging-thesis-n6", [], SEEDS),
                ("heatmap-2d-n4", UNPAIRED, SEEDS),
            )
        },
        "tagging-thesis-n3-defaults-16seeds": (
            "tagging-thesis-n3",
            NEW,
            16,
            "the library's defaults, 16 seeds (the first 8 within float rounding of the 8-seed "
            "sweep's: another batch)",
            None,
        ),
        "tagging-thesis-n3-vote10-restart0.02": (
            "tagging-thesis-n3",
            [*NEW, "algorithm.default_vote_scale=10"],
            SEEDS,
            "the library's defaults with the default vote at the units' scale only",
            None,
        ),
        "tagging-thesis-n3-restart0.1": (
            "tagging-thesis-n3",
            [*TAG_BASE, "algorithm.restart_tol=0.1", "algorithm.refine_tol=0.1"],
            SEEDS,
            "the library's defaults with shorter exploring searches only",
            None,
        ),
        "tagging-thesis-n3-vote-alternate-16seeds": (
            "tagging-thesis-n3",
            [*NEW, "algorithm.default_vote_scale=10", "algorithm.vote_alternate=true"],
            16,
            "the library's defaults with exploring searches alternating the default vote's "
            "scale between 1 and 10 (the first at 1)",
            None,
        ),
        "beacon-vote-alternate": (
            "beacon-n5",
            ["algorithm.default_vote_scale=10", "algorithm.vote_alternate=true"],
            SEEDS,
            "the defaults with exploring searches alternating the default vote's scale between "
            "1 and 10 (the first at 1)",
            None,
        ),
        "paper-budget-1of64-vote10": (
            "tagging-paper-auto",
            ["algorithm.budget=4.6875e9", "run.probe_seconds=10", *VOTE10],
            3,
            f"1/64 of the paper's 3e11 agent-steps, {VOTE10_WHAT}",
            None,
        ),
        **{
            f"tagging-thesis-n3-vote10-{label}-16seeds": (
                "tagging-thesis-n3",
                [*TAG_BASE, *replaced(VOTE10, changes)],
                16,
                f"{VOTE10_WHAT}, {what}",
                None,
            )
            for label, changes, what in (
                (
                    "refinetol0.2",
                    ["algorithm.refine_tol=0.2"],
                    "the refine phase converging at the default 0.2 of its own spread",
                ),
                (
                    "refinetol0.4",
                    ["algorithm.refine_tol=0.4"],
                    "the refine phase converging at 0.4 of its own spread",
                ),
                (
                    "refine0.4",
                    ["algorithm.refine_tol=0.2", "algorithm.refine=0.4"],
                    "a refine phase of 0.4 of the iterations converging at 0.2 of its spread",
                ),
            )
        },
        **{
            name: (
                experiment,
                [*base, *replaced(PORTFOLIO, extra)],
                seeds,
                PORTFOLIO_WHAT + what,
                None,
            )
            for name, experiment, base, extra, seeds, what in (
                ("tagging-thesis-n3-portfolio-16seeds", "tagging-thesis-n3", NEW, [], 16, ""),
                (
                    "tagging-thesis-n3-portfolio-v0.1-16seeds",
                    "tagging-thesis-n3",
                    NEW,
                    ["algorithm.vote_restart_tol=0.1"],
                    16,
                    ", those searches until 0.1",
                ),
                (
                    "tagging-thesis-n3-portfolio-late-16seeds",
                    "tagging-thesis-n3",
                    NEW,
                    ["algorithm.vote_first=false"],
                    16,
                    ", the first search at scale 1",
                ),
                ("beacon-portfolio", "beacon-n5", [], [], SEEDS, ""),
            )
        },
        "cognet-plume-raw": (
            "plume-n5",
            ["algorithm.standardize_inputs=false"],
            SEEDS,
            "the defaults before standardize_inputs = 'auto' (raw patch pixels)",
            None,
        ),
        **{
            name: (experiment, [*base, "algorithm.tied_vote_scale=10", *extra], seeds, what, None)
            for name, experiment, base, extra, seeds, what in (
                (
                    "tagging-thesis-n3-tiedvote10-16seeds",
                    "tagging-thesis-n3",
                    NEW,
                    [],
                    16,
                    TIED_WHAT,
                ),
                (
                    "tagging-thesis-n3-tiedvote10-restart0.1-16seeds",
                    "tagging-thesis-n3",
                    TAG_BASE,
                    ["algorithm.restart_tol=0.1"],
                    16,
                    f"{TIED_WHAT}, exploring searches until 0.1 of the initial spread",
                ),
                ("beacon-tiedvote10", "beacon-n5", [], [], SEEDS, TIED_WHAT),
            )
        },
        **{
            f"{row}-restart{tol}": (
                experiment,
                [f"algorithm.restart_tol={tol}", f"algorithm.refine_tol={tol}"],
                SEEDS,
                f"exploring searches until {tol} of the initial spread (the refine phase's "
                f"until {tol} of its own)",
                None,
            )
            for row, experiment, tol in (
                ("beacon", "beacon-n5", "0.1"),
                ("beacon", "beacon-n5", "0.2"),
                ("hearing-tiger", "hearing-tiger-n7", "0.2"),
            )
        },
    }
)


#: experiments whose TOML pins the exploring search (tagging, heatmap): their rows are as before
PINNED = ("tagging-thesis-n3", "tagging-thesis-n6", "heatmap-2d-n4", "tagging-paper-cognet")
#: probes of this session's defaults (the horizon rule): twice the default budget, and as many
#: nodes as the tuned hand-written controller uses on noisy Dec-Tiger (2 x count + 1 = 9)
EXTRA.update(
    {
        "hearing-tiger-noisy-n9": (
            "hearing-tiger-noisy-n7",
            ["algorithm.nodes=9"],
            SEEDS,
            "the defaults with 9 nodes, those of the tuned hand-written controller (count 4)",
            None,
        ),
        "hearing-tiger-noisy-budget2x": (
            "hearing-tiger-noisy-n7",
            ["algorithm.budget=1.2e9"],
            SEEDS,
            "the defaults with twice the default budget (1.2e9 agent-steps)",
            None,
        ),
        "readme-seek-budget2x": (
            str(HERE / "readme-seek-n3.toml"),
            ["algorithm.budget=2.4e9"],
            SEEDS,
            "the defaults with twice the default budget (2.4e9 agent-steps)",
            None,
        ),
    }
)
#: rows whose problem the rule of ``distinct_actions`` turns it on for (5 nodes, 5 moves)
DISTINCT_ROWS = ("beacon", "beacon-clean", "bearing-chase", "plume")
EXTRA.update(
    {
        **{
            f"cognet-{row}-before-distinct": (
                ROWS[row][0],
                ["algorithm.distinct_actions=false"],
                SEEDS,
                "the defaults before distinct_actions: every node's action drawn on its own",
                None,
            )
            for row in DISTINCT_ROWS
        },
        **{
            f"{row}-refine-half": (
                ROWS[row][0],
                ["algorithm.refine=0.5"],
                SEEDS,
                "the defaults with half of the iterations refining instead of a quarter" + when,
                f"cognet-{row}",
            )
            for row, when in (
                (
                    "plume",
                    " (run at commit d3ca24d, whose distinct flags drew on the stream of "
                    "the hidden weights)",
                ),
                ("bearing-chase", ""),
                ("beacon-clean", ""),
                ("readme-seek", ""),
            )
        },
        "plume-refine-half-fixed": (
            ROWS["plume"][0],
            ["algorithm.refine=0.5"],
            SEEDS,
            "the defaults with half of the iterations refining instead of a quarter (the "
            "fixed flag stream)",
            "cognet-plume",
        ),
        "tagging-thesis-n3-refine-half": (
            "tagging-thesis-n3",
            [*replaced(NEW, ["algorithm.refine=0.5"])],
            SEEDS,
            "the library's defaults with half of the iterations refining instead of a quarter",
            "tagging-thesis-n3-defaults",
        ),
        "paper-budget-1of64-now": (
            "tagging-paper-auto",
            ["algorithm.budget=4.6875e9", "run.probe_seconds=10"],
            3,
            "1/64 of the paper's 3e11 agent-steps under the defaults of now (the horizon rule, "
            "distinct_actions; the row paper-budget-1of64 ran before the rule)",
            "paper-budget-1of64",
        ),
        "paper-budget-1of8-now": (
            "tagging-paper-auto",
            ["algorithm.budget=3.75e10", "run.probe_seconds=10"],
            3,
            "1/8 of the paper's 3e11 agent-steps under the defaults of now (the row "
            "paper-budget-1of8 ran before the horizon rule)",
            "paper-budget-1of8",
        ),
    }
)
#: rows run under the horizon rule, or setting all its fields
AFTER_RULE = (
    "hearing-tiger-noisy-n9",
    "hearing-tiger-noisy-budget2x",
    "readme-seek-budget2x",
    *(f"cognet-{row}-before-distinct" for row in DISTINCT_ROWS),
    "plume-refine-half",
    "bearing-chase-refine-half",
    "beacon-clean-refine-half",
    "readme-seek-refine-half",
    "plume-refine-half-fixed",
    "paper-budget-1of64-now",
    "paper-budget-1of8-now",
)


def before_rule(name: str, experiment: str, overrides: list[str]) -> list[str]:
    """``overrides`` of row ``name`` with the fields of ``BEFORE_RULE`` it does not set, on an
    experiment that leaves the search to the defaults: the command that reproduces a row
    measured before the horizon rule."""
    later = (AFTER_RULE, AFTER_REDRAW, AFTER_POLISH, AFTER_AXES)
    if experiment in PINNED or any(name in rows for rows in later):
        return overrides
    return replaced(BEFORE_RULE, overrides)


def earlier_defaults(suffix: str, what: str) -> dict:
    """Rows ``cognet-ROW-SUFFIX``: each simulator's sweep of the defaults before a change (the
    ``cognet-ROW`` sweeps of then, kept under that name)."""
    return {
        f"cognet-{row}-{suffix}": (experiment, [], SEEDS, what, None)
        for row, (experiment, _) in ROWS.items()
    }


#: the refine phase's redrawn units and the kept policies' sharper votes as they were before
#: they became defaults: every row measured before pins them (``before_redraw``)
BEFORE_REDRAW = ["algorithm.refine_redraw=0.0", "algorithm.kept_sharpness=1.0"]
#: the library's defaults on the experiments that pin the search (their TOMLs pin
#: ``kept_sharpness = 1``): ``NEW`` with the kept policies' sharper votes
NEWEST = [*NEW, "algorithm.kept_sharpness=10"]
#: rows of the sweeps that chose them (this session's); ``cognet-ROW`` rows are the defaults
AFTER_REDRAW = {
    "bearing-chase-redraw-only": (
        "bearing-chase-n5",
        ["algorithm.kept_sharpness=1.0"],
        SEEDS,
        "candidate: the refine phase with refine_redraw 0.5 alone (kept policies as they were)",
        "cognet-bearing-chase-before-redraw",
    ),
    **{
        f"{row}-redraw-quarter": (
            ROWS[row][0],
            ["algorithm.refine_redraw=0.25"],
            SEEDS,
            "candidate: a quarter of the refine phase's candidates redraw a unit (the rule's "
            "half on scalar observations)",
            f"cognet-{row}",
        )
        for row in ("bearing-chase", "hearing-tiger-noisy", "box-push")
    },
    "plume-redraw-kept10": (
        "plume-n5",
        ["algorithm.refine_redraw=0.5"],
        SEEDS,
        "candidate: refine_redraw 0.5 on the 3 x 3 patch (the rule's 'auto' gives 0 there), "
        "kept_sharpness 10",
        "cognet-plume-before-redraw",
    ),
    "tagging-thesis-n3-sharp10": (
        "tagging-thesis-n3",
        [*NEW, "algorithm.refine_redraw=0.0", "algorithm.vote_sharpness=10"],
        SEEDS,
        "candidate: every candidate's votes x 10 (vote_sharpness), no redrawn units",
        "tagging-thesis-n3-defaults",
    ),
    "tagging-thesis-n3-kept10": (
        "tagging-thesis-n3",
        [*NEW, "algorithm.refine_redraw=0.0", "algorithm.kept_sharpness=10"],
        SEEDS,
        "candidate: the kept policies' votes x 10 (kept_sharpness), no redrawn units",
        "tagging-thesis-n3-defaults",
    ),
    **{
        f"paper-budget-1of64-{suffix}": (
            "tagging-paper-auto",
            ["algorithm.budget=4.6875e9", "run.probe_seconds=10", *replaced(BEFORE_REDRAW, extra)],
            3,
            f"1/64 of the paper's budget, {what}",
            "paper-budget-1of64-now",
        )
        for suffix, extra, what in (
            ("sharp10", ["algorithm.vote_sharpness=10"], "candidate: vote_sharpness 10"),
            ("kept10", ["algorithm.kept_sharpness=10"], "candidate: kept_sharpness 10"),
        )
    },
    **{
        f"{experiment}-defaults-now": (experiment, [*NEWEST, *paired], SEEDS, what, experiment)
        for experiment, paired in (
            ("tagging-thesis-n3", []),
            ("tagging-thesis-n6", []),
            ("heatmap-2d-n4", UNPAIRED),
        )
        for what in ("the library's defaults (with refine_redraw and kept_sharpness)",)
    },
    "paper-budget-1of64-levels3": (
        "tagging-paper-auto",
        ["algorithm.budget=4.6875e9", "run.probe_seconds=10", "algorithm.refine_levels=3"],
        3,
        "1/64 of the paper's budget, candidate: the defaults with the refine phase in 3 parts, "
        "coarse to fine (refine_levels 3)",
        "paper-budget-1of64-redraw",
    ),
    **{
        f"paper-budget-{frac}-redraw": (
            "tagging-paper-auto",
            [f"algorithm.budget={budget}", "run.probe_seconds=10"],
            3,
            f"{what} of the paper's 3e11 agent-steps under the defaults with refine_redraw and "
            "kept_sharpness",
            f"paper-budget-{frac}-now",
        )
        for frac, budget, what in (("1of64", "4.6875e9", "1/64"), ("1of8", "3.75e10", "1/8"))
    },
    **earlier_defaults("before-redraw", "the defaults before refine_redraw and kept_sharpness"),
}


def before_redraw(name: str, overrides: list[str]) -> list[str]:
    """``overrides`` of row ``name`` with ``BEFORE_REDRAW``'s fields it does not set, for the
    rows measured before those fields became defaults."""
    if name in AFTER_POLISH or name in AFTER_AXES:
        return overrides
    if name in AFTER_REDRAW and not name.endswith("-before-redraw"):
        return overrides
    return replaced(BEFORE_REDRAW, overrides)


#: the polish after the search as it was before it became a default: every row measured
#: before pins it off (``before_polish``)
BEFORE_POLISH = ["algorithm.polish_share=0.0"]
#: the library's defaults on the experiments that pin the search, with the polish
NEWEST_POLISHED = [*NEWEST, "algorithm.polish_share=0.25"]
#: rows measured since the polish became a default (``polish_share`` 0.25)
AFTER_POLISH = {
    **{
        f"{experiment}-defaults-polish": (
            experiment,
            [*NEWEST_POLISHED, *paired],
            SEEDS,
            what,
            f"{experiment}-defaults-now",
        )
        for experiment, paired in (
            ("tagging-thesis-n3", []),
            ("tagging-thesis-n6", []),
            ("heatmap-2d-n4", UNPAIRED),
        )
        for what in ("the library's defaults (with the polish after the search)",)
    },
    "paper-budget-1of64-polish": (
        "tagging-paper-auto",
        ["algorithm.budget=4.6875e9", "run.probe_seconds=10"],
        3,
        "1/64 of the paper's 3e11 agent-steps under the defaults with the polish",
        "paper-budget-1of64-redraw",
    ),
    **earlier_defaults("before-polish", "the defaults before the polish after the search"),
}


def before_polish(name: str, overrides: list[str]) -> list[str]:
    """``overrides`` of row ``name`` with ``BEFORE_POLISH``, for the rows measured before the
    polish became a default."""
    if name in AFTER_AXES or (name in AFTER_POLISH and not name.endswith("-before-polish")):
        return overrides
    return replaced(BEFORE_POLISH, overrides)


#: the polish as it was before its AXIS moves and its extension past the share became
#: defaults: every row measured before with the polish on pins them off (``before_axes``)
BEFORE_AXES = ["algorithm.polish_axes=false", "algorithm.polish_extend=1.0"]
#: the library's defaults on the experiments that pin the search (their TOMLs pin the polish
#: off): with the polish, its AXIS moves and its extension (defaults of the fields)
NEWEST_AXES = NEWEST_POLISHED
#: the rows swept with ``start_draw`` as a candidate (rows ``ROW-start``)
START_ROWS = (
    "hearing-tiger",
    "hearing-tiger-noisy",
    "readme-seek",
    "beacon-clean",
    "box-push",
    "bearing-chase",
)
#: a candidate measured on every row with the code of commit a36ff1e (68c99d8 with the two
#: defaults changed, as d29fbb7 changes them on main; run with ``PYTHONPATH`` set to its
#: checkout), then adopted: the defaults since
S0I800_WHAT = (
    "the defaults since (measured as a candidate, code of commit a36ff1e): start_draw with "
    "start_spread 0 (start roles move in the refine phase) and ITERATIONS_RANGE up to 800 at "
    "187.5 rollouts per candidate (twice the exploring searches)"
)
#: rows of the defaults since that ran later, with the code of main (da5cefd)
S0I800_LATER = {
    "paper-budget-1of8": "1/8 of the paper's 3e11 agent-steps under the defaults (code of da5cefd)",
    "paper-budget-full": (
        "the paper's whole 3e11 agent-steps under the defaults, seed 0 (code of da5cefd)"
    ),
    "paper-budget-full-seeds12": (
        "the paper's whole 3e11 agent-steps under the defaults, seeds 1 and 2 (code of 2c56d27)"
    ),
}
#: the pinned experiments (tagging, heatmap) under the defaults since: their TOMLs pin
#: ``start_draw`` off, which the candidate's code did not yet
NEWEST_STARTS = ["algorithm.start_draw=true", "algorithm.start_spread=0.0"]
#: rows measured since the AXIS moves and the extension became defaults
AFTER_AXES = {
    **{
        f"{experiment}-defaults-axes": (
            experiment,
            NEWEST_AXES,
            SEEDS,
            "the library's defaults (the polish with AXIS and START moves and its extension)",
            f"{experiment}-defaults-polish",
        )
        for experiment in ("tagging-thesis-n3", "tagging-thesis-n6")
    },
    "paper-budget-1of64-axes": (
        "tagging-paper-auto",
        ["algorithm.budget=4.6875e9", "run.probe_seconds=10"],
        3,
        "1/64 of the paper's 3e11 agent-steps under the defaults with the polish's AXIS and "
        "START moves and extension",
        "paper-budget-1of64-polish",
    ),
    "paper-budget-1of8-axes": (
        "tagging-paper-auto",
        ["algorithm.budget=3.75e10", "run.probe_seconds=10"],
        3,
        "1/8 of the paper's 3e11 agent-steps under the defaults with the polish's AXIS and "
        "START moves and extension",
        "paper-budget-1of64-axes",
    ),
    **earlier_defaults(
        "before-axes", "the defaults before the polish's AXIS and START moves and its extension"
    ),
    "hearing-tiger-noisy-budget4": (
        "hearing-tiger-noisy-n7",
        ["algorithm.budget=2.4e9"],
        SEEDS,
        "noisy Dec-Tiger at 4 times the default budget",
        "cognet-hearing-tiger-noisy",
    ),
    "plume-i800": (
        "plume-n5",
        ["algorithm.iterations=800", "algorithm.eval_rollouts=188"],
        SEEDS,
        "candidate: 800 iterations x 188 rollouts per candidate, the same budget (twice the "
        "exploring searches, each of about 95 iterations)",
        "cognet-plume",
    ),
    "paper-budget-1of64-start": (
        "tagging-paper-auto",
        ["algorithm.budget=4.6875e9", "run.probe_seconds=10", "algorithm.start_draw=true"],
        3,
        "1/64 of the paper's 3e11 agent-steps, candidate: every candidate draws per agent the "
        "node whose role it starts in (start_draw)",
        "paper-budget-1of64-axes",
    ),
    **{
        f"{row}-start": (
            ROWS[row][0],
            ["algorithm.start_draw=true"],
            SEEDS,
            "candidate: every candidate draws per agent the node whose role it starts in "
            "(start_draw)",
            f"cognet-{row}",
        )
        for row in START_ROWS
    },
    **{
        f"{experiment}-start": (
            experiment,
            [*NEWEST_AXES, "algorithm.start_draw=true"],
            SEEDS,
            "candidate: the library's defaults with start_draw",
            f"{experiment}-defaults-axes",
        )
        for experiment in ("tagging-thesis-n3", "tagging-thesis-n6")
    },
    **{
        f"{name}-spread{spread}": (
            experiment,
            [*extra, "algorithm.start_draw=true", f"algorithm.start_spread={spread}"],
            seeds,
            f"candidate: start_draw from a first categorical with {spread} of its mass spread "
            "evenly over the nodes, the rest on node 0 (start_spread)"
            + (": the start roles move in the refine phase only" if spread == 0 else ""),
            f"{name}-start",
        )
        for name, experiment, extra, seeds, spreads in (
            ("hearing-tiger-noisy", "hearing-tiger-noisy-n7", [], SEEDS, (0.3, 0.0)),
            (
                "paper-budget-1of64",
                "tagging-paper-auto",
                ["algorithm.budget=4.6875e9", "run.probe_seconds=10"],
                3,
                (0.0,),
            ),
        )
        for spread in spreads
    },
    **{
        f"{name}-s0i800": (
            experiment,
            extra,
            seeds,
            S0I800_LATER.get(name, S0I800_WHAT),
            earlier,
        )
        for name, experiment, extra, seeds, earlier in (
            *((row, ROWS[row][0], [], SEEDS, f"cognet-{row}") for row in ROWS),
            *(
                (e, e, [*NEWEST_AXES, *NEWEST_STARTS], SEEDS, f"{e}-defaults-axes")
                for e in ("tagging-thesis-n3", "tagging-thesis-n6")
            ),
            (
                "heatmap-2d-n4",
                "heatmap-2d-n4",
                [*NEWEST_AXES, *UNPAIRED, *NEWEST_STARTS],
                SEEDS,
                "heatmap-2d-n4-defaults-polish",
            ),
            (
                "paper-budget-1of64",
                "tagging-paper-auto",
                ["algorithm.budget=4.6875e9", "run.probe_seconds=10"],
                3,
                "paper-budget-1of64-axes",
            ),
            (
                "paper-budget-1of8",
                "tagging-paper-auto",
                ["algorithm.budget=3.75e10", "run.probe_seconds=10"],
                3,
                "paper-budget-1of8-axes",
            ),
            (  # seed 0 alone (35 min), then seeds 1 and 2 side by side (row -seeds12)
                "paper-budget-full",
                "tagging-paper-auto",
                ["algorithm.budget=3e11", "run.probe_seconds=10"],
                1,
                "paper-budget-1of8-s0i800",
            ),
            (
                "paper-budget-full-seeds12",
                "tagging-paper-auto",
                ["algorithm.budget=3e11", "run.probe_seconds=10"],
                (1, 2),
                "paper-budget-1of8-s0i800",
            ),
        )
    },
    "hearing-tiger-noisy-n9-axes": (
        "hearing-tiger-noisy-n7",
        ["algorithm.nodes=9"],
        SEEDS,
        "noisy Dec-Tiger with 9 nodes (the hand-written controller's count 4 needs 9), under "
        "the defaults with the AXIS and START moves",
        "hearing-tiger-noisy-n9",
    ),
}

#: a candidate: the polish's COUNTER moves (``polish_counter``), swept on every row whose
#: inputs have at most 4 features (the plume's 9 and the heatmap's 16 get none: their sweeps
#: would repeat the "-s0i800" rows seed for seed)
COUNTER_WHAT = (
    "the polish's COUNTER moves (polish_counter: every controller rewritten as a counter of the "
    "evidence on one feature), valued in a sweep of their own before the polish's sweeps"
)
#: their first version (code of commit 1e795fc), then replaced: the COUNTER moves listed in
#: every sweep of the polish, so fewer sweeps fitted in its share
COUNTER_EVERY_WHAT = (
    "first version of the COUNTER moves (code of commit 1e795fc): listed in every sweep of the "
    "polish, so fewer sweeps fit in its share"
)
#: rows whose inputs have more than 4 features: the polish has no COUNTER moves there
NO_COUNTER_ROWS = ("plume",)
AFTER_AXES.update(
    {
        f"{name}-counter": (experiment, extra, seeds, COUNTER_WHAT, f"{name}-s0i800")
        for name, experiment, extra, seeds in (
            *((row, ROWS[row][0], [], SEEDS) for row in ROWS if row not in NO_COUNTER_ROWS),
            *(
                (e, e, [*NEWEST_AXES, *NEWEST_STARTS], SEEDS)
                for e in ("tagging-thesis-n3", "tagging-thesis-n6")
            ),
            (
                "paper-budget-1of64",
                "tagging-paper-auto",
                ["algorithm.budget=4.6875e9", "run.probe_seconds=10"],
                3,
            ),
        )
    }
)
AFTER_AXES.update(
    {
        f"{name}-every": (experiment, overrides, seeds, COUNTER_EVERY_WHAT, earlier)
        for name, (experiment, overrides, seeds, _, earlier) in dict(AFTER_AXES).items()
        if name.endswith("-counter") and (RESULTS / f"{name}-every" / "runs.json").is_file()
    }
)
AFTER_AXES["plume-i1600-counter"] = (
    "plume-n5",
    ["algorithm.iterations=1600", "algorithm.eval_rollouts=94"],
    SEEDS,
    "candidate: 1600 iterations x 94 rollouts per candidate, the same budget (twice the "
    "exploring searches of the defaults, each of about 95 iterations)",
    "plume-s0i800",
)
AFTER_AXES["plume-budget2x"] = (
    "plume-n5",
    ["algorithm.budget=2.4e9"],
    SEEDS,
    "the defaults (code of main) with twice the default budget, 2.4e9 agent-steps",
    "plume-s0i800",
)
AFTER_AXES["plume-whiten"] = (
    "plume-n5",
    ["algorithm.whiten_inputs=true"],
    SEEDS,
    "candidate: the patch PCA-whitened (whiten_inputs; the sweep ran as a candidate default, "
    "'auto' deciding true: its runs.json records no override, the resolved flag true)",
    "plume-s0i800",
)
AFTER_AXES["hearing-tiger-noisy-n9-counter"] = (
    "hearing-tiger-noisy-n7",
    ["algorithm.nodes=9"],
    SEEDS,
    "noisy Dec-Tiger with 9 nodes (the hand-written controller's count 4 needs 9), under the "
    "defaults with the polish's COUNTER moves (code of main)",
    "hearing-tiger-noisy-n9-axes",
)


def before_axes(name: str, overrides: list[str]) -> list[str]:
    """``overrides`` of row ``name`` with ``BEFORE_AXES``, for the rows measured with the
    polish on before its AXIS moves and extension became defaults."""
    if name in AFTER_AXES and not name.endswith("-before-axes"):
        return overrides
    if "algorithm.polish_share=0.0" in overrides:  # no polish: the fields change nothing
        return overrides
    return replaced(BEFORE_AXES, overrides)


EXTRA = {
    name: (experiment, before_rule(name, experiment, overrides), *rest)
    for name, (experiment, overrides, *rest) in {
        **EXTRA,
        **AFTER_REDRAW,
        **AFTER_POLISH,
        **AFTER_AXES,
    }.items()
}
EXTRA = {
    name: (
        experiment,
        before_axes(name, before_polish(name, before_redraw(name, overrides))),
        *rest,
    )
    for name, (experiment, overrides, *rest) in EXTRA.items()
}


def _sweep(experiment: str, overrides: list[str], seeds, out: Path, imports=()) -> None:
    """``cognet-jax sweep`` of ``seeds`` seeds from 0, or of ``(first, count)``."""
    first, count = seeds if isinstance(seeds, tuple) else (0, seeds)
    cmd = ["cognet-jax", *imports, "sweep", experiment, "--seeds", str(count), "--no-progress"]
    cmd += ["--first-seed", str(first)] if first else []
    for o in ["run.plots=false", *overrides]:
        cmd += ["--set", o]
    cmd += ["--out", str(out), "--overwrite"]
    print(" ".join(cmd), flush=True)
    subprocess.run(cmd, check=True)


def run_cognet(rows: list[str]) -> None:
    for row in rows:
        imports = ["--import", str(IMPORTS[row])] if row in IMPORTS else []
        _sweep(ROWS[row][0], [], SEEDS, RESULTS / f"cognet-{row}", imports)


#: rows whose observation is a scalar: COG-DICE's regions apply (``cogdice`` column)
SCALAR_ROWS = ("hearing-tiger", "hearing-tiger-noisy", "bearing-chase", "box-push", "readme-seek")


def run_cogdice(rows: list[str]) -> None:
    """COG-DICE's defaults (``experiment.algorithm = "cogdice"``, the experiment's nodes) on
    the rows of ``rows`` whose observation is a scalar."""
    for row in rows:
        if row in SCALAR_ROWS:
            imports = ["--import", str(IMPORTS[row])] if row in IMPORTS else []
            overrides = ["experiment.algorithm=cogdice"]
            _sweep(ROWS[row][0], overrides, SEEDS, RESULTS / f"cogdice-{row}", imports)


#: rows whose observation is an image patch: the encoded variant applies (``encoded`` column)
ENCODED_ROWS = ("plume",)
#: the encoded variant: the defaults on a VAE's encoder mean, the VAE trained on the
#: simulator's own observations with the heatmap's encoded experiments' settings (a 2-D latent
#: at KL weight 0.01: cognet_jax/experiments/heatmap-encoded-n4.toml)
ENCODED = ['network.observation="encoded"', "network.vae_latent=2", "network.vae_kl_weight=0.01"]


def run_encoded(rows: list[str]) -> None:
    """The encoded variant (``ENCODED``) on the rows of ``rows`` whose observation is an image
    patch."""
    for row in rows:
        if row in ENCODED_ROWS:
            imports = ["--import", str(IMPORTS[row])] if row in IMPORTS else []
            _sweep(ROWS[row][0], ENCODED, SEEDS, RESULTS / f"encoded-{row}", imports)


def run_extra(names: list[str]) -> None:
    for name in names:
        experiment, overrides, seeds, _, _ = EXTRA[name]
        rows = [row for row, (exp, _) in ROWS.items() if exp == experiment and row in IMPORTS]
        imports = ["--import", str(IMPORTS[rows[0]])] if rows else []
        _sweep(experiment, overrides, seeds, RESULTS / name, imports)


#: the rollouts of the rescoring (``run_rescore``): the hand-written controllers' precision
RESCORE_ROLLOUTS = HAND_HONEST_ROLLOUTS
#: what the rescoring writes beside a sweep's runs.json
RESCORED = "rescored.json"


def _rescored_value(run: Path, imports: list[str]) -> dict:
    """The last ``RESCORE_ROLLOUTS``-rollout evaluation of the run folder ``run`` (its own
    evaluation key, ``cognet-jax evaluate``), made first when it has none."""

    def found():
        path = run / "evaluations.jsonl"
        lines = path.read_text().splitlines() if path.is_file() else []
        hits = [e for e in map(json.loads, lines) if e["rollouts"] == RESCORE_ROLLOUTS]
        return hits[-1] if hits else None

    if found() is None:
        cmd = ["cognet-jax", *imports, "evaluate", str(run), "--rollouts", str(RESCORE_ROLLOUTS)]
        print(" ".join(cmd), flush=True)
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    return found()


def run_rescore(rows: list[str], source: Path | None) -> None:
    """Every seed's kept policy of each row's defaults sweep (``_defaults_sweep``) on
    ``RESCORE_ROLLOUTS`` rollouts of its own evaluation key, written to ``RESCORED`` beside
    the sweep's runs.json. The run folders are the sweep's (``runs/``, not committed) or, with
    ``source`` (a folder holding one sweep folder per experiment, named as the experiment), a
    sweep of the same experiment whose 10,000-rollout values equal the committed ones seed for
    seed: the same policies (a run is deterministic on one machine)."""
    for row in rows:
        sweep = _defaults_sweep(row)[0]
        experiment = Path(ROWS[row][0]).name.removesuffix(".toml")
        folder = sweep.parent if source is None else source / experiment
        if not (folder / "runs.json").is_file():
            print(f"{row}: no sweep in {folder}; skipped", flush=True)
            continue
        committed = json.loads(sweep.read_text())["rows"]
        rerun = json.loads((folder / "runs.json").read_text())["rows"]
        pairs = {r["seed"]: r["final_value"]["mean"] for r in rerun}
        if any(pairs.get(r["seed"]) != r["final_value"]["mean"] for r in committed):
            print(f"{row}: {folder} is not the committed sweep seed for seed; skipped")
            continue
        imports = ["--import", str(IMPORTS[row])] if row in IMPORTS else []
        seeds = [
            {
                "seed": r["seed"],
                **_rescored_value(folder / "runs" / f"setting0-seed{r['seed']}", imports),
            }
            for r in committed
        ]
        record = {
            "rollouts": RESCORE_ROLLOUTS,
            "sweep": str(sweep.relative_to(HERE)),
            "seeds": seeds,
        }
        (sweep.parent / RESCORED).write_text(json.dumps(record, indent=1) + "\n")
        print(f"{row}: wrote {sweep.parent / RESCORED}", flush=True)


#: nodes a hand-written controller of these rows takes, by its grid point
HAND_NODES = {
    "hearing-tiger": lambda theta: 2 * theta["count"] + 1,
    "hearing-tiger-noisy": lambda theta: 2 * theta["count"] + 1,
}


def _hand_within_nodes(row: str, hand: dict) -> str:
    """Where the tuned hand-written controller takes more nodes than the row's search has:
    the best grid point within them, valued as the tuned one (``HONEST_SEED``)."""
    if row not in HAND_NODES:
        return ""
    import jax
    import numpy as np

    from cognet_jax.api import build_env
    from cognet_jax.baselines import HONEST_SEED, hand_returns, simulator_module

    config = _config(row)
    nodes = config.algorithm.nodes
    if HAND_NODES[row](hand["best"]) <= nodes:
        return ""
    fits = [(theta, v) for theta, v in hand["values"] if HAND_NODES[row](theta) <= nodes]
    theta = max(fits, key=lambda tv: tv[1])[0]
    env, params = build_env(config)
    controller, policy = simulator_module(config.env.name).hand_controller(env, **theta)
    key = jax.random.key(HONEST_SEED)
    r = np.asarray(hand_returns(env, params, controller, policy, key, hand["rollouts"]))
    point = ", ".join(f"{k} = {v}" for k, v in theta.items())
    return (
        f" ({HAND_NODES[row](hand['best'])} nodes; within the search's {nodes}: {point}, "
        f"{r.mean():.3f} +- {r.std() / np.sqrt(len(r)):.3f})"
    )


def _holds(mean: float, worst: float, bar: float) -> bool:
    """Issue 52's bar: the 8-seed mean at least ``bar``, no seed below it by over 3%."""
    return mean >= bar and worst >= bar - 0.03 * abs(bar)


def _search_cell(
    path: Path, hand: float | None, history: Path | None = None, previous: Path | None = None
) -> str:
    """A cell of the suite table from the sweep ``path``; the earlier defaults' sweeps are
    found beside ``history`` (by default ``path``: ``NAME-before-...``), and with ``history``
    its own mean is the one before the start roles and twice the searches; ``previous``: the
    sweep before the polish's COUNTER moves."""
    if not path.is_file():
        return "not run"
    data = json.loads(path.read_text())
    values = [r["final_value"]["mean"] for r in data["rows"]]
    mean = sum(values) / len(values)
    alg = data["config"]["algorithm"]
    population = alg.get("candidates", alg.get("samples"))  # COG-DICE calls them samples
    steps = (  # the search's own count where the weight-space sizes do not apply (COG-DICE)
        _agent_steps(data["config"])
        if "candidates" in alg
        else data["rows"][0]["simulated_agent_steps"]
    )
    sizes = f"{alg['iterations']} x {population} x {alg['eval_rollouts']}"
    polish = [finish_of(r).get("rollouts") for r in data["rows"]]
    if "candidates" in alg and all(p is not None for p in polish):  # the polish's, per run
        from cognet_jax.api import build_env
        from cognet_jax.registry import config_from_dict

        env, _ = build_env(config_from_dict(data["config"]))
        extra = sum(polish) / len(polish) * env.horizon * env.num_agents
        sizes += f", the polish {extra:.2g} more on average"
    verdict, rescored = "", path.parent / RESCORED
    if rescored.is_file():  # the same policies valued as precisely as the hand-written one
        record = json.loads(rescored.read_text())
        precise = [x["mean"] for x in record["seeds"]]
        judged = (sum(precise) / len(precise), min(precise))
        note = (
            f" on 10,000 rollouts per seed; {judged[0]:.3f}, min {judged[1]:.3f} on "
            f"{record['rollouts']:,}"
        )
    else:
        judged, note = (mean, min(values)), ""
    if hand is not None:
        verdict = " (holds)" if _holds(*judged, hand) else " (**below**)"
    verdict = note + verdict
    history = path if history is None else history
    before_cell = ""
    for suffix, what in (
        ("-before-rule", "the horizon rule"),
        ("-before-distinct", "distinct"),
        ("-before-redraw", "redraw"),
        ("-before-polish", "the polish"),
        ("-before-axes", "the AXIS and START moves"),
    ):
        before = _values(history.parent.parent / f"{history.parent.name}{suffix}" / "runs.json")
        if before:
            before_cell += f"; before {what} {sum(before) / len(before):.3f}"
    before = _values(history) if history != path else None
    if before:
        mean_before = sum(before) / len(before)
        before_cell += f"; before the start roles and twice the searches {mean_before:.3f}"
    before = _values(previous) if previous is not None else None
    if before:
        before_cell += f"; before the COUNTER moves {sum(before) / len(before):.3f}"
    return (
        f"{mean:.3f}, min {min(values):.3f}{verdict}; {data['wall_s'] / len(values):.0f} s per "
        f"seed ({len(values)} seeds in one sweep); {steps:.2g} agent-steps ({sizes}){before_cell}"
    )


def _values(path: Path) -> list[float] | None:
    if not path.is_file():
        return None
    return [r["final_value"]["mean"] for r in json.loads(path.read_text())["rows"]]


def _first_reach(rows: list[dict], target: float) -> str:
    """Median over seeds of the wall seconds at which the anytime best's honest value (the
    probes, and the final value at the run's end) first reached ``target``; "never" for a
    seed that did not."""
    times = []
    for r in rows:
        hit = [p["wall_s"] for p in r.get("probes") or [] if p["value"] >= target]
        if r["final_value"]["mean"] >= target:  # the policy handed back (after any polish)
            hit.append(r["wall_s"])
        times.append(min(hit) if hit else float("inf"))
    times.sort()
    median = times[len(times) // 2]
    shown = ", ".join("never" if t == float("inf") else f"{t:.0f}" for t in times)
    return f"{'never' if median == float('inf') else f'{median:.0f} s'} ({shown})"


#: the hand-written controllers of tagging (SPEC section 8): thesis and COG-DICE paper setting
TAGGING_REACTIVE = {"thesis": 20.76, "cogdice-paper": 108.0}


def extra_table() -> list[str]:
    rows = [
        "| sweep | experiment | what it tests | seeds | honest mean (min, max) | earlier "
        "sweep: mean (min) | agent-steps per run | sweep wall s | time to the hand-written "
        "controller: median (per seed) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name, (experiment, overrides, _, what, earlier) in EXTRA.items():
        path = RESULTS / name / "runs.json"
        values = _values(path)
        if values is None:
            continue
        data = json.loads(path.read_text())
        # the earlier sweep: of experiments/results/sweeps, else of the suite's own folder
        before = _values(HERE / "results" / "sweeps" / (earlier or "-") / "runs.json")
        before = before or _values(RESULTS / (earlier or "-") / "runs.json")
        before_cell = f"{sum(before) / len(before):.3f} ({min(before):.3f})" if before else ""
        setting = data["config"]["env"].get("setting")
        target = TAGGING_REACTIVE.get(setting) if experiment.startswith("tagging") else None
        reach = _first_reach(data["rows"], target) if target and "probe" in str(overrides) else ""
        sets = " ".join(f"`{o}`" for o in overrides)
        rows.append(
            f"| {name} | {Path(experiment).name} {sets} | {what} | {len(values)} | "
            f"{sum(values) / len(values):.3f} ({min(values):.3f}, {max(values):.3f}) | "
            f"{before_cell} | {_agent_steps(data['config']):.3g} | {data['wall_s']:.0f} | "
            f"{reach} |"
        )
    return rows


def single_runs_table() -> list[str]:
    """One ``cognet-jax train`` at a time (folders ``*-single/seedS`` of ``RESULTS``): each
    run's honest value, wall and compile seconds, and the wall time at which its anytime best
    first reached the hand-written controller (``_first_reach``: probes, then the end)."""
    rows = [
        "| runs | experiment | seed | honest value | wall s (compile s) | time to the "
        "hand-written controller |",
        "|---|---|---|---|---|---|",
    ]
    for folder in sorted(RESULTS.glob("*-single")):
        for path in sorted(folder.glob("seed*/results.json")):
            r = json.loads(path.read_text())
            target = TAGGING_REACTIVE.get(r["config"]["env"].get("setting"))
            reach = _first_reach([r], target).split(" (")[0] if target else ""
            rows.append(
                f"| {folder.name} | {r['experiment']} | {r['seed']} | "
                f"{r['final_value']['mean']:.3f} | {r['wall_s']:.1f} ({r['compile_s']:.1f}) | "
                f"{reach} (target {target}) |"
            )
    return rows


SINGLE_NOTES = """Each row is one `cognet-jax train EXPERIMENT --seed S` with the overrides of
its sweep (paper-budget-1of64-axes, tagging-thesis-n3-defaults-axes) and `run.probe_seconds`
(10 s on the paper setting, 1 s on the thesis one), run one after another: the first of each
compiled its programs, the others found them kept. The values equal the sweeps' seed for
seed. The thesis runs shared the machine with a sweep."""


def _defaults_sweep(row: str) -> tuple[Path, Path | None]:
    """The runs.json of the sweep of ``row`` under the defaults of now, and of the sweep
    before the COUNTER moves (None where the row has none or was not re-run with them)."""
    previous = RESULTS / f"{row}-s0i800" / "runs.json"  # the defaults of S0I800_WHAT
    now = RESULTS / f"{row}-counter" / "runs.json"  # since: with COUNTER moves
    if row in NO_COUNTER_ROWS or not now.is_file():
        return previous, None
    return now, previous


def _at_hand_nodes(row: str, hand_path: Path) -> str:
    """Where the tuned hand-written controller takes more nodes than the row's experiment
    gives the search: the defaults' sweep with as many (``ROW-nN-counter``), if run."""
    if row not in HAND_NODES or not hand_path.is_file():
        return ""
    hand = json.loads(hand_path.read_text())
    nodes = HAND_NODES[row](hand["best"])
    values = _values(RESULTS / f"{row}-n{nodes}-counter" / "runs.json")
    if nodes <= _config(row).algorithm.nodes or not values:
        return ""
    mean = sum(values) / len(values)
    ok = _holds(mean, min(values), hand["honest"][0])
    return (
        f"; with the hand-written controller's {nodes} nodes (`--set algorithm.nodes={nodes}`): "
        f"{mean:.3f}, min {min(values):.3f} ({'holds' if ok else '**below**'})"
    )


def table() -> list[str]:
    from cognet_jax.plugins import import_plugin

    for path in IMPORTS.values():  # the configs of their sweeps name their simulators
        import_plugin(str(path))
    rows = [
        "| problem | what it covers | hand-written controller: grid -> tuned, value | upper "
        "bound | COG-DICE defaults | COGNet-DICE defaults: 8-seed mean, min; wall; agent-steps "
        "| encoded variant |",
        "|---|---|---|---|---|---|---|",
    ]
    not_counted = []
    for row, (experiment, what) in ROWS.items():
        hand_path = RESULTS / f"hand-{row}.json"
        hand, hand_cell, bound_cell = None, "not run", ""
        if hand_path.is_file():
            h = json.loads(hand_path.read_text())
            hand = h["honest"][0]
            grid = "; ".join(f"{k} in {list(v)}" for k, v in h["grid"].items())
            best = ", ".join(f"{k} = {v}" for k, v in h["best"].items())
            hand_cell = f"{grid} -> {best}: **{hand:.3f}** +- {h['honest'][1]:.3f}"
            hand_cell += _hand_within_nodes(row, h)
            if h["bound"]:
                bound_cell = f"{h['bound'][0]:.3f} ({h['bound'][1]})"
        earlier = RESULTS / f"cognet-{row}" / "runs.json"
        now, previous = _defaults_sweep(row)
        if row not in NO_COUNTER_ROWS and previous is None:
            not_counted.append(row)
        cognet = _search_cell(now, hand, earlier, previous) if now.is_file() else "not run"
        cognet += _at_hand_nodes(row, hand_path)
        if cognet == "not run" and earlier.is_file():
            change = "the start roles and twice the searches"
            cognet = f"not yet re-run under {change}; before: " + _search_cell(earlier, hand)
        for suffix, change in (
            ("-before-axes", "the polish's AXIS and START moves and extension"),
            ("-before-polish", "the polish"),
            ("-before-redraw", "refine_redraw, kept_sharpness and the polish"),
        ):
            earlier = RESULTS / f"cognet-{row}{suffix}" / "runs.json"
            if cognet == "not run" and earlier.is_file():  # not swept under the defaults of now
                cognet = f"not yet re-run under {change}; before: " + _search_cell(earlier, hand)
        cogdice = _search_cell(RESULTS / f"cogdice-{row}" / "runs.json", hand)
        encoded = "n/a"
        if row in ENCODED_ROWS:
            encoded = _search_cell(RESULTS / f"encoded-{row}" / "runs.json", hand)
        name = Path(experiment).name if row in IMPORTS else experiment
        rows.append(
            f"| {row} (`{name}`) | {what} | {hand_cell} | {bound_cell} | {cogdice} | "
            f"{cognet} | {encoded} |"
        )
    if not_counted:
        rows += ["", f"Not yet re-run with the COUNTER moves: {', '.join(not_counted)}."]
    return rows


NOTES = """\
"holds" means the 8-seed mean is at least the hand-written controller's value and no seed is
below it by more than 3% of its magnitude (issue 52's bar); "below" marks a row where it does
not. The hand-written controllers are the rules of each simulator's module (`hand_controller`):
counting clear hearings (Dec-Tiger), stepping along the larger offset (beacon), stepping toward
the bearing (chase), climbing the patch (plume), pushing when the range is small (box pushing).
The encoded variant runs the defaults on a VAE's encoder mean, the VAE trained on the
simulator's own observations (`network.observation = "encoded"`, a 2-D latent at KL weight 0.01
as the heatmap's encoded experiments; `python experiments/suite.py encoded ROW`) on the row
whose observation is an image patch, the plume; the other rows observe no image ("n/a";
heatmap rows: experiments/README.md, heatmap). On the plume it ends well below the raw patch
(its VAE trained on the random controller's patches, most of them far from the source, with
the heatmap's settings, not chosen for this simulator); its sweep (2026-12-01) shared the
machine with the test suite for most of its hour, so its wall time is an upper bound. The defaults
size the search from a noise pilot (cognet_jax/algorithms/sizing.py): on Dec-Tiger, its noisy
variant and box pushing it moves the budget from rollouts to candidates; on beacon, chase and
the README simulator it keeps the sizes of before. They end with a refine phase
(`algorithm.refine`, the last quarter of the iterations searching around the kept policy). The
horizon rule (`resolve_search` in cognet_jax/algorithms/cognet_weights_settings.py): where the
horizon is longer than the controller has nodes -- every row of this table -- the default vote
starts at the units' scale and the exploring searches are short (`default_vote_scale` 10,
`restart_tol` and `refine_tol` 0.1); "before the horizon rule" gives the 8-seed mean of the same
sweep with the values of before (1, 0.02, 0.2; rows "-before-rule" of the next table). The
sweeps of noisy Dec-Tiger, both beacons, box pushing and the README simulator ran before the
rule with its three values set by `--set` (their runs.json record those overrides); the
Dec-Tiger and chase sweeps ran again under the rule and gave the same values seed for seed. Wall
times were measured one sweep at a time, at times beside lighter work (the test suite, a second
session's commands) on the same 2 cores. "not run" marks a simulator not yet swept under the
defaults. `standardize_inputs` "auto" standardises the plume's 3 x 3 patch only of these rows
(`missed_inputs`: inputs narrow or far off centre; row cognet-plume-raw of the next table: a
sweep without). `distinct_actions`
"auto" (`covers_rarely`) draws the nodes' actions without repeats, for the candidates whose
flag says so, on beacon, chase and plume (5 nodes, 5 moves; "before distinct" gives the sweep of
the defaults before it, rows "-before-distinct" of the next table; its first version, commit
d3ca24d, drew the flags on the stream of the hidden weights: every row here ran under the fixed
code, except plume-refine-half). The COG-DICE column
runs COG-DICE's defaults (`--set experiment.algorithm=cogdice`, `python experiments/suite.py
cogdice ROW`) on the rows with a scalar observation; its Dec-Tiger sweep shared the machine with
another sweep and the test suite for most of its hour, and its README-simulator sweep (2026-12-01)
with test runs and a 4000-run sweep, so their wall times are upper bounds.
The defaults of now also keep policies with their votes x 10 (`kept_sharpness`: the argmax
next node) and, on scalar observations, let half of the refine phase's candidates redraw one
hidden unit from the initial distribution (`refine_redraw` "auto", `redraw_share` in
cognet_jax/algorithms/cognet_weights_settings.py); "before redraw" gives the 8-seed mean of the
defaults before both (rows "-before-redraw" of the next table, the sweeps of this table's
earlier version). Since then the defaults also polish the kept policy after the search
(`polish_share` 0.25, cognet_jax/algorithms/weight_polish.py: one threshold, vote or action at
a time, valued on paired rollouts); "before the polish" gives the sweep of the defaults before
it (rows "-before-polish"): the search is the same, seed for seed, so the difference is the
polish's alone, and the agent-steps cell adds what it simulated. The grids of the Dec-Tiger
and beacon controllers were widened (their tuned points had been at an edge of the grid):
noisy Dec-Tiger's hand-written controller rose from -18.253 (count 4, margin 1.5) to the
value in the table. The polish of now also rewrites a node's weakest unit as a threshold on one
feature (AXIS, inputs of at most 4 features), lets another node's role start a controller
(START), and goes on past its share while every sweep applies a move (up to twice it:
`polish_axes`, `polish_extend`); "before the AXIS and START moves" gives the sweep of the
polish before them (rows "-before-axes"), again the same search seed for seed. The defaults of
now also draw the start roles in the refine phase (`start_draw`, `start_spread` 0) and size up
to 800 iterations at 187.5 rollouts per candidate (twice the exploring searches): the column
gives their sweeps (rows "-s0i800" of the next table), and "before the start roles and twice the
searches" the sweep of the defaults before them (`cognet-ROW`). A row that says "not yet re-run"
was not swept under them. The polish of now also rewrites every controller as a counter of the
evidence on one feature (COUNTER, `polish_counter`, cognet_jax/algorithms/weight_polish.py):
the column gives its sweeps (rows "-counter" of the next table) and "before the COUNTER moves"
the sweep before it (rows "-s0i800"), the same search seed for seed; the plume (9 features)
has no COUNTER moves, its cell is the sweep before.
Where a cell also gives values "on 200,000", the row's verdict is theirs: every seed's kept
policy evaluated again on 200,000 rollouts of its own evaluation key (`cognet-jax evaluate
RUN --rollouts 200000`; `python experiments/suite.py rescore ROW`, written to the sweep's
rescored.json), the precision of the hand-written controller's value. A seed's honest value
on 10,000 rollouts has a standard error of 0.03-0.10 on these simulators, and every sweep of
the table draws the same 8 evaluation keys (seeds 0-7), so one draw of that noise sits in
every sweep of a row alike: on the README simulator the 8 kept policies play almost alike,
and seed 0's policy on the evaluation keys of seeds 0-7 gives 19.809-19.909, mean 19.850,
where the 8 policies' own 10,000-rollout values average 19.849 and their 200,000-rollout
values 19.888 (experiments/NOTES.md, "The bar and the 10,000-rollout values")."""


EXTRA_NOTES = """\
The defaults race a pool of the 4 best policies on fresh rollouts (`algorithm.best_pool`,
cognet_jax/algorithms/best_pool.py). Rows measured with its first version (commit de9d6d7)
could evict the kept member when its mean was the pool's lowest; the version in the code never
evicts it and keeps non-finite values out (commit 92b7ccb): the "-pool-fixed" rows and the
rows run after the noise pilot. Rows "-before-pilot" ran the budget's split before the pilot
(400 iterations x 200 candidates x 375 rollouts at the default budget); "beacon-k1000" ran the
pilot's first rule, which also bought rollouts with iterations where the pilot asked for more
than the budget's (rejected: 25.44 against 27.28). Rows "-nopool" and "before the pool" ran the
earlier defaults, which kept the policy with the best single fresh value: the maximum of
hundreds of noisy means, whose in-loop estimate was up to 4 above its honest value on tagging
and Dec-Tiger (the sweeps' summary.md files give both).
"Earlier sweep" is the committed 8-seed sweep of the same experiment before tied structures and
restarts (experiments/results/sweeps, table "COGNet-DICE (default)"). The time to the
hand-written controller is read from `run.probe_seconds` probes: the wall time (compile
included, from the start of the sweep's program of all its seeds) at which a seed's anytime best
first had an honest value at or above the reactive controller's (108.0 on the paper setting);
probes of a sweep run the seeds side by side, so a single run reaches it sooner. The two
tagging ablations ran while the untied search still drew two more keys per iteration (other
random numbers for the same search; the untied search now draws exactly the earlier draws, so
the pinned experiments reproduce their committed rows bit for bit). Rows "-vote10" and
"-restart0.1" / "-restart0.2" of beacon and Dec-Tiger ran on working snapshots that wrote the
refine phase's convergence as `restart_tol` of its own starting spread and set the candidate
values as defaults; the overrides shown set the same thresholds in the committed code (the
earlier defaults' rows were reproduced bit for bit by it: tagging n3, 8 seeds)."""


#: iterations at which ``refine_trace`` reads the kept policy's estimate
TRACE_AT = (100, 200, 300, 350, 400)


def refine_trace(row: str) -> list[str]:
    """Per seed of ``row``'s sweep with and without the refine phase: the kept policy's in-loop
    estimate (``in_loop_best_per_iteration``, the pool's mean) after the iterations of ``TRACE_AT``,
    and the honest value; empty when either sweep is missing."""
    paths = [RESULTS / f"cognet-{row}-before-refine", RESULTS / f"cognet-{row}-before-rule"]
    if not all((p / "runs.json").is_file() for p in paths):
        return []
    steps = " | ".join(f"after {i}" for i in TRACE_AT)
    lines = [
        f"| sweep | seed | kept policy's estimate: {steps} | honest value |",
        "|---|---|" + "---|" * len(TRACE_AT) + "---|",
    ]
    for path in paths:
        for r in json.loads((path / "runs.json").read_text())["rows"]:
            best = in_loop_best_series(r)
            cells = " | ".join(f"{best[min(i, len(best)) - 1]:.2f}" for i in TRACE_AT)
            honest = r["final_value"]["mean"]
            lines.append(f"| {path.name} | {r['seed']} | {cells} | {honest:.3f} |")
    return lines


#: beacon sweeps ``reaching_hand`` counts seeds of: the search changes tried against its plateau
REACH_SWEEPS = (
    "cognet-beacon-before-refine",
    "cognet-beacon-before-rule",
    "beacon-starts2",
    "beacon-starts3",
    "beacon-restart0.1",
    "beacon-restart0.2",
    "beacon-vote-alternate",
    "beacon-portfolio",
    "beacon-tiedvote10",
    "cognet-beacon",
)


def reaching_hand(row: str, sweeps) -> list[str]:
    """Per sweep of ``sweeps``: how many seeds' honest values reach ``row``'s hand-written
    controller, and the mean, from the saved results; empty without the hand-written value."""
    hand_path = RESULTS / f"hand-{row}.json"
    if not hand_path.is_file():
        return []
    hand = json.loads(hand_path.read_text())["honest"][0]
    lines = [
        f"| sweep | seeds at or above the hand-written controller ({hand:.3f}) | mean |",
        "|---|---|---|",
    ]
    for name in sweeps:
        values = _values(RESULTS / name / "runs.json")
        if values:
            hits = sum(v >= hand for v in values)
            lines.append(f"| {name} | {hits} of {len(values)} | {sum(values) / len(values):.3f} |")
    return lines


TRACE_NOTES = """\
Where the refine phase costs: on beacon the kept policy of most seeds sat near 24.9 from about
iteration 100 -- the agents step toward the beacon but never stop, so they leave its radius
again -- and, without the refine phase, left it only in the last hundred iterations; refining
from iteration 300 around that policy keeps it there. Why the plateau: a node network's default
vote starts at the scale of `vote_mean` (5) while a unit's vote grows with its pre-activation
(spread about 10), so the default loses to every unit a tenth of an observation unit past its
threshold and a stop region needs all four units' thresholds moved at once. The table below
counts, per sweep, the seeds that reached the hand-written controller: independent searches
before the refine phase ("beacon-starts2", "-starts3"), shorter exploring searches
("beacon-restart0.1", "-restart0.2") and the default vote at the units' scale with shorter
searches ("cognet-beacon", the defaults under the horizon rule). On tagging n3 (horizon 3, 3
nodes) those values ended lower ("tagging-thesis-n3-vote10-16seeds" against
"tagging-thesis-n3-defaults-16seeds" above), and each of their two changes alone lowered it
there too ("tagging-thesis-n3-vote10-restart0.02", "tagging-thesis-n3-restart0.1"); alternating
the two scales between exploring searches ("-vote-alternate"), a portfolio of both kinds
("-portfolio") and the large vote for tied candidates only ("-tiedvote10") kept tagging n3 and
helped beacon less: the rule gives them to problems whose horizon exceeds the nodes. The sweep
of "beacon-starts2" shared the machine with the test suite; the 16-seed
tagging sweeps, "heatmap-2d-n4-vote10", "cognet-beacon-clean" and "beacon-vote-alternate" with
another sweep: their wall times are not comparable."""


#: thresholds ``t`` of the reactive tagging controller (regions ``(-inf, -t]``, ``(-t, t]``,
#: ``(t, inf)``) that ``run_reactive`` evaluates on the paper setting
REACTIVE_THRESHOLDS = (0.9, 0.99, 0.999, 1.0, 1.001, 1.01, 1.1)


def run_reactive() -> None:
    """The reactive controller of SPEC section 8 on the paper setting with its two division
    points moved to ``-t`` and ``t``: 20,000 rollouts of one key per ``t`` (common random
    numbers), written to results/suite/reactive-paper.json."""
    import jax
    import jax.numpy as jnp

    from cognet_jax.baselines import hand_returns
    from cognet_jax.controllers.regions import reactive_tagging_policy
    from cognet_jax.envs.tagging import make_tagging

    env, params = make_tagging("cogdice-paper")
    controller, policy = reactive_tagging_policy()
    values = []
    for t in REACTIVE_THRESHOLDS:
        points = jnp.tile(jnp.array([-t, t], jnp.float32), (2, 3, 1))
        r = hand_returns(
            env, params, controller, policy.replace(points=points), jax.random.key(5), 20_000
        )
        values.append([t, float(r.mean()), float(r.std() / len(r) ** 0.5)])
        print(f"t = {t}: {values[-1][1]:.3f}", flush=True)
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "reactive-paper.json").write_text(json.dumps({"values": values}, indent=1))


def reactive_table() -> list[str]:
    """The saved ``run_reactive`` values as one table row; empty when not run."""
    path = RESULTS / "reactive-paper.json"
    if not path.is_file():
        return []
    values = json.loads(path.read_text())["values"]
    return [
        "| division points | " + " | ".join(f"+-{t:g}" for t, _, _ in values) + " |",
        "|---|" + "---|" * len(values),
        "| value (20,000 rollouts) | "
        + " | ".join(f"{v:.2f} +- {se:.2f}" for _, v, se in values)
        + " |",
    ]


REACTIVE_NOTES = """\
What the tied (reactive) searches' plateau near 106.6 on the paper setting matches: the
reactive controller's 108.0 needs its division points within a few thousandths of -1 and 1.
Taggers and evader stop at the walls (0 and 10) and then move by whole steps, so distances of
exactly 1 recur: points a hundredth away on both sides cost about 1.5 (106.5 - 106.6, the
tied searches' plateau), a thousandth 0.15 - 0.5. A unit's threshold is `-b / w` of two
Gaussian draws, and telling 106.6 from 108.0 is a difference of 1.3% of a value whose rollouts
spread about 50, so the 108.0 of SPEC's reactive controller is a bar of exact arithmetic;
controllers with memory can pass it instead (`tagging-paper-cognet`'s seed 0, untied, 115.0)."""


#: bearings (radians) at which ``chase_map`` reads both controllers: 5-degree steps
MAP_BEARINGS = [(-180 + 5 * i) * 3.141592653589793 / 180 for i in range(73)]
#: letters of the chase's actions (``envs.base.MOVES5``): stay, x+1, x-1, y+1, y-1
MOVE_LETTERS = "SRLUD"


def chase_map() -> list[str]:
    """The first move of the saved seed-0 policy of the chase sweep (agent 0, from node 0)
    and of the tuned hand-written controller at every bearing of ``MAP_BEARINGS``, one letter
    per bearing; empty when the policy is not saved."""
    import jax
    import jax.numpy as jnp

    from cognet_jax.api import build_env
    from cognet_jax.controllers.step import controller_step
    from cognet_jax.envs.bearing_chase import hand_controller
    from cognet_jax.saved_runs import load_run

    folder = RESULTS / "cognet-bearing-chase" / "seed0"
    hand_path = RESULTS / "hand-bearing-chase.json"
    if not (folder / "policy.msgpack").is_file() or not hand_path.is_file():
        return []
    run = load_run(folder)
    env, _ = build_env(run.config)
    controller, policy = hand_controller(env, **json.loads(hand_path.read_text())["best"])
    lines = []
    for name, pol in (("COGNet-DICE, seed 0", run.policy), ("hand-written", policy)):
        letters = ""
        for theta in MAP_BEARINGS:
            obs = jnp.full((2,), theta, jnp.float32)
            if name == "hand-written":
                node = controller.next_node(None, pol, jnp.zeros(2, jnp.int32), obs)
                action = int(pol.actions[0, node[0]])
            else:
                action = int(
                    controller_step(pol, jnp.zeros(2, jnp.int32), obs, jax.random.key(0))[0][0]
                )
            letters += MOVE_LETTERS[action]
        lines.append(f"    {name:20s} {letters}")
    return ["    bearing (degrees)    -180 ... 0 ... 180, every 5", *lines]


CHASE_NOTES = """\
What the chase's controller misses: the moves at each bearing (R, L: x+1, x-1; U, D: y+1,
y-1). The hand-written controller steps L on both ends of the bearing's range, where it wraps
around: a fifth interval, the same move on both ends of the observation's range, which needs
units of the node network that agree on both sides. Seed 0 of the sweep before
`distinct_actions` orders four intervals (L, D, R, U) and misses it; under the defaults seed 0
has it. Read from the saved policies of the 8 seeds of the defaults: those that end near the
hand-written controller (14.8 - 14.9) have the fifth interval, the others (13.2 - 13.4) do
not."""


#: the sweeps with half of the iterations refining, against the defaults' sweep of each
REFINE_HALF = (
    ("plume", "plume-refine-half-fixed", "cognet-plume"),
    ("beacon without noise", "beacon-clean-refine-half", "cognet-beacon-clean"),
    ("the README simulator", "readme-seek-refine-half", "cognet-readme-seek"),
    ("tagging n3", "tagging-thesis-n3-refine-half", "tagging-thesis-n3-defaults"),
)


def refine_half_note() -> str:
    """The refine-half sweeps against the defaults, from their saved values."""
    parts = []
    for what, half, default in REFINE_HALF:
        a, b = _values(RESULTS / half / "runs.json"), _values(RESULTS / default / "runs.json")
        if a and b:
            parts.append(
                f"{what} {sum(a) / len(a):.3f} (worst {min(a):.3f}) against "
                f"{sum(b) / len(b):.3f} ({min(b):.3f})"
            )
    if not parts:
        return ""
    return (
        "Half of the iterations refining instead of a quarter (`algorithm.refine=0.5`, rows "
        '"-refine-half", 8 seeds each, against the defaults): ' + "; ".join(parts) + ". Not "
        "adopted: tagging's thesis setting loses a seed below the reactive controller, and the "
        "others move within their seeds' spread."
    )


def write_table() -> None:
    moves = chase_map()  # before ``table`` imports the plug-ins: the policy's numerics had none
    body = [
        "## Continuous-observation suite: hand-written controllers against the defaults",
        "",
        *table(),
        "",
        NOTES,
        "",
        "### Ablations, tagging and heatmap under the new defaults, budgets",
        "",
        *extra_table(),
        "",
        EXTRA_NOTES,
        "",
        refine_half_note(),
        "",
        "### Time to the hand-written controller, one run at a time",
        "",
        *single_runs_table(),
        "",
        SINGLE_NOTES,
        "",
        "### The refine phase seed by seed: beacon, before the horizon rule",
        "",
        *refine_trace("beacon"),
        "",
        TRACE_NOTES,
        "",
        *reaching_hand("beacon", REACH_SWEEPS),
        "",
        "### The paper setting's reactive controller, its division points moved",
        "",
        *reactive_table(),
        "",
        REACTIVE_NOTES,
        "",
        "### The chase's first move by bearing",
        "",
        *moves,
        "",
        CHASE_NOTES,
        "",
        f"Generated by `python experiments/suite.py`; machine: {machine()}.",
    ]
    replace_block("suite", "\n".join(body))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    kinds = ["hand", "cognet", "cogdice", "encoded", "extra", "reactive", "rescore"]
    p.add_argument("what", nargs="?", choices=kinds, default=None)
    p.add_argument(
        "rows", nargs="*", help=f"default: all of {', '.join(ROWS)} (with extra: of EXTRA)"
    )
    p.add_argument("--table-only", action="store_true")
    p.add_argument(
        "--from",
        dest="source",
        type=Path,
        default=None,
        help="rescore: a folder of sweeps, one per experiment, to take the run folders from",
    )
    args = p.parse_args(argv)
    known = EXTRA if args.what == "extra" else ROWS
    unknown = [r for r in args.rows if r not in known]
    if unknown:
        p.error(f"unknown row(s) {', '.join(unknown)}; known: {', '.join(known)}")
    rows = args.rows or list(ROWS)
    if not args.table_only:
        if args.what in (None, "hand"):
            run_hand(rows)
        if args.what in (None, "cognet"):
            run_cognet(rows)
        if args.what in (None, "cogdice"):
            run_cogdice(rows)
        if args.what in (None, "encoded"):
            run_encoded(rows)
        if args.what in (None, "extra"):
            run_extra(args.rows if args.what == "extra" and args.rows else list(EXTRA))
        if args.what in (None, "reactive"):
            run_reactive()
        if args.what in (None, "rescore"):
            run_rescore(rows, args.source)
    write_table()
    return 0


if __name__ == "__main__":
    sys.exit(main())
