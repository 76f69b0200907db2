"""Sizes of a cross-entropy search from its budget: the "auto" settings of ``cognet-dice`` as
rules over the problem's sizes (horizon, agents), the budget in agent-steps and, when measured,
the simulator's noise (``noise_pilot``).

``sized(section, env, noise)`` fills in ``iterations``, ``candidates``, ``eval_rollouts`` and
``elites`` where they are "auto" and keeps every size given as a number; the registry calls
it when a config is read (``AlgorithmEntry.resolve``, with the noise of a pilot), so a run's
results.json holds the sizes it ran with.
"""

from __future__ import annotations

import dataclasses
import math

#: the settings ``sized`` fills in when they are "auto"
SIZE_FIELDS = ("iterations", "candidates", "eval_rollouts", "elites")
#: default budget, in rollouts of the search (``budget = "auto"``: this x horizon x agents
#: agent-steps): the same number of episodes on every problem
AUTO_BUDGET_ROLLOUTS = 3e7
#: population of the cross-entropy method before the budget grows it, and the elites' share
AUTO_CANDIDATES = 200
ELITE_FRACTION = 0.05
#: iterations are ``budget rollouts / (candidates x rollouts per candidate)`` within this
#: range: the distribution needs about a hundred refits with smoothing 0.3 to settle.
#: **[choice]** Up to 800, where the earlier rule stopped at 400: the exploring searches
#: restart when they converge (about a hundred iterations each on the suite's problems), and
#: searches ending in optima of very different quality are draws of a lottery, so twice the
#: iterations at half the rollouts each is twice the draws (experiments/NOTES.md, "Twice the
#: exploring searches")
ITERATIONS_RANGE = (100, 800)
#: rollouts per candidate the iterations are sized with: the default budget then gives the
#: most iterations (3e7 rollouts / (200 x 187.5) = 800)
EVAL_ROLLOUTS_BASE = 187.5
#: rollouts per candidate are kept in this range
EVAL_ROLLOUTS_RANGE = (10, 1000)
#: with the noise measured, a candidate's standard error is this fraction of how much the
#: initial candidates differ (``Noise.rollouts_to_resolve``)
NOISE_RESOLUTION = 8.0


def resolving_rollouts(noise) -> float:
    """Rollouts per candidate that resolve the initial candidates of ``noise``
    (``noise_pilot.Noise``) to ``1 / NOISE_RESOLUTION`` of their spread, at least the smallest
    of ``EVAL_ROLLOUTS_RANGE``; ``inf`` without a measurement."""
    need = math.inf if noise is None else noise.rollouts_to_resolve(NOISE_RESOLUTION)
    return need if math.isinf(need) else max(EVAL_ROLLOUTS_RANGE[0], math.ceil(need))


def sized(section, env, noise=None):
    """``section`` with its "auto" sizes filled in from the budget ``B`` (agent-steps;
    ``AUTO_BUDGET_ROLLOUTS x h x n`` by default) on a simulator of horizon ``h`` and ``n``
    agents, ``R = B / (h n)`` rollouts, and the simulator's ``noise`` when measured:

    * iterations ``I = R / (AUTO_CANDIDATES x min(EVAL_ROLLOUTS_BASE, Kn))`` clipped to
      ``ITERATIONS_RANGE`` (a budget below the fewest runs fewer), with ``Kn`` below;
    * the budget's rollouts per candidate ``Kb = R / (AUTO_CANDIDATES x I)``; ``K = Kb`` at most
      the largest of ``EVAL_ROLLOUTS_RANGE`` (a budget beyond grows the population instead);
    * where the noise says fewer rollouts already tell the initial candidates apart,
      ``Kn = resolving_rollouts(noise) < Kb``, the budget moves from rollouts to candidates:
      ``K = sqrt(Kn Kb)`` and ``C = R / (I K)`` (both by the square root of ``Kb / Kn``);
      a quiet simulator also reaches the most iterations at a smaller budget (``I`` above).
      **[choice]** Never the other way: on the noisiest simulators of the suite more
      rollouts bought with fewer iterations gave worse controllers, while on quiet ones a
      larger population with fewer rollouts each gave better ones (experiments/NOTES.md).
      Half way (the geometric mean), since candidates differ less once the distribution
      narrows than at the start, where ``Kn`` is measured;
    * elites ``max(2, ELITE_FRACTION x C)``.

    Settings given as numbers are kept, and the others sized around them."""
    values = {f: getattr(section, f) for f in SIZE_FIELDS}
    if all(v != "auto" for v in values.values()):
        return section
    per_rollout = env.horizon * env.num_agents
    budget = AUTO_BUDGET_ROLLOUTS * per_rollout if section.budget == "auto" else section.budget
    rollouts = max(1.0, budget / per_rollout)
    auto = {f for f, v in values.items() if v == "auto"}
    lo_i, hi_i = ITERATIONS_RANGE
    lo_k, hi_k = EVAL_ROLLOUTS_RANGE

    resolving = resolving_rollouts(noise)
    c = AUTO_CANDIDATES if "candidates" in auto else values["candidates"]
    i = values["iterations"]
    if "iterations" in auto:
        base = min(EVAL_ROLLOUTS_BASE, resolving)
        base = base if "eval_rollouts" in auto else values["eval_rollouts"]
        i = max(1, round(min(hi_i, max(lo_i, rollouts / (c * base)))))
    k = values["eval_rollouts"]
    spare = "eval_rollouts" not in auto  # budget the given rollouts leave to the population
    if "eval_rollouts" in auto:
        budget_k = rollouts / (c * i)
        k = int(min(hi_k, max(lo_k, budget_k)))
        spare = budget_k > hi_k
        if "candidates" in auto and resolving < k:
            k, spare = int(min(hi_k, max(lo_k, math.sqrt(resolving * budget_k)))), True
    if "candidates" in auto and spare and rollouts / (i * k) > c:
        c = int(rollouts / (i * k))
    if "iterations" in auto and rollouts < c * lo_i * k:  # a budget below the range
        i = max(1, int(rollouts / (c * k)))
    e = values["elites"] if "elites" not in auto else max(2, round(ELITE_FRACTION * c))
    return dataclasses.replace(section, iterations=i, candidates=c, eval_rollouts=k, elites=e)
