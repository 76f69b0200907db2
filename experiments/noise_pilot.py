"""How noisy a candidate's value is against how much candidates differ, per simulator: the
evidence for sizing ``eval_rollouts`` from the simulator (issue 52; not a default yet).

For each experiment, ``PILOT`` candidates of the initial ``cognet-dice`` distribution (the
first draw of seed 0) are each rolled out ``ROLLOUTS`` times on the same keys (common random
numbers). ``within`` is the standard deviation of one rollout's return (mean over candidates),
``between`` the spread of the candidates' true means (the variance of their sample means less
the noise's share, ``within^2 / ROLLOUTS``). Their ratio says how many rollouts tell two
candidates apart: K ~ (c x within / between)^2.

    python experiments/noise_pilot.py       # writes experiments/results/suite/noise-pilot.json
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import jax
import numpy as np

HERE = Path(__file__).resolve().parent
OUT = HERE / "results" / "suite" / "noise-pilot.json"
PILOT = ROLLOUTS = 64
#: the initial default vote the saved measurements drew with: before the horizon rule
#: (``resolve_search``) set it to 10 where the horizon exceeds the nodes
VOTE_BEFORE_RULE = ["algorithm.default_vote_scale=1"]
#: experiment -> overrides (the pinned tagging experiment with the library's defaults)
EXPERIMENTS = {
    "tagging-thesis-n3": [
        "algorithm.tie_structure=true",
        "algorithm.restart_tol=0.02",
        "algorithm.best_pool=4",
    ],
    **{
        experiment: VOTE_BEFORE_RULE
        for experiment in (
            "tagging-paper-auto",
            "hearing-tiger-n7",
            "hearing-tiger-noisy-n7",
            "beacon-n5",
            "bearing-chase-n5",
            "box-push-n3",
            str(HERE / "readme-seek-n3.toml"),
        )
    },
}


def pilot(experiment: str, overrides: list[str]) -> dict:
    from cognet_jax.api import build
    from cognet_jax.registry import load_config

    built = build(load_config(experiment, overrides))
    alg, params = built.algorithm, built.params
    state = alg.init(jax.random.key(0), params)
    _, policies = alg.ask(jax.random.key(1), state, params)
    policies = jax.tree.map(lambda x: x[:PILOT], policies)
    returns = jax.jit(
        jax.vmap(lambda p: alg.returns(jax.random.key(2), p, ROLLOUTS, params, ROLLOUTS))
    )(policies)
    r = np.asarray(returns, np.float64)  # [PILOT, ROLLOUTS]
    within = float(np.sqrt(r.var(1, ddof=1).mean()))
    means = r.mean(1)
    between = float(np.sqrt(max(0.0, means.var(ddof=1) - within**2 / ROLLOUTS)))
    return {
        "experiment": Path(experiment).name,
        "horizon": alg.env.horizon,
        "within": within,
        "between": between,
        "ratio": between / within if within > 0 else None,
        "mean": float(means.mean()),
        "top_decile_mean": float(np.sort(means)[-PILOT // 10 :].mean()),
    }


def main() -> int:
    from cognet_jax.plugins import import_plugin

    import_plugin(str(HERE / "readme_seek.py"))
    rows = []
    for experiment, overrides in EXPERIMENTS.items():
        rows.append(pilot(experiment, overrides))
        row = rows[-1]
        print(
            f"{row['experiment']:24s} h {row['horizon']:4d}  within {row['within']:9.3f}  "
            f"between {row['between']:9.3f}  ratio {row['ratio']:.3f}",
            flush=True,
        )
    OUT.write_text(json.dumps({"pilot": PILOT, "rollouts": ROLLOUTS, "rows": rows}, indent=1))
    print(f"wrote {OUT}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
