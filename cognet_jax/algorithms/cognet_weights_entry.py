"""The registry entry of the default ``cognet-dice`` (the search: ``algorithms.cognet_weights``):
config -> search (``build``), the "auto" settings decided before a run (``resolve``: the
horizon rule, input standardisation, the noise pilot's sizes, a budget in minutes) and the
dynamic hyper-parameters (``hyper``)."""

from __future__ import annotations

import dataclasses

from cognet_jax.algorithms.cognet_weights import CognetWeights
from cognet_jax.algorithms.cognet_weights_settings import (
    CognetWeightsSection,
    WeightsHyper,
    WeightsSettings,
    input_whitening,
    minutes_to_budget,
    resolve_search,
    resolve_standardize,
)
from cognet_jax.algorithms.noise_pilot import check_pilot_fits, measure_noise_cached
from cognet_jax.algorithms.sizing import SIZE_FIELDS, sized
from cognet_jax.budget import check_budget
from cognet_jax.observations import (
    build_pipeline,
    input_covariance,
    input_statistics,
    neural_controller,
)
from cognet_jax.registry import env_description, fields_from, register_algorithm


def build(
    config, env, env_params, memory: int | None = None, statistics: bool = True
) -> CognetWeights:
    """The search of ``config`` (``[algorithm]`` with ``experiment.algorithm = "cognet-dice"``,
    ``[network]``) on ``env``; with ``standardize_inputs`` the input statistics, and with
    ``polish_share`` the features' spread, are those of ``env_params``
    (``input_statistics``). ``statistics=False``: built without them (no rollout), a search
    whose shapes only are read (``noise_pilot.check_pilot_fits``)."""
    settings = fields_from(WeightsSettings, config.algorithm, config.network)
    pipeline, controller = neural_controller(
        env, settings.nodes, settings.hidden, build_pipeline(config, env, env_params)
    )
    if not statistics:  # shapes only: nothing measured, not even the "auto" decision
        settings = dataclasses.replace(settings, standardize_inputs=False, whiten_inputs=False)
    elif settings.standardize_inputs == "auto":  # not resolved: a config made in code
        decided = resolve_standardize(config, env, env_params).standardize_inputs
        settings = dataclasses.replace(settings, standardize_inputs=decided)
    stats = None
    if statistics and (settings.standardize_inputs or settings.polish_share > 0):
        stats = input_statistics(env, controller, pipeline, env_params, memory)
    mean, scale = stats if stats is not None else (None, None)
    kept = stats if settings.standardize_inputs else None
    if settings.standardize_inputs and settings.whiten_inputs:
        covariance = input_covariance(env, controller, pipeline, env_params, memory)
        kept = input_whitening(stats, covariance)
    return CognetWeights(env, settings, memory, pipeline, kept, scale, mean)


def resolve(config, env, env_params) -> CognetWeightsSection:
    """``config.algorithm`` with its "auto" sizes filled in (``sizing.sized``). When
    ``eval_rollouts`` is "auto", the sizes read the simulator's noise under the initial
    distribution (``noise_pilot``, measured once per simulator and distribution in a process),
    so rollouts per candidate follow what tells candidates apart on this simulator. With
    ``budget_minutes`` the budget is those minutes at the pilot's measured rate
    (``minutes_to_budget``). A budget or sizes of an absurd run are refused first, as
    ``api.build`` would refuse the sized run (``budget.check_budget``), before the seconds of
    statistics and pilot: the noise moves the budget between rollouts and candidates, it does
    not shrink it."""
    if config.algorithm.budget_minutes <= 0:
        check_budget(dataclasses.replace(config, algorithm=sized(config.algorithm, env)), env)
    config = dataclasses.replace(config, algorithm=resolve_search(config.algorithm, env))
    minutes = config.algorithm.budget_minutes > 0
    piloted = config.algorithm.eval_rollouts == "auto" or minutes
    if piloted:
        # the pilot's candidates sized first: the input statistics of "auto" standardisation
        # compile a large controller long
        check_pilot_fits(build(config, env, env_params, statistics=False))
    section = resolve_standardize(config, env, env_params)
    config = dataclasses.replace(config, algorithm=section)
    if not piloted:
        return sized(section, env)
    shown = {
        k: v
        for k, v in dataclasses.asdict(section).items()
        if k not in (*SIZE_FIELDS, "budget", "budget_minutes")
    }
    network = dataclasses.asdict(config.network) if config.network is not None else None
    noise = measure_noise_cached(
        [env_description(config), shown, network],
        lambda: (build(config, env, env_params), env_params),
    )
    if minutes:
        section = minutes_to_budget(section, noise)
    return sized(section, env, noise if section.eval_rollouts == "auto" else None)


def hyper(config) -> WeightsHyper:
    """The dynamic hyper-parameters of ``config.algorithm``."""
    return fields_from(WeightsHyper, config.algorithm)


register_algorithm(
    "cognet-dice",
    CognetWeightsSection,
    build,
    hyper,
    dynamic=("algorithm.alpha", "algorithm.action_floor", "algorithm.category_floor"),
    reads=("network",),
    overwrite=False,
    resolve=resolve,
)
