"""The 1D tagging experiments (COGNet-DICE, COG-DICE, G-DICE on discretised observations) and
their generated table in experiments/README.md.

    python experiments/tagging.py                        # every built-in tagging experiment, seed 0
    python experiments/tagging.py tagging-thesis-n3 tagging-thesis-cogdice-n3 --seeds 0 1 2
    python experiments/tagging.py --group paper          # only the COG-DICE paper setting
    python experiments/tagging.py --table-only           # rebuild the table from saved results

Every run goes through ``cognet_jax.runner.run_training`` (exactly what ``cognet-jax train NAME
--seed N`` does) and writes ``experiments/results/tagging/<name>-seed<N>/``. The table reads the
results files only: honest value (fresh evaluation of the best policy, >= 10,000 rollouts, a key
the search never saw), the search budget in simulated agent-steps, wall time, and the published
numbers of SPEC section 8 beside them.
"""

from __future__ import annotations

import argparse
import glob
import json
import sys
from pathlib import Path

from _readme import machine, replace_block

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results" / "tagging"

THESIS_REFERENCE = "20.76"
PAPER_REFERENCE = "108.0"

#: Deviations from SPEC section 5 for the thesis algorithm (see the notes of the table).
COGNET_OPTIONS = [
    "algorithm.train_on=top",
    "network.learning_rate=0.03",
    "algorithm.best_rollouts=1000",
]
#: run name -> (built-in experiment, overrides); a run not listed is the experiment itself
VARIANTS = {
    "tagging-thesis-spec-n3+options": ("tagging-thesis-spec-n3", COGNET_OPTIONS),
    "tagging-thesis-spec-n6+options": ("tagging-thesis-spec-n6", COGNET_OPTIONS),
    # separate training has no candidates: only the learning rate and the step-8 evaluation
    "tagging-separate-n3+options": ("tagging-separate-n3", COGNET_OPTIONS[1:]),
    "tagging-separate-n6+options": ("tagging-separate-n6", COGNET_OPTIONS[1:]),
    # ablation of the default: half the candidates and elites of tagging-paper-cognet
    "tagging-paper-cognet-c400": (
        "tagging-paper-cognet",
        ["algorithm.candidates=400", "algorithm.elites=20"],
    ),
}

#: run name -> (group, published value, what the published value is)
EXPERIMENTS = {
    "tagging-thesis-n3": ("thesis", "1.594", "thesis COGNet-DICE"),
    "tagging-thesis-n6": ("thesis", "11.103", "thesis COGNet-DICE"),
    "tagging-thesis-spec-n3": ("thesis", "1.594", "thesis COGNet-DICE"),
    "tagging-thesis-spec-n6": ("thesis", "11.103", "thesis COGNet-DICE"),
    "tagging-thesis-spec-n3+options": ("thesis", "1.594", "thesis COGNet-DICE"),
    "tagging-thesis-spec-n6+options": ("thesis", "11.103", "thesis COGNet-DICE"),
    "tagging-separate-n3": ("thesis", "> 2", "thesis, separate training"),
    "tagging-separate-n6": ("thesis", "> 8", "thesis, separate training"),
    "tagging-separate-n3+options": ("thesis", "> 2", "thesis, separate training"),
    "tagging-separate-n6+options": ("thesis", "> 8", "thesis, separate training"),
    "tagging-thesis-cogdice-n3": ("thesis", "1.540", "thesis COG-DICE"),
    "tagging-thesis-cogdice-n6": ("thesis", "1.794", "thesis COG-DICE"),
    "tagging-paper-cogdice": ("paper", "101.8", "COG-DICE paper"),
    "tagging-paper-cogdice-full": ("paper", "101.8", "COG-DICE paper"),
    "tagging-paper-cognet": ("paper", "", ""),
    "tagging-paper-cognet-full": ("paper", "", ""),
    "tagging-paper-cognet-c400": ("paper", "", ""),
    "tagging-paper-cognet-spec": ("paper", "", ""),
    "tagging-paper-gdice-d0.5": ("paper", "89.9", "COG-DICE paper, G-DICE"),
    "tagging-paper-gdice-d1": ("paper", "65.09", "COG-DICE paper, G-DICE"),
    "tagging-paper-gdice-d2": ("paper", "54.09", "COG-DICE paper, G-DICE"),
    "tagging-paper-gdice-d4": ("paper", "13.49", "COG-DICE paper, G-DICE"),
}
GROUP_TITLES = {
    "thesis": (
        "Thesis setting (h 3, gamma 1; thesis Table 5.1)",
        THESIS_REFERENCE,
    ),
    "paper": (
        "COG-DICE paper setting (h 150, gamma 0.9, respawn)",
        PAPER_REFERENCE,
    ),
}


def out_dir(name: str, seed: int) -> Path:
    return RESULTS / f"{name}-seed{seed}"


def run(names: list[str], seeds: list[int]) -> None:
    from cognet_jax.config import load_config
    from cognet_jax.runner import run_training

    for name in names:
        experiment, overrides = VARIANTS.get(name, (name, []))
        sets = [f"experiment.name={json.dumps(name)}", *overrides, "run.progress=false"]
        for seed in seeds:
            run_training(load_config(experiment, sets), seed, out_dir(name, seed))


def _settings(r: dict) -> str:
    alg, algorithm = r["config"]["algorithm"], r["algorithm"]
    env = r["config"]["env"]
    if algorithm == "cognet-dice":
        text = (
            f"{alg['iterations']} it x {alg['candidates']} cand. x {alg['eval_rollouts']}, "
            f"{alg['elites']} elites, alpha {alg['alpha']:g}, floors {alg['action_floor']:g}, "
            f"best re-eval 2 x {alg['best_rollouts']}, hidden {r['config']['network']['hidden']}"
        )
        return text
    if algorithm == "cognet-dice-thesis":
        text = (
            f"{alg['iterations']} it x ({alg['rollouts']} rollouts + {alg['top']} cand. x "
            f"{alg['eval_rollouts']})"
        )
        if alg["separate"]:
            text = f"{alg['iterations']} it x {alg['rollouts']} rollouts, separate"
    else:
        text = f"{alg['iterations']} it x {alg['samples']} samples x {alg['eval_rollouts']}"
        text += f", N_b {alg['elites']}"
        if algorithm == "cogdice":
            text += f", N_t {alg['regions']}"
        if env.get("obs_division"):
            text += f", d {env['obs_division']:g}"
    text += f", alpha {alg['alpha']:g}"
    if alg.get("entropy_injection"):
        text += ", EI"
    if alg.get("best_rollouts"):
        text += f", best re-eval {alg['best_rollouts']}"
    if alg.get("train_on") == "top":
        text += f", nets on top {alg['top']}, lr {r['config']['network']['learning_rate']:g}"
    return text


def table_rows(group: str) -> list[str]:
    title, reference = GROUP_TITLES[group]
    rows = [
        f"### {title}",
        "",
        "| experiment | algorithm | nodes | budget | seed | honest value (mean +- s.e.) | "
        "in-loop best | simulated agent-steps | wall s (compile s) | published | "
        "reference controller |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, (g, published, source) in EXPERIMENTS.items():
        if g != group:
            continue
        for path in sorted(RESULTS.glob(f"{glob.escape(name)}-seed*/results.json")):
            r = json.loads(path.read_text())
            if r["experiment"] != name:
                continue
            f = r["final_value"]
            steps = r.get("simulated_agent_steps")
            steps_text = f"{steps:.3g}" if steps else "n/a"
            paper = f"{published} ({source})" if published else "not published"
            rows.append(
                f"| {name} | {r['algorithm']} | {r['config']['algorithm']['nodes']} | "
                f"{_settings(r)} | {r['seed']} | {f['mean']:.3f} +- {f['stderr']:.3f} | "
                f"{r['in_loop_best']:.3f} | {steps_text} | {r['wall_s']:.1f} "
                f"({r['compile_s']:.1f}) | {paper} | {reference} |"
            )
    return rows


def seed_summary_rows(group: str) -> list[str]:
    """Per experiment with at least two seeds: mean, min and max honest value over the seeds
    and the mean wall time of a run (from the same results files as the table above)."""
    rows = [
        "| experiment | algorithm | seeds | honest mean | min | max | wall s per run (mean) |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, (g, *_) in EXPERIMENTS.items():
        if g != group:
            continue
        found = [
            json.loads(p.read_text())
            for p in sorted(RESULTS.glob(f"{glob.escape(name)}-seed*/results.json"))
        ]
        found = [r for r in found if r["experiment"] == name]
        if len(found) < 2:
            continue
        values = [r["final_value"]["mean"] for r in found]
        walls = [r["wall_s"] for r in found]
        seeds = ", ".join(str(r["seed"]) for r in found)
        rows.append(
            f"| {name} | {found[0]['algorithm']} | {len(found)} ({seeds}) | "
            f"{sum(values) / len(values):.3f} | {min(values):.3f} | {max(values):.3f} | "
            f"{sum(walls) / len(walls):.1f} |"
        )
    return rows if len(rows) > 2 else []


NOTES = """\
Columns. Honest value: a fresh evaluation of the run's best policy (10,000 rollouts, a key
the search never saw), mean +- standard error. In-loop best: the search's own maximum of noisy
Monte Carlo means (the thesis reports this kind of number); it is biased upwards and shown
only to make that bias visible. Simulated agent-steps: the search's budget, iterations x
rollouts per iteration x horizon x agents (the final honest evaluation not included).
Reference controller: the reactive 3-node controller of SPEC section 8 (start "move left";
next node by the region of the observation: (-inf, -1] left, (-1, 1] tag, (1, inf) right).

The default COGNet-DICE (`cognet-dice`, rows tagging-thesis-n3 / -n6 / tagging-paper-cognet)
samples whole joint controllers from a distribution over the node networks' weights and refits
it to the elites (cognet_jax/algorithms/cognet_weights.py); its in-loop best is the largest
1000-rollout fresh value of an iteration's winner or mode, so the gap to the honest value is
the winner's curse of 1200 (thesis setting) or 2000 (paper setting) such means. On average it
beats the reactive controller on the thesis setting because it finds the better joint
behaviour: the two agents start by moving in opposite directions (the start node of every
tagging-thesis-n3 policy here: one agent "left", the other "right"; the issue measured 23.2
for that reactive variant). The 8-seed sweeps of
these experiments are in the section "COGNet-DICE (default): 8-seed sweeps and ablations".

COGNet-DICE as SPEC section 5 specifies it (tagging-thesis-spec-n3 / -n6, algorithm
cognet-dice-thesis) stays far from the
reactive controller. Its node networks learn from the pairs of the K_keep = 10 kept rollouts
only (at most 60 pairs), and in most iterations nothing is kept: the elite threshold V_w, set
on one iteration's candidate values, is rarely beaten by the next iteration's until an entropy
injection resets it (kept_per_iteration in results.json). The "+options" rows change two
SPEC choices: the networks train on the pairs of all K_top = 100 pre-selected rollouts
(`algorithm.train_on = "top"`, learning rate 0.03), and step 8 evaluates the updated policy
with 1000 rollouts instead of K_eval = 100 (`algorithm.best_rollouts = 1000`), so the anytime
best is not a lucky 100-rollout mean. The rest of the gap to 20.76 is a local optimum of the
action distributions. In the 3-node "+options" policy the start node's action stays mixed
between left and right (about 0.43 / 0.55), and that same node is where the networks send
z < -1, so the controller has no pure "left" node. Leaving the t = 0 visits out of the action
counts (a one-off experiment, not an option) gave 14.17 and the same mixed node, so the start
visit alone does not explain it. The SPEC choices we would change are the training set of
step 7 (top instead of kept) and the size of the step-8 evaluation. COG-DICE on the same
budget does better than SPEC COGNet-DICE here (the thesis reports the opposite, with in-loop
values).

Separate training fixes node q to action q mod 3, so node 0, the start node, plays "tag". At
t = 0 a random position tags successfully with probability 0.19, so both taggers together
expect -13.4 from that first step against -2 for moving, a loss of about 11 before any
observation. This caps what the separate runs can reach below the
reactive controller's 20.76. The 6-node separate run's best policy (-25.3 honest against -2.3
in-loop) is a lucky 100-rollout mean; the "+options" rows choose the best on 1000-rollout
evaluations.

COG-DICE paper setting. The budget has to fit 10 minutes on 2 cores; the paper used 500
iterations x 2000 samples x 1000 rollouts. Runs of 300 iterations with seed 0, all with
3 regions and alpha 0.1, honest values (`cognet-jax train tagging-paper-cogdice --set ...`):

| samples x rollouts, elites | entropy injection | winner re-evaluated | honest |
|---|---|---|---|
| 1000 x 50, 50 | no | no | 76.6 |
| 1000 x 50, 50 | yes | no | 90.6 |
| 1000 x 50, 50 | yes | 1000 rollouts | 78.5 |
| 2000 x 25, 50 | yes | 1000 rollouts | 99.1 |
| 4000 x 25, 50 | yes | 1000 rollouts | 102.1 (the built-in run) |

Without entropy injection the elite threshold froze after about 100 iterations: no sample
beat a lucky iteration's V_w again, so nothing was kept. Converged policies that fell short had
the same flaw. One agent's controller never moved left, because finding a "left" node means
changing its action, the transitions into it and its division points at the same time. More
samples per iteration find such joint changes more often, so 4000 samples of 25 rollouts
each did better than fewer samples evaluated more precisely. COGNet-DICE
(tagging-paper-cognet-spec, SPEC settings) got far less from the same budget of simulated
agent-steps. Its networks have to learn the region boundaries from the pairs of 10 kept
rollouts per iteration, while COG-DICE samples the boundaries directly. G-DICE on the
discretised problem uses the same search settings as COG-DICE. Against the published G-DICE
values it is lower at d = 0.5, where each agent has 41 observations and so 41 transition rows
per node to learn. It is also lower at d = 1 and d = 4, and about equal at d = 2. At d = 4 the
observation cannot tell "close enough to tag" from "4 away", so no controller tags
reliably."""


#: the paper-budget runs (500 x 2000 x 1000) -> the built-in run of the same algorithm
PAPER_BUDGET_RUNS = {
    "tagging-paper-cogdice-full": ("COG-DICE", "tagging-paper-cogdice"),
    "tagging-paper-cognet-full": ("COGNet-DICE", "tagging-paper-cognet"),
}


def paper_budget_paragraph() -> list[str]:
    """The COG-DICE paper's own budget (tagging-paper-cogdice-full, tagging-paper-cognet-full)
    against the built-in smaller runs, from their saved results (nothing typed by hand)."""
    lines = []
    for name, (label, small_name) in PAPER_BUDGET_RUNS.items():
        full, small = out_dir(name, 0), out_dir(small_name, 0)
        if not (full / "results.json").is_file() or not (small / "results.json").is_file():
            continue
        f = json.loads((full / "results.json").read_text())
        s = json.loads((small / "results.json").read_text())
        fv, sv = f["final_value"], s["final_value"]
        rate = f["simulated_agent_steps"] / (f["wall_s"] - f["compile_s"])
        ratio = f["simulated_agent_steps"] / s["simulated_agent_steps"]
        fit = "within" if f["wall_s"] <= 3600 else "over"
        lines.append(
            f"{label} at the COG-DICE paper's own budget, `{name}` (seed 0): "
            f"{f['simulated_agent_steps']:.1e} simulated agent-steps in {f['wall_s'] / 60:.1f} "
            f"min wall on this 2-core CPU ({fit} the hour; {f['compile_s']:.1f} s of it compile, "
            f"{rate / 1e6:.0f} M agent-steps/s at h 150 with respawn; the paper's authors report "
            f"20-40 hours for COG-DICE), honest value {fv['mean']:.3f} +- {fv['stderr']:.3f} "
            f"against the published COG-DICE 101.8 and the reactive controller's "
            f"{PAPER_REFERENCE}. The built-in `{small_name}` gets {sv['mean']:.3f} +- "
            f"{sv['stderr']:.3f} from {ratio:.0f}x fewer agent-steps in {s['wall_s']:.0f} s."
        )
        lines.append("")
    return lines


def write_table(groups: list[str]) -> None:
    body = ["## 1D tagging", ""]
    for group in groups:
        body += [*table_rows(group), ""]
        summary = seed_summary_rows(group)
        if summary:
            body += ["Over seeds (same results files):", "", *summary, ""]
    body += [*paper_budget_paragraph(), NOTES, ""]
    body += [f"Generated by `python experiments/tagging.py`; machine: {machine()}."]
    replace_block("tagging", "\n".join(body))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("experiments", nargs="*", help=f"default: all of {', '.join(EXPERIMENTS)}")
    p.add_argument("--group", choices=sorted(GROUP_TITLES), help="only this setting's runs")
    p.add_argument("--seeds", type=int, nargs="+", default=[0])
    p.add_argument("--table-only", action="store_true", help="only rebuild the table")
    args = p.parse_args(argv)
    unknown = [n for n in args.experiments if n not in EXPERIMENTS]
    if unknown:
        p.error(f"unknown experiment(s) {', '.join(unknown)}; known: {', '.join(EXPERIMENTS)}")
    names = args.experiments or [n for n, (g, *_) in EXPERIMENTS.items() if args.group in (None, g)]
    if not args.table_only:
        run(names, args.seeds)
    write_table(list(GROUP_TITLES))
    return 0


if __name__ == "__main__":
    sys.exit(main())
