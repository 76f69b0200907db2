"""The paper setting's kept policies against the reactive controller of SPEC section 8 (its
division points at -1 and 1) on the same honest rollouts: each run folder's seed evaluation key
and ``evaluation.rollouts``, so the difference is paired.

    python experiments/paired_reactive.py RUN_FOLDER...
"""

import sys

import jax.numpy as jnp
import numpy as np

from cognet_jax.api import seed_key, split_seed_key
from cognet_jax.controllers.regions import reactive_tagging_policy
from cognet_jax.rollout import many_returns
from cognet_jax.saved_runs import load_run

rc, rp = reactive_tagging_policy()
pts = jnp.tile(jnp.array([-1.0, 1.0], jnp.float32), (2, 3, 1))
rp = rp.replace(points=pts)
for d in sys.argv[1:]:
    run = load_run(d)
    seed = run.results["seed"]
    _, _, k_eval = split_seed_key(seed_key(run.config, seed))
    n = run.config.evaluation.rollouts
    ours = np.asarray(run.algorithm.returns(k_eval, run.policy, n, run.params))
    reac = np.asarray(many_returns(run.algorithm.env, rc, k_eval, run.params.env, rp, n))
    diff = ours - reac
    sweep = d.rstrip("/").split("/")[-3]
    same = f"results {run.results['final_value']['mean']:.3f}"
    paired = f"diff {diff.mean():.3f} +- {diff.std() / np.sqrt(n):.3f}"
    print(f"{sweep} {seed} ours {ours.mean():.3f} ({same}) reactive {reac.mean():.3f} {paired}")
