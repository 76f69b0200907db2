"""The budget policy of a run: how long it takes at least (its agent-steps at the fastest rate
this library simulates), what is refused as absurd, what is announced as long. ``api.build``
checks it once per run (``check_budget``); the driver and the command line read the same
constants to announce long runs and sweeps."""

from __future__ import annotations

import dataclasses

from cognet_jax.config import Config, ConfigError
from cognet_jax.errors import ResourceError
from cognet_jax.memory import budget_bytes, gb
from cognet_jax.registry import env_entry

#: agent-steps per second: about the fastest this library simulates on a 2-core CPU
#: (benchmarks/README.md: region controllers, 1e5 rollouts); time at this rate is a lower bound
FASTEST_RATE = 2e8
#: a run whose simulated agent-steps take longer than this even at ``FASTEST_RATE`` is refused
ABSURD_SECONDS = 7 * 86400.0
#: a run over this (at ``FASTEST_RATE``) gets a warning with the estimate before it starts
LONG_SECONDS = 3600.0


def simulated_agent_steps(config: Config, env) -> tuple[int, int]:
    """``(search, evaluation)``: agent-steps the search simulates at least (``iterations`` x the
    section's ``rollouts_per_iteration()`` x horizon x agents; 0 for a section without it) and
    the honest evaluation simulates."""
    per_rollout = env.horizon * env.num_agents
    rollouts = getattr(config.algorithm, "rollouts_per_iteration", None)
    search = config.algorithm.iterations * rollouts() * per_rollout if rollouts else 0
    return search, config.evaluation.rollouts * per_rollout


#: bytes the honest evaluation holds per rollout at its peak: the returns in float32, their
#: float64 copy on the host and the standard deviation's float64 temporary
#: (``honest_value.final_value_of``)
EVALUATION_BYTES_PER_ROLLOUT = 20

#: seconds one search iteration takes at least, whatever it simulates: a call of a compiled
#: program that draws and ranks its candidates (an iteration that values them exactly, G-DICE
#: on a small model, simulates nothing)
FASTEST_ITERATION = 1e-4


def _search_seconds(config: Config, env) -> tuple[float, bool]:
    """``(seconds, by_iterations)``: the search's least time -- its agent-steps at
    ``FASTEST_RATE``, or its iterations at ``FASTEST_ITERATION`` each when that is longer
    (``by_iterations`` then true)."""
    steps = simulated_agent_steps(config, env)[0] / FASTEST_RATE
    iterations = getattr(config.algorithm, "iterations", 0)
    floor = iterations * FASTEST_ITERATION if isinstance(iterations, int) else 0.0
    return max(steps, floor), floor > steps


def estimated_seconds(config: Config, env) -> float:
    """Seconds a run of ``config`` takes at least: its search (``_search_seconds``) and the
    honest evaluation's agent-steps at ``FASTEST_RATE``. An estimate, no check."""
    return _search_seconds(config, env)[0] + simulated_agent_steps(config, env)[1] / FASTEST_RATE


def check_budget(config: Config, env) -> float:
    """Seconds the run takes at least (its agent-steps at ``FASTEST_RATE``), checked before
    anything is built or compiled: ``ConfigError`` naming the field when that is absurd (over
    ``ABSURD_SECONDS``), ``ResourceError`` when the honest evaluation's returns cannot fit the
    memory budget ``run.memory_gb``."""
    search, evaluation = simulated_agent_steps(config, env)
    returns = EVALUATION_BYTES_PER_ROLLOUT * config.evaluation.rollouts
    if returns > budget_bytes(config.run.memory_gb):
        raise ResourceError(
            f"evaluation.rollouts: {config.evaluation.rollouts} returns need {gb(returns)} "
            f"({EVALUATION_BYTES_PER_ROLLOUT} bytes each), over the memory budget of "
            f"{gb(budget_bytes(config.run.memory_gb))}; lower evaluation.rollouts or raise "
            "run.memory_gb"
        )
    seconds = estimated_seconds(config, env)
    if seconds > ABSURD_SECONDS and _search_seconds(config, env)[1]:
        raise ConfigError(
            "algorithm.iterations",
            f"{config.algorithm.iterations} iterations take at least {seconds / 86400:.0f} days "
            f"at {FASTEST_ITERATION * 1e6:.0f} us each, over the limit of "
            f"{ABSURD_SECONDS / 86400:.0f} days",
        )
    if seconds > ABSURD_SECONDS:
        field = "evaluation.rollouts" if evaluation > search else _largest_size(config, env)
        fixed = "" if field else f"the simulator's horizon of {env.horizon} steps: "
        raise ConfigError(
            field,
            f"{fixed}the run simulates {search + evaluation:.3g} agent-steps (horizon "
            f"{env.horizon}, {env.num_agents} agents): at least {seconds / 86400:.0f} days at "
            f"{FASTEST_RATE:.0e} agent-steps/s, over the limit of {ABSURD_SECONDS / 86400:.0f} "
            "days",
        )
    return seconds


#: the horizon a size check compares with, for simulators without a default horizon
TYPICAL_HORIZON = 100


def _largest_size(config: Config, env) -> str:
    """The size field of the search that is the largest multiple of its reference (the one to
    blame when the run's agent-steps are absurd): the horizon, or a number of ``[algorithm]``
    (an integer, or one the section's ``size_references(env)`` names: its "auto" sizes and
    budget, measured against what its rules give by default). The reference of an integer
    is its default; of the horizon, ``TYPICAL_HORIZON`` when the simulator's default is not
    a number. "" names the simulator's own horizon, when its section has no such field."""
    section = config.algorithm
    references = getattr(section, "size_references", lambda env: {})(env)
    horizon = "problem" if "problem" in env_entry(config.env.name).reads else "env"
    own = getattr(getattr(config, horizon), "horizon", None)
    horizon_default = {f.name: f.default for f in dataclasses.fields(getattr(config, horizon))}
    horizon_default = horizon_default.get("horizon")
    if not isinstance(horizon_default, int) or isinstance(horizon_default, bool):
        horizon_default = TYPICAL_HORIZON  # a simulator whose horizon comes from its setting
    name = f"{horizon}.horizon" if isinstance(own, int) else ""
    ratios = {name: env.horizon / horizon_default}
    defaults = {f.name: f.default for f in dataclasses.fields(type(section))}
    for field in [f.name for f in _int_fields(config)] + sorted(references):
        value, reference = getattr(section, field, None), references.get(field, defaults[field])
        number = isinstance(value, (int, float)) and not isinstance(value, bool)
        if number and isinstance(reference, (int, float)) and reference > 0:
            ratios[f"algorithm.{field}"] = value / reference
    return max(ratios, key=ratios.get)


def _int_fields(config: Config):
    return [
        f
        for f in dataclasses.fields(type(config.algorithm))
        if isinstance(getattr(config.algorithm, f.name), int)
        and not isinstance(getattr(config.algorithm, f.name), bool)
    ]


#: an honest evaluation of this many rollouts or more is announced before it runs
ANNOUNCED_ROLLOUTS = 1_000_000


def evaluation_line(config: Config, env, what: str) -> str | None:
    """The line announcing ``what``'s honest evaluation (its rollouts, agent-steps and least
    time at ``FASTEST_RATE``) when it has ``ANNOUNCED_ROLLOUTS`` or more; ``None`` below."""
    if config.evaluation.rollouts < ANNOUNCED_ROLLOUTS:
        return None
    steps = simulated_agent_steps(config, env)[1]
    return (
        f"evaluating {what}: {config.evaluation.rollouts} rollouts, {steps:.3g} agent-steps, "
        f"at least {steps / FASTEST_RATE:.3g} s ..."
    )
