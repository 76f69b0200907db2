"""G-DICE's registry entry: a config to a search (``build``). The rules that size it from the
model: ``repeats = "auto"`` (``auto_repeats``), the evaluator (``resolve_evaluator``), the
polish where affordable (``affordable_polish``), a portfolio when more than one search runs
(``algorithms.gdice_portfolio``). The search itself: ``algorithms.gdice_search``."""

from __future__ import annotations

import dataclasses

from cognet_jax.algorithms.best_response import best_response_cost
from cognet_jax.algorithms.cross_entropy import (
    ENTROPY_FIELDS,
)
from cognet_jax.algorithms.engine import (
    threshold_hyper,
)
from cognet_jax.algorithms.gdice_portfolio import GDicePortfolio
from cognet_jax.algorithms.gdice_search import (
    AUTO_REPEATS_MAX,
    BEST_RESPONSE_FLOATS,
    EXACT_AUTO_LIMIT,
    EXACT_EVALUATOR_LIMIT,
    EXACT_TOP_MAX,
    HYBRID_EXACT_LIMIT,
    HYBRID_MIN_TOP,
    POLISH_SWEEP_LIMIT,
    GDice,
    GDiceSection,
    GDiceSettings,
)
from cognet_jax.config import (
    ConfigError,
)
from cognet_jax.envs.tabular import TabularEnv
from cognet_jax.exact_jax import (
    exact_cost,
)
from cognet_jax.registry import fields_from, register_algorithm


def exact_iteration_cost(env, section, env_params=None) -> int:
    """Multiply-adds of exact values for one iteration's samples (all restarts)."""
    # a layered controller's recursion runs over one layer (``nodes`` per agent) per step
    searches = section.restarts + section.shared_restarts + section.explore_restarts
    return exact_cost(env, section.nodes, env_params) * section.samples * searches


def auto_repeats(env, section, env_params) -> int:
    """How many times ``repeats = "auto"`` runs every search: as many as keep one iteration's
    exact values of every sample within ``EXACT_AUTO_LIMIT`` multiply-adds (the limit that
    makes ``evaluator = "auto"`` exact), at most ``AUTO_REPEATS_MAX``; 1 where the samples are
    not all valued exactly (``rollouts``, ``hybrid``, or ``auto`` resolving to either). So the
    search grows where it is cheap (Dec-Tiger: 8 at every horizon; GridSmall: 6 at h 2, 2 at
    h 5, 1 from h 7) and stays as it is on the larger models."""
    if section.evaluator not in ("exact", "auto") or not isinstance(env, TabularEnv):
        return 1
    cost = exact_iteration_cost(env, section, env_params)
    return max(1, min(AUTO_REPEATS_MAX, EXACT_AUTO_LIMIT // cost))


def with_repeats(env, section, env_params):
    """``section`` with ``repeats`` resolved to a number and every search count
    (``restarts``, ``shared_restarts``, ``explore_restarts``) multiplied by it. The first
    search of each kind keeps its keys (``GDicePortfolio._member_keys`` splits one key per
    member, and a split's i-th key does not depend on the count), so the repeated portfolio
    runs the unrepeated one's searches and more."""
    repeats = section.repeats
    if repeats == "auto":
        repeats = auto_repeats(env, section, env_params)
    return dataclasses.replace(
        section,
        repeats=repeats,
        restarts=section.restarts * repeats,
        shared_restarts=section.shared_restarts * repeats,
        explore_restarts=section.explore_restarts * repeats,
    )


def resolve_evaluator(env, section, env_params) -> str:
    """``section.evaluator`` with ``"auto"`` resolved from the model's exact cost
    (``EXACT_AUTO_LIMIT``); ``ConfigError`` when exact values would cost more than
    ``EXACT_EVALUATOR_LIMIT`` per iteration."""
    evaluator = section.evaluator
    if evaluator != "rollouts" and not isinstance(env, TabularEnv):
        raise ConfigError(
            "algorithm.evaluator",
            f"{evaluator!r} needs a tabular .dpomdp model (env.name = 'dpomdp')",
        )
    if evaluator == "rollouts":
        return evaluator
    cost = exact_iteration_cost(env, section, env_params)
    auto_top = section.exact_top == "auto"
    top = min(
        max(1, fitting_top(cost, section)) if auto_top else section.exact_top, section.samples
    )
    if evaluator == "auto":
        evaluator = "exact" if cost <= EXACT_AUTO_LIMIT else "hybrid"
        if evaluator == "hybrid" and (
            top < HYBRID_MIN_TOP if auto_top else cost * top // section.samples > EXACT_AUTO_LIMIT
        ):
            return "rollouts"
    if evaluator == "hybrid":
        cost = cost * top // section.samples
    if cost > EXACT_EVALUATOR_LIMIT:
        raise ConfigError(
            "algorithm.evaluator",
            f"{evaluator!r} would need {cost:.2e} multiply-adds per iteration (nodes^agents * S "
            f"* (S + joint observations) * horizon * samples * searches > "
            f"{EXACT_EVALUATOR_LIMIT:.0e}); use 'rollouts' or fewer nodes/samples"
            + (" or exact_top" if evaluator == "hybrid" else ""),
        )
    return evaluator


def resolve_exact_top(env, section, env_params, evaluator: str) -> int:
    """``section.exact_top`` with "auto" resolved: with the hybrid evaluator, as many of the
    samples as keep one iteration's exact values within ``HYBRID_EXACT_LIMIT`` multiply-adds,
    at most ``EXACT_TOP_MAX`` and at least 1 (fire fighting 2-3-3: 34 at h 3, 25 at h 4, 20 at
    h 5; box pushing 45 at h 4); ``EXACT_TOP_MAX`` where it is unused."""
    if section.exact_top != "auto":
        return section.exact_top
    if evaluator != "hybrid":
        return EXACT_TOP_MAX
    return max(1, fitting_top(exact_iteration_cost(env, section, env_params), section))


def fitting_top(cost: int, section) -> int:
    """How many of ``section.samples`` get exact values within ``HYBRID_EXACT_LIMIT``
    multiply-adds per iteration when valuing all of them costs ``cost``, at most
    ``EXACT_TOP_MAX``."""
    fits = HYBRID_EXACT_LIMIT * section.samples // max(cost, 1)
    return int(min(EXACT_TOP_MAX, section.samples, fits))


def affordable_polish(env, settings, env_params):
    """``settings`` with the polish and the best responses dropped where they would cost more
    than ``POLISH_SWEEP_LIMIT`` / ``BEST_RESPONSE_FLOATS`` for this model (results.json's
    ``resolved`` shows what ran)."""
    nodes = settings.nodes
    if settings.polish_sweeps and settings.evaluator in ("exact", "hybrid"):
        moves = GDice(env, settings).polish_moves(count=True)
        if moves * exact_cost(env, nodes, env_params) > POLISH_SWEEP_LIMIT:
            settings = dataclasses.replace(settings, polish_sweeps=0)
    if settings.best_response_rounds and not (settings.polish_sweeps and settings.layered):
        settings = dataclasses.replace(settings, best_response_rounds=0)
    if settings.best_response_rounds:
        costs = [best_response_cost(env, nodes, i, env_params) for i in range(env.num_agents)]
        if (
            max(c[0] for c in costs) > POLISH_SWEEP_LIMIT
            or max(c[1] for c in costs) > BEST_RESPONSE_FLOATS
        ):
            settings = dataclasses.replace(settings, best_response_rounds=0)
    return settings


def build(config, env, env_params, memory: int | None = None) -> GDice | GDicePortfolio:
    """The search of ``config`` (``experiment.algorithm = "gdice"``): the searches repeated
    (``with_repeats``), the evaluator and its exact part resolved (``resolve_evaluator``,
    ``resolve_exact_top``), the polish kept where
    affordable (``affordable_polish``), a portfolio when more than one search runs."""
    a = with_repeats(env, config.algorithm, env_params)
    evaluator = resolve_evaluator(env, a, env_params)
    top = resolve_exact_top(env, a, env_params, evaluator)
    settings = affordable_polish(
        env, fields_from(GDiceSettings, a, evaluator=evaluator, exact_top=top), env_params
    )
    if a.restarts > 1 or a.shared_restarts > 0 or a.explore_restarts > 0:
        return GDicePortfolio(
            env,
            settings,
            memory,
            shared_restarts=a.shared_restarts,
            explore_restarts=a.explore_restarts,
            explore_rate=a.explore_entropy_rate,
        )
    return GDice(env, settings, memory)


register_algorithm(
    "gdice",
    GDiceSection,
    build,
    threshold_hyper,
    dynamic=(*ENTROPY_FIELDS, "algorithm.alpha"),
    discrete=True,
    overwrite=False,
)
