"""G-DICE with its defaults in a minute (issue 55): one ``cognet-jax train gdice-dpomdp`` per
(problem, horizon) on the models experiments/models.py writes, the wall time split into
compile and search loop, the exact value of the kept policy against the published optimum,
and the table in experiments/README.md (block ``gdice-minute``).

    python experiments/gdice_minute.py --horizons 4 5     # runs, then the table
    python experiments/gdice_minute.py --problems marsRovers --horizons 4
    python experiments/gdice_minute.py --table-only

Each run is ``cognet-jax train gdice-dpomdp --seed 0 --set problem.path=MODEL --set
problem.horizon=H --set problem.discount=1`` in a fresh process (its compile included, with
the compilation cache off: what a first run costs), alone on the machine; results.json is kept
as ``experiments/results/gdice-minute/<problem>-h<H>.json``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

from _readme import finish_of, machine, replace_block

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results" / "gdice-minute"
#: problem -> (models.py arguments, published optima by horizon: MADP / masplan benchmark pages)
PROBLEMS = {
    "boxPushing": (["box-pushing"], {2: 17.6, 3: 66.081, 4: 98.593, 5: 107.72}),
    "fireFighting233": (
        ["fire-fighting", "--houses", "3", "--levels", "3", "--madp-rounding"],
        {2: -4.383496, 3: -5.736969, 4: -6.578834, 5: -7.069874},
    ),
    "marsRovers": (["mars"], {2: 5.80, 3: 9.38, 4: 10.18, 5: 13.26}),
    "meetingGrid3x3corners": (["meeting-grid"], {2: 0.0, 3: 0.133, 4: 0.432, 5: 0.894}),
}
#: the goals: seconds per run at these horizons
GOAL_SECONDS = {4: 60.0, 5: 180.0}


def run(horizons: list[int], problems: list[str]) -> None:
    RESULTS.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        for problem in problems:
            args = PROBLEMS[problem][0]
            model = Path(tmp) / f"{problem}.dpomdp"
            subprocess.run([sys.executable, str(HERE / "models.py"), *args, "--out", str(model)])
            for h in horizons:
                out = Path(tmp) / f"{problem}-h{h}"
                cmd = [
                    "cognet-jax", "--no-compile-cache", "train", "gdice-dpomdp", "--seed", "0",
                    "--set", f"problem.path={model}", "--set", f"problem.horizon={h}",
                    "--set", "problem.discount=1", "--set", "run.plots=false",
                    "--out", str(out), "--no-progress",
                ]  # fmt: skip
                print(" ".join(cmd), flush=True)
                subprocess.run(cmd, check=True)
                record = json.loads((out / "results.json").read_text())
                (RESULTS / f"{problem}-h{h}.json").write_text(json.dumps(record, indent=1))


def table() -> list[str]:
    rows = [
        "| problem | h | exact value | published optimum | % of optimum | wall s | compile s "
        "| search loop s | of which polish s | evaluator (exact_top) | goal |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for problem, (_, optima) in PROBLEMS.items():
        for path in sorted(RESULTS.glob(f"{problem}-h*.json")):
            r = json.loads(path.read_text())
            h = r["config"]["problem"]["horizon"]
            value, optimum = r["final_value"].get("exact"), optima.get(h)
            share = ""  # 100 less the shortfall in % of the optimum's magnitude
            if value is not None and optimum:
                share = f"{100 - 100 * (optimum - value) / abs(optimum):.1f}"
            polish = finish_of(r).get("seconds", 0.0)
            goal = GOAL_SECONDS.get(h)
            verdict = "" if goal is None else ("met" if r["wall_s"] <= goal else f"> {goal:.0f} s")
            if goal is not None and share and float(share) < 99.0:
                verdict += ", value < 99%" if verdict != "met" else " (time); value < 99%"
            shown = "" if value is None else f"{value:.4f}"
            rows.append(
                f"| {problem} | {h} | {shown} | {optimum} | {share} | {r['wall_s']:.1f} | "
                f"{r['compile_s']:.1f} | {r['loop_s']:.1f} | {polish:.1f} | "
                f"{_evaluator(r['resolved'])} | {verdict} |"
            )
    return rows


def _evaluator(resolved: dict) -> str:
    evaluator = resolved.get("evaluator")
    if evaluator == "hybrid":
        return f"hybrid ({resolved.get('exact_top')})"
    return str(evaluator)


#: 8-seed sweeps behind the choice of ``exact_top = "auto"`` (results/gdice-minute/sweeps/)
SWEEPS = [
    ("fireFighting233", 4, "ff233-h4-top25", "exact_top 25 (the rule's at h 4)"),
    ("fireFighting233", 4, "ff233-h4-top50", "exact_top 50 (before the rule)"),
    ("meetingGrid3x3corners", 4, "grid-h4-top15", "hybrid, exact_top 15 (the defaults)"),
    ("marsRovers", 5, "mars-h5-polish", "hybrid, exact_top 6, polished (the defaults)"),
    ("marsRovers", 5, "mars-h5-hybrid6", "hybrid, exact_top 6, no polish (before 1e10)"),
    ("marsRovers", 5, "mars-h5-rollouts", "rollouts (before HYBRID_MIN_TOP)"),
    ("marsRovers", 5, "mars-h5-i300-rollouts", "rollouts, 300 iterations"),
    ("marsRovers", 5, "mars-h5-repeats2-top5", "hybrid, exact_top 5, repeats 2"),
]


def sweep_table() -> list[str]:
    rows = [
        "| problem | h | setting | seeds | exact value: mean (min, max) | worst seed, % of the "
        "optimum | sweep wall s |",
        "|---|---|---|---|---|---|---|",
    ]
    for problem, h, folder, what in SWEEPS:
        path = RESULTS / "sweeps" / folder / "runs.json"
        if not path.is_file():
            continue
        sweep = json.loads(path.read_text())
        values = [r["final_value"]["exact"] for r in sweep["rows"]]
        optimum = PROBLEMS[problem][1].get(h)
        worst = min(values)
        share = f"{100 - 100 * (optimum - worst) / abs(optimum):.2f}" if optimum else ""
        rows.append(
            f"| {problem} | {h} | {what} | {len(values)} | {sum(values) / len(values):.4f} "
            f"({worst:.4f}, {max(values):.4f}) | {share} | {sweep['wall_s']:.0f} |"
        )
    return rows


NOTES = """\
One run per cell (seed 0), each in a fresh process with the compilation cache off, so the
compile is what a first run pays; wall = compile + search loop (the polish included) + the
honest evaluation; "goal" is issue 55's 60 s at h 4 and 180 s at h 5, and the value's goal is
99% of the optimum. The models are experiments/models.py's, written from the published rules:
box pushing and fire fighting reproduce the published optima (experiments/README.md, G-DICE
defaults on problems outside ../shared); Mars rovers and the 3 x 3 meeting grid follow MADP's
files, quirks included (their transitions, observations, rewards and start were compared
equal with a copy of each file, which this repository does not hold). What the rows stand on:
rollouts and exact values read the observation rows as lists where they are sparse (box
pushing, Mars rovers and the grid observe deterministically: one entry of 25 to 81 per row),
and the exact value of a layered controller skips the last layer's empty backup
(cognet_jax/envs/tabular.py, exact_jax.py). Rows of the earlier Mars and grid models (a start,
moves and observations of this project's reading): results/gdice-minute/before-madp-rules/."""


SWEEP_NOTES = """\
`cognet-jax sweep gdice-dpomdp --seeds 8 --set problem.path=MODEL --set problem.horizon=4 --set
problem.discount=1` with `--set algorithm.exact_top=N`, all 8 seeds in one program (so the wall
is not a single run's). With 50 samples per search valued exactly, fire fighting's exact part
took 235 of 264 ms per iteration (150 exact values, gather-bound: about 1.6 ms each); the
rule `exact_top = "auto"` (cognet_jax/algorithms/gdice_search.py, `HYBRID_EXACT_LIMIT`) keeps
that part within 4e7 multiply-adds per iteration. The rows before the rule
(results/gdice-minute/before-exact-top-auto/: fire fighting h 4 75.8 s) are the single runs of
the table's first version; the grid's sweep at exact_top 19 ran on the earlier grid model
(before-madp-rules/grid-h4-top19: 8 of 8 seeds at that model's best, 0.5495).

Mars rovers at h 5 (exact optimum 13.2665; published 13.26): rollouts alone, what
`evaluator = "auto"` chose before `HYBRID_MIN_TOP` (cognet_jax/algorithms/gdice_search.py),
ended 1 seed of 8 at the optimum; the hybrid with the 6 exact values per iteration that fit
`HYBRID_EXACT_LIMIT` ends 4 of 8 there, the others in local optima (11.56 - 13.10) that two
repeats or 300 iterations do not leave. The polish (single-entry moves valued exactly, and
best responses) takes every seed but one from there to the optimum in 5 - 8 s: it was off on
Mars rovers while `POLISH_SWEEP_LIMIT` was 1e9 (one sweep costs 6.2e9 multiply-adds there);
at 1e10 (the defaults since) it runs on every model of the table, the meeting grid at h 4
included (2.0e9; 9.6 s of polish, within its minute). The sweep "polished" ran after the fix
that runs a G-DICE sweep's polish one run after another (`finish_per_run`: side by side,
every step computed the sweep and the best responses both, 564 s for one step of two runs):
{polished}."""


def polished_mars() -> str:
    """The prose of the polished Mars rovers sweep, from its saved rows."""
    path = RESULTS / "sweeps" / "mars-h5-polish" / "runs.json"
    if not path.is_file():
        return "not run"
    sweep = json.loads(path.read_text())
    optimum = 13.2665  # exact, to the 4 decimals the rows are compared at
    values = {r["seed"]: r["final_value"]["exact"] for r in sweep["rows"]}
    at = [s for s, v in values.items() if round(v, 4) >= optimum]
    others = ", ".join(
        f"seed {s} at {v:.4f} ({100 * v / optimum:.1f}% of the exact optimum)"
        for s, v in sorted(values.items())
        if s not in at
    )
    text = f"{len(at)} of {len(values)} seeds at the optimum"
    text += f", {others}" if others else ""
    return text + f", wall {sweep['wall_s']:.0f} s for the {len(values)} (beside another sweep)"


def write_table() -> None:
    body = [
        "## G-DICE defaults in a minute: wall time per run at h 4 and 5",
        "",
        *table(),
        "",
        NOTES,
        "",
        "### exact_top: 8 seeds",
        "",
        *sweep_table(),
        "",
        SWEEP_NOTES.format(polished=polished_mars()),
        "",
        f"Generated by `python experiments/gdice_minute.py`; machine: {machine()}.",
    ]
    replace_block("gdice-minute", "\n".join(body))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--horizons", type=int, nargs="+", default=[4, 5])
    p.add_argument("--problems", nargs="+", choices=list(PROBLEMS), default=list(PROBLEMS))
    p.add_argument("--table-only", action="store_true")
    args = p.parse_args(argv)
    if not args.table_only:
        run(args.horizons, args.problems)
    write_table()
    return 0


if __name__ == "__main__":
    sys.exit(main())
