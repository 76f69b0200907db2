"""Sizes of a cross-entropy search from its budget: the "auto" settings of ``cognet-dice`` as
rules over the problem's sizes (horizon, agents) and the budget in agent-steps.

``sized(section, env)`` fills in ``iterations``, ``candidates``, ``eval_rollouts`` and ``elites``
where they are "auto" and keeps every size given as a number; the registry calls it when a
config is read (``AlgorithmEntry.resolve``), so a run's results.json holds the sizes it ran
with.
"""

from __future__ import annotations

import dataclasses

#: the settings ``sized`` fills in when they are "auto"
SIZE_FIELDS = ("iterations", "candidates", "eval_rollouts", "elites")
#: default budget, in rollouts of the search (``budget = "auto"``: this x horizon x agents
#: agent-steps): the same number of episodes on every problem
AUTO_BUDGET_ROLLOUTS = 3e7
#: population of the cross-entropy method, and the elites' share of it
AUTO_CANDIDATES = 200
ELITE_FRACTION = 0.05
#: iterations are ``budget rollouts / (candidates x EVAL_ROLLOUTS_BASE)`` within this range:
#: the distribution needs about a hundred refits with smoothing 0.3 to settle, and beyond a
#: few hundred, evaluations of less noise pay more than further refits (shared/FINDINGS.md)
ITERATIONS_RANGE = (100, 400)
EVAL_ROLLOUTS_BASE = 250
#: rollouts per candidate, after the iterations are set: what the budget leaves, in this
#: range; a budget beyond the largest grows the population instead
EVAL_ROLLOUTS_RANGE = (10, 1000)


def sized(section, env):
    """``section`` with its "auto" sizes filled in from the budget ``B`` (agent-steps;
    ``AUTO_BUDGET_ROLLOUTS x h x n`` by default) on a simulator of horizon ``h`` and ``n``
    agents, ``R = B / (h n)`` rollouts:

    * candidates ``C = AUTO_CANDIDATES``, elites ``max(2, ELITE_FRACTION x C)``;
    * iterations ``I = R / (C x EVAL_ROLLOUTS_BASE)`` clipped to ``ITERATIONS_RANGE``;
    * rollouts per candidate ``K = R / (C x I)`` clipped to ``EVAL_ROLLOUTS_RANGE``;
    * when ``K`` is at its largest, ``C = R / (I x K)``: a larger budget always buys more
      iterations, then less noise per candidate, then a larger population.

    Settings given as numbers are kept, and the others sized around them."""
    values = {f: getattr(section, f) for f in SIZE_FIELDS}
    if all(v != "auto" for v in values.values()):
        return section
    per_rollout = env.horizon * env.num_agents
    budget = AUTO_BUDGET_ROLLOUTS * per_rollout if section.budget == "auto" else section.budget
    rollouts = max(1.0, budget / per_rollout)

    def given_or(name, rule):
        return values[name] if values[name] != "auto" else rule()

    lo_i, hi_i = ITERATIONS_RANGE
    lo_k, hi_k = EVAL_ROLLOUTS_RANGE
    c = given_or("candidates", lambda: AUTO_CANDIDATES)
    i = given_or(
        "iterations",
        lambda: max(1, round(min(hi_i, max(lo_i, rollouts / (c * EVAL_ROLLOUTS_BASE))))),
    )
    k = given_or("eval_rollouts", lambda: int(min(hi_k, max(lo_k, rollouts / (c * i)))))
    if values["candidates"] == "auto" and k >= hi_k and rollouts / (i * k) > c:
        c = int(rollouts / (i * k))
    if values["iterations"] == "auto" and rollouts < c * lo_i * k:  # a budget below the range
        i = max(1, int(rollouts / (c * k)))
    e = given_or("elites", lambda: max(2, round(ELITE_FRACTION * c)))
    return dataclasses.replace(section, iterations=i, candidates=c, eval_rollouts=k, elites=e)
