"""The 8-seed sweeps that judge the default COGNet-DICE (and its ablations); writes the
``cognet-sweeps`` block of experiments/README.md from the saved sweep folders.

    python experiments/cognet_sweeps.py              # run every sweep below, then the table
    python experiments/cognet_sweeps.py --table-only # rebuild the table from saved sweeps

Each sweep is exactly ``cognet-jax sweep EXPERIMENT --seeds 8 [--set ...] --out
experiments/results/sweeps/NAME`` (one compiled program for the 8 seeds; seed s uses the keys
of ``cognet-jax train --seed s``). The table reads ``runs.json`` of every folder: honest value
per seed (fresh 10,000-rollout evaluation of the seed's best policy with a key the search never
saw), the settings from the stored config, the search budget in simulated agent-steps per run
and the sweep's wall time.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

from _readme import machine, replace_block

HERE = Path(__file__).resolve().parent
SWEEPS = HERE / "results" / "sweeps"
SEEDS = 8

#: the raw heatmap search before standardised inputs and paired best (both off)
PLAIN = ["algorithm.standardize_inputs=false", "algorithm.paired_best=false"]

#: folder -> (experiment, overrides, what the row tests)
RUNS = {
    "tagging-thesis-n3": ("tagging-thesis-n3", [], "default"),
    "tagging-thesis-n6": ("tagging-thesis-n6", [], "default"),
    "tagging-thesis-n3-it800": (
        "tagging-thesis-n3",
        ["algorithm.iterations=800"],
        "ablation: 800 iterations",
    ),
    "tagging-thesis-n6-it800": (
        "tagging-thesis-n6",
        ["algorithm.iterations=800"],
        "ablation: 800 iterations",
    ),
    "heatmap-2d-n4": ("heatmap-2d-n4", [], "default"),
    "heatmap-2d-n4-plain": (
        "heatmap-2d-n4",
        PLAIN,
        "ablation: raw pixels, best by the best fresh value (the default before standardised "
        "inputs and paired best)",
    ),
    "heatmap-2d-n4-best1000": (
        "heatmap-2d-n4",
        [*PLAIN, "algorithm.best_rollouts=1000"],
        "ablation of -plain: anytime best on 1000 fresh rollouts",
    ),
    "heatmap-2d-n4-hidden16": (
        "heatmap-2d-n4",
        [*PLAIN, "network.hidden=16"],
        "ablation of -plain: 16 hidden units",
    ),
    "heatmap-encoded-n4": ("heatmap-encoded-n4", [], "default (2-D latent, KL weight 0.01)"),
    "heatmap-encoded-n4-latent1": (
        "heatmap-encoded-n4",
        ["network.vae_latent=1", "network.vae_kl_weight=1.0", "network.vae_epochs=60"],
        "ablation: the thesis's 1-D VAE (distance only: see the heatmap's distance-only bound)",
    ),
    "heatmap-encoded-n4-default": (
        "heatmap-encoded-n4",
        ["env.start=default"],
        "default start range (bound 4.431)",
    ),
    "heatmap-2d-n4-default": (
        "heatmap-2d-n4",
        ["env.start=default"],
        "default start range (bound 4.431)",
    ),
    "heatmap-2d-n4-default-std": (
        "heatmap-2d-n4",
        ["env.start=default", "algorithm.paired_best=false"],
        "ablation: standardised inputs without paired best",
    ),
    "heatmap-2d-n4-default-plain": (
        "heatmap-2d-n4",
        ["env.start=default", *PLAIN],
        "ablation: raw pixels, best by the best fresh value",
    ),
}


def run(names: list[str]) -> None:
    for name in names:
        experiment, overrides, _ = RUNS[name]
        sets = [x for o in overrides for x in ("--set", o)]
        cmd = ["cognet-jax", "sweep", experiment, "--seeds", str(SEEDS), "--no-progress"]
        cmd += [*sets, "--out", str(SWEEPS / name)]
        print(" ".join(cmd), flush=True)
        subprocess.run(cmd, check=True)


def _settings(config: dict) -> str:
    alg, net, env = config["algorithm"], config["network"], config["env"]
    text = (
        f"{alg['iterations']} it x {alg['candidates']} cand. x {alg['eval_rollouts']}, "
        f"{alg['elites']} elites, best on {alg['best_rollouts']}, hidden {net['hidden']}"
    )
    if alg.get("standardize_inputs"):
        text += ", standardised inputs"
    if alg.get("paired_best"):
        text += ", paired best"
    if net.get("observation") == "encoded":
        text += f", VAE latent {net['vae_latent']} (KL weight {net['vae_kl_weight']:g})"
    if env.get("start"):
        text += f", start {env['start']}"
    return text


def _agent_steps(config: dict) -> float:
    from cognet_jax.api import build_env
    from cognet_jax.registry import config_from_dict

    env, _ = build_env(config_from_dict(config))
    alg = config["algorithm"]
    fresh = 3 if alg.get("paired_best") else 2  # winner, mode (and the best so far)
    per_iteration = alg["candidates"] * alg["eval_rollouts"] + fresh * alg["best_rollouts"]
    return alg["iterations"] * per_iteration * env.horizon * env.num_agents


def table() -> list[str]:
    rows = [
        "| sweep | experiment | what it tests | settings | seeds | honest mean +- s.e. | "
        "min | max | per seed | agent-steps per run | sweep wall s |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, (_, _, note) in RUNS.items():
        path = SWEEPS / name / "runs.json"
        if not path.is_file():
            continue
        data = json.loads(path.read_text())
        values = [r["final_value"]["mean"] for r in data["rows"]]
        n = len(values)
        mean = sum(values) / n
        se = (sum((v - mean) ** 2 for v in values) / (n - 1) / n) ** 0.5 if n > 1 else 0.0
        cells = ", ".join(f"{v:.2f}" for v in values)
        sets = " ".join(f"`--set {o}`" for o in data.get("overrides", []))
        rows.append(
            f"| {name} | {data['experiment']} {sets} | {note} | {_settings(data['config'])} | "
            f"{n} | {mean:.3f} +- {se:.3f} | {min(values):.3f} | {max(values):.3f} | {cells} | "
            f"{_agent_steps(data['config']):.3g} | {data['wall_s']:.0f} |"
        )
    return rows


NOTES = """\
Each row is one `cognet-jax sweep EXPERIMENT --seeds 8` (seeds 0-7); the honest value of a seed
is the fresh 10,000-rollout evaluation of its best policy, +- is the standard error over the 8
seeds. Sweep wall time covers the 8 seeds in one program on 2 cores (compile included); the
wall time of single `cognet-jax train` runs is in the tagging and heatmap tables. The sweeps
heatmap-2d-n4-plain and heatmap-2d-n4-hidden16 shared the machine with a test run, so their
wall times are too high (heatmap-2d-n4-best1000 ran alone: its settings differ only in the
number of fresh rollouts per iteration, 2 x 1000 instead of 2 x `best_rollouts`). Rows whose
overrides switch `standardize_inputs` and `paired_best` off ran before those options existed,
with the code path that is still taken when they are off."""


def write_table() -> None:
    body = [
        "## COGNet-DICE (default): 8-seed sweeps and ablations",
        "",
        *table(),
        "",
        NOTES,
        "",
        f"Generated by `python experiments/cognet_sweeps.py`; machine: {machine()}.",
    ]
    replace_block("cognet-sweeps", "\n".join(body))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("sweeps", nargs="*", help=f"default: all of {', '.join(RUNS)}")
    p.add_argument("--table-only", action="store_true")
    args = p.parse_args(argv)
    unknown = [n for n in args.sweeps if n not in RUNS]
    if unknown:
        p.error(f"unknown sweep(s) {', '.join(unknown)}; known: {', '.join(RUNS)}")
    if not args.table_only:
        run(args.sweeps or list(RUNS))
    write_table()
    return 0


if __name__ == "__main__":
    sys.exit(main())
