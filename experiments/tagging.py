"""The 1D tagging experiments (COGNet-DICE, COG-DICE, G-DICE on discretised observations) and
their generated table in experiments/README.md.

    python experiments/tagging.py                        # every built-in tagging experiment, seed 0
    python experiments/tagging.py tagging-thesis-n3 tagging-thesis-cogdice-n3 --seeds 0 1 2
    python experiments/tagging.py --group paper          # only the COG-DICE paper setting
    python experiments/tagging.py --table-only           # rebuild the table from saved results

Every run goes through ``cognet_jax.driver.train`` (exactly what ``cognet-jax train NAME
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
    from cognet_jax.driver import train
    from cognet_jax.registry import load_config

    for name in names:
        experiment, overrides = VARIANTS.get(name, (name, []))
        sets = [f"experiment.name={json.dumps(name)}", *overrides, "run.progress=false"]
        for seed in seeds:
            train(load_config(experiment, sets), seed, out_dir(name, seed))


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


def _result(name: str, seed: int = 0) -> dict | None:
    path = out_dir(name, seed) / "results.json"
    return json.loads(path.read_text()) if path.is_file() else None


def _honest(name: str, seed: int = 0) -> float | None:
    r = _result(name, seed)
    return None if r is None else r["final_value"]["mean"]


def _compare(a: float, b: float, tolerance: float = 0.05) -> str:
    """'about equal to' within ``tolerance`` (relative), else 'above' / 'below'."""
    if abs(a - b) <= tolerance * abs(b):
        return "about equal to"
    return "above" if a > b else "below"


def _start_actions(name: str, seed: int = 0):
    """``(algorithm, policy, start)`` of a saved best policy, ``start`` the action
    probabilities ``[agents, actions]`` of its start node (``None`` three times if unsaved)."""
    import numpy as np

    from cognet_jax.saved_runs import load_run

    if _result(name, seed) is None:
        return None, None, None
    run = load_run(out_dir(name, seed))
    algorithm, policy = run.algorithm, run.policy
    return algorithm, policy, np.asarray(policy.action_probs)[:, 0]


def _first_step_rewards() -> tuple[float, float, float]:
    """Thesis setting, t = 0 from uniform positions: the probability that a tag succeeds, and
    the joint expected reward of both agents tagging and of both moving (closed form)."""
    from cognet_jax.envs.tagging import make_tagging

    env, params = make_tagging("thesis")
    length, r = env.length, float(params.tag_radius)
    hit = (2 * r * length - r * r) / length**2  # P(|p - e| <= r), p and e uniform on [0, L]
    tag = hit * float(params.tag_reward) + (1 - hit) * float(params.miss_reward)
    return hit, env.num_agents * tag, env.num_agents * float(params.move_reward)


def notes() -> str:
    """The notes under the tagging table; every figure is read from the saved results or
    computed from the configs and the simulator."""
    import numpy as np

    from cognet_jax.registry import load_config

    out = [
        "Columns. Honest value: a fresh evaluation of the run's best policy (10,000 rollouts, a "
        "key the search never saw), mean +- standard error. In-loop best: the search's own "
        "maximum of noisy Monte Carlo means (the thesis reports this kind of number); it is "
        "biased upwards and shown only to make that bias visible. Simulated agent-steps: the "
        "search's budget, iterations x rollouts per iteration x horizon x agents (the final "
        "honest evaluation not included). Reference controller: the reactive 3-node controller "
        'of SPEC section 8 (start "move left"; next node by the region of the observation: '
        "(-inf, -1] left, (-1, 1] tag, (1, inf) right).",
        "",
    ]
    its = [
        load_config(e).algorithm.iterations for e in ("tagging-thesis-n3", "tagging-paper-cognet")
    ]
    opposite, seeds = 0, 0
    for seed in range(64):
        if _result("tagging-thesis-n3", seed) is None:
            continue
        _, _, start = _start_actions("tagging-thesis-n3", seed)
        moves = set(start.argmax(-1).tolist())
        seeds += 1
        opposite += moves == {1, 2}  # one agent left, the other right
    out += [
        "The default COGNet-DICE (`cognet-dice`, rows tagging-thesis-n3 / -n6 / "
        "tagging-paper-cognet) samples whole joint controllers from a distribution over the "
        "node networks' weights and refits it to the elites "
        "(cognet_jax/algorithms/cognet_weights.py); its in-loop best is the largest fresh "
        "value of an iteration's winner or mode, so the gap to the honest value is the "
        f"winner's curse of {2 * its[0]} (thesis setting) or {2 * its[1]} (paper setting) such "
        "means. On average it beats the reactive controller on the thesis setting because it "
        "finds the better joint behaviour: the two agents start by moving in opposite "
        f"directions (the start node of {opposite} of the {seeds} saved tagging-thesis-n3 "
        'policies: one agent "left", the other "right"; the issue measured 23.2 for that '
        "reactive variant). The 8-seed sweeps of these experiments are in the section "
        '"COGNet-DICE (default): 8-seed sweeps and ablations".',
        "",
    ]
    spec = (
        "COGNet-DICE as SPEC section 5 specifies it (tagging-thesis-spec-n3 / -n6, algorithm "
        "cognet-dice-thesis) stays far from the reactive controller. Its node networks learn "
        "from the pairs of the K_keep = 10 kept rollouts only (at most 60 pairs), and in most "
        "iterations nothing is kept: the elite threshold V_w, set on one iteration's candidate "
        "values, is rarely beaten by the next iteration's until an entropy injection resets it "
        '(kept_per_iteration in results.json). The "+options" rows change two SPEC choices: '
        "the networks train on the pairs of all K_top = 100 pre-selected rollouts "
        '(`algorithm.train_on = "top"`, learning rate 0.03), and step 8 evaluates the updated '
        "policy with 1000 rollouts instead of K_eval = 100 (`algorithm.best_rollouts = 1000`), "
        "so the anytime best is not a lucky 100-rollout mean."
    )
    algorithm, policy, start = _start_actions("tagging-thesis-spec-n3+options")
    if start is not None:
        import jax
        import jax.numpy as jnp

        z = jnp.linspace(-10.0, -1.5, 18)
        logits = jax.vmap(
            lambda v: algorithm.controller.all_node_logits(policy.net_params, jnp.stack([v, v]))
        )(z)  # [z, agents, nodes, next]
        to = np.asarray(logits.argmax(-1))[:, :, 0]  # from the start node
        targets = [int(np.bincount(to[:, a]).argmax()) for a in range(to.shape[1])]
        cells = "; ".join(
            f"agent {a}: left {p[1]:.2f}, right {p[2]:.2f}, tag {p[0]:.2f}"
            for a, p in enumerate(start)
        )
        spec += (
            f" The rest of the gap to {THESIS_REFERENCE} is in the action distributions. The "
            f'start node of the 3-node "+options" policy (seed 0) plays {cells}; from it, '
            "the networks send z < -1 mostly to node "
            + " / ".join(map(str, targets))
            + " (agent 0 / 1)"
            + (
                ", the start node itself, so a mixed start node is also where the controller "
                'goes to move left: it has no pure "left" node.'
                if all(t == 0 for t in targets) and all(min(p[1], p[2]) > 0.2 for p in start)
                else "."
            )
        )
    cog, net = _honest("tagging-thesis-cogdice-n3"), _honest("tagging-thesis-spec-n3")
    if cog is not None and net is not None:
        spec += (
            " The SPEC choices we would change are the training set of step 7 (top instead of "
            f"kept) and the size of the step-8 evaluation. COG-DICE on the same budget is "
            f"{_compare(cog, net)} SPEC COGNet-DICE here ({cog:.3f} against {net:.3f}, 3 nodes; "
            "the thesis reports COGNet-DICE above COG-DICE, with in-loop values)."
        )
    out += [spec, ""]
    hit, tag, move = _first_step_rewards()
    sep = _result("tagging-separate-n6")
    out += [
        "Separate training fixes node q to action q mod 3, so node 0, the start node, plays "
        f'"tag". At t = 0 a random position tags successfully with probability {hit:.2f}, so '
        f"both taggers together expect {tag:.1f} from that first step against {move:.0f} for "
        f"moving, a loss of about {move - tag:.0f} before any observation. This caps what the "
        f"separate runs can reach below the reactive controller's {THESIS_REFERENCE}."
        + (
            f" The 6-node separate run's best policy ({sep['final_value']['mean']:.1f} honest "
            f"against {sep['in_loop_best']:.1f} in-loop) is a lucky 100-rollout mean; the "
            '"+options" rows choose the best on 1000-rollout evaluations.'
            if sep is not None
            else ""
        ),
        "",
    ]
    paper = _result("tagging-paper-cogdice")
    if paper is not None:
        a = paper["config"]["algorithm"]
        out += [
            "COG-DICE paper setting. The built-in run has to fit 10 minutes on 2 cores; the paper "
            "used 500 iterations x 2000 samples x 1000 rollouts (the `-full` rows run that "
            f"budget). Its settings ({a['samples']} samples x {a['eval_rollouts']} rollouts, "
            f"{a['elites']} elites, alpha {a['alpha']:g}, entropy injection, the winner "
            f"re-evaluated with {a['best_rollouts']} rollouts) were chosen by single-seed runs "
            "of 300 iterations that were not kept. In those, without entropy injection the "
            "elite threshold froze (no sample beat a lucky iteration's V_w again, so nothing "
            "was kept), and more samples with fewer rollouts each did better than fewer "
            'samples evaluated more precisely: finding a "left" node means changing an '
            "action, the transitions into it and its division points at the same time, and "
            "more samples find such joint changes more often. Seed 0 of the built-in run: "
            f"{paper['final_value']['mean']:.3f}.",
        ]
        spec_paper = _honest("tagging-paper-cognet-spec")
        if spec_paper is not None:
            out[-1] += (
                " COGNet-DICE with SPEC settings (tagging-paper-cognet-spec) got "
                f"{spec_paper:.3f} from the same budget of simulated agent-steps: its networks "
                "have to learn the region boundaries from the pairs of 10 kept rollouts per "
                "iteration, while COG-DICE samples the boundaries directly."
            )
        words = []
        for d in ("0.5", "1", "2", "4"):
            name = f"tagging-paper-gdice-d{d}"
            value = _honest(name)
            if value is not None:
                published = float(EXPERIMENTS[name][1])
                words.append(f"d = {d}: {_compare(value, published)} ({value:.1f} / {published})")
        if words:
            out[-1] += (
                " G-DICE on the discretised problem uses the same search settings as COG-DICE; "
                "against the published G-DICE values (ours / published) it is "
                + "; ".join(words)
                + ". At d = 0.5 each agent has 41 observations and so 41 transition rows per "
                'node to learn; at d = 4 the observation cannot tell "close enough to tag" '
                'from "4 away", so no controller tags reliably.'
            )
    return "\n".join(out).rstrip()


#: the paper-budget runs (500 x 2000 x 1000) -> the built-in run of the same algorithm
PAPER_BUDGET_RUNS = {
    "tagging-paper-cogdice-full": ("COG-DICE", "tagging-paper-cogdice"),
    "tagging-paper-cognet-full": ("COGNet-DICE", "tagging-paper-cognet"),
}


#: the paper budget's wall-time target on the 2-core CPU (issue 34)
PAPER_BUDGET_TARGET_S = 30 * 60


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
        fit = "within" if f["wall_s"] <= PAPER_BUDGET_TARGET_S else "over"
        generator = f["config"]["run"]["prng_impl"]
        lines.append(
            f"{label} at the COG-DICE paper's own budget, `{name}` (seed 0): "
            f"{f['simulated_agent_steps']:.1e} simulated agent-steps in {f['wall_s'] / 60:.1f} "
            f"min wall on this 2-core CPU ({fit} the {PAPER_BUDGET_TARGET_S / 60:.0f}-minute "
            f"target; generator {generator}; {f['compile_s']:.1f} s of it compile, "
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
    body += [*paper_budget_paragraph(), notes(), ""]
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
