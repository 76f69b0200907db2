"""What a finished G-DICE run reports (the driver's hooks of ``engine.Search``): the polish
record and its progress line, the exact values of the best controller on a ``.dpomdp`` model,
and the controller graphs with the model's action and observation names."""

from __future__ import annotations

import warnings

import numpy as np

from cognet_jax.controllers.figures import action_names, tabular_plots
from cognet_jax.envs.tabular import TabularEnv, load_problem
from cognet_jax.errors import OneLineWarning
from cognet_jax.exact import exact_value
from cognet_jax.registry import env_entry

#: the exact value's joint tables (joint nodes x joint observations entries, ``exact``) above
#: which the record skips it: 2**26 entries are 0.5 GB of int64, and the count grows as
#: nodes ** agents (10 agents of 7 nodes: 2.8e8 joint nodes)
EXACT_MAX_ENTRIES = 1 << 26


def _model(config, env):
    """The parsed ``.dpomdp`` model of a tabular simulator built from ``problem.path``, else
    ``None`` (a user's simulator may read ``[problem]`` in a format of its own)."""
    reads = "problem" in env_entry(config.env.name).reads
    if not isinstance(env, TabularEnv) or not config.problem.path or not reads:
        return None
    return load_problem(config.problem)


class TabularReports:
    """The reporting hooks of G-DICE's searches (``GDice``, ``GDicePortfolio``)."""

    def finish_record(self, info, seconds: float) -> dict | None:
        """results.json ``polish``: exact values before and after, moves and best responses
        applied, exact evaluations spent (``gdice_search.PolishInfo`` of one run)."""
        if info is None:
            return None
        return {
            "value_before": float(info.before),
            "value_after": float(info.after),
            "moves_applied": int(info.moves_applied),
            "moves_per_sweep": int(info.moves_per_sweep),
            "best_responses_applied": int(info.responses_applied),
            "exact_evaluations": int(info.evaluations),
            "budget": int(info.budget),
            "seconds": seconds,
        }

    def finish_status(self, work) -> dict:
        """The polish's progress: moves applied, the best exact value and the exact
        evaluations spent so far (the largest over runs and candidates)."""
        moves, value, spent = (
            np.max(np.asarray(getattr(work, f))) for f in ("moves_applied", "value", "spent")
        )
        return {"moves": int(moves), "value": f"{float(value):.6g}", "evaluations": int(spent)}

    def finish_line(self, record: dict) -> str | None:
        return (
            f"polish: exact {record['value_before']:.6f} -> {record['value_after']:.6f} "
            f"({record['moves_applied']} moves of {record['moves_per_sweep']} tried per sweep, "
            f"{record['best_responses_applied']} best responses, {record['seconds']:.1f} s)"
        )

    def exact_record(self, config, policy) -> dict | None:
        """``{"exact": value at problem.horizon (backward DP)}`` plus ``"exact_infinite"``
        (Bellman iteration to 1e-10) when the discount is below 1, on a ``.dpomdp`` model."""
        model = _model(config, self.env)
        if model is None:
            return None
        actions, transitions = np.asarray(policy.actions), np.asarray(policy.transitions)
        entries = float(actions.shape[-1]) ** len(model.obs_counts) * np.prod(model.obs_counts)
        if entries > EXACT_MAX_ENTRIES:
            warnings.warn(
                f"{config.problem.path}: no exact value of the policy ({actions.shape[-1]} "
                f"nodes ** {len(model.obs_counts)} agents x joint observations = {entries:.2g} "
                f"table entries, over {EXACT_MAX_ENTRIES:.2g}); its honest value stands",
                OneLineWarning,
                stacklevel=2,
            )
            return None
        horizon, gamma = config.problem.horizon, model.discount
        out = {"exact": float(exact_value(model, actions, transitions, horizon, gamma))}
        if gamma < 1:
            out["exact_infinite"] = float(exact_value(model, actions, transitions, None, gamma))
        return out

    def write_plots(self, config, policy, record: dict, out_dir) -> list:
        """``controllers.png``: each agent's controller graph, with the model's names."""
        env, model = self.env, _model(config, self.env)
        if model is not None:
            names = model.action_names
            same = len(set(names)) == 1
            actions = names[0] if same else tuple(str(a) for a in range(env.num_actions))
            observations = [list(n) for n in model.observation_names]
        else:
            actions = action_names(env)
            values = getattr(env, "observation_values", None)  # discretised observations
            labels = [f"{v:g}" for v in values] if values is not None else None
            labels = labels or [str(z) for z in range(env.num_obs)]
            observations = [labels] * env.num_agents
        return tabular_plots(env, policy, record, out_dir, actions, observations)
