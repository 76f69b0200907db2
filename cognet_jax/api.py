"""Public entry points: build a simulator and a search from a ``Config`` (or by name), and get
pure functions to run them.

* ``build_algorithm(config) -> (algorithm, params)``: the immutable search object and its
  ``SearchParams`` (the simulator's params pytree and the hyper-parameters), gymnax style;
  every method of the search takes ``params`` explicitly (``algorithms.engine``).
* ``make_train(config) -> train(key, params=None) -> (final_state, metrics)``: the whole search
  as one pure function -- ``lax.scan`` over ``algorithm.iterations`` iterations, then the
  algorithm's ``finish`` (e.g. a final polish of the best policy) -- returning the policy
  ``cognet-jax train --seed s`` returns for ``key = seed_key(config, s)``. ``jax.vmap`` over
  keys runs many seeds, over ``params`` many noise levels or ``alpha`` values, in one program.
* ``make_evaluate(config) -> evaluate(key, policy, params=None) -> (mean, stderr)``: the
  honest value of a policy from the seed key's evaluation key, which the search never uses.

Key layout for a seed: ``key -> (init_key, run_key, eval_key)`` (``split_seed_key``);
iteration i uses ``fold_in(run_key, i)`` with i read from the state (``iteration_step``), so a
resumed run continues the same random stream; ``eval_key`` is reserved for the honest final
evaluation (``final_returns``). The command line (``cognet_jax.driver``) runs these same
functions.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from cognet_jax.algorithms.engine import SearchParams
from cognet_jax.budget import check_budget
from cognet_jax.config import (
    INT32_MAX,
    Config,
    ConfigError,
    ExperimentSection,
    NetworkSection,
    ProblemSection,
    section_from_dict,
)
from cognet_jax.envs.base import check_simulator
from cognet_jax.errors import UsageError
from cognet_jax.memory import budget_bytes
from cognet_jax.prng import impl_of, make_key
from cognet_jax.registry import (
    algorithm_entry,
    build_env,
    config_from_dict,
    env_entry,
    is_builtin,
    validate,
)
from cognet_jax.rollout import mean_and_stderr


def params_of(config: Config, env_params=None) -> SearchParams:
    """The ``SearchParams`` of ``config``: its simulator's params (``env_params`` when given)
    and its algorithm's hyper-parameters (the registry entry's ``hyper``)."""
    if env_params is None:
        _, env_params = build_env(config)
    return SearchParams(
        env=env_params, hyper=algorithm_entry(config.experiment.algorithm).hyper(config)
    )


@dataclasses.dataclass(frozen=True)
class Built:
    """Everything a run of ``config`` is made of, built once (``build``): the simulator and its
    params, the search and its ``SearchParams``, and ``seconds``, the run's time at least
    (its agent-steps at ``budget.FASTEST_RATE``, ``check_budget``)."""

    config: Config
    env: Any
    env_params: Any
    algorithm: Any
    params: SearchParams
    seconds: float


def build(config: Config, env=None, env_params=None, lanes: int = 1) -> Built:
    """Build a run of ``config`` and make every admission check once: the simulator
    (``build_env``, or the ``env`` object given) traced once (``check_simulator``), the
    run's time and memory (``check_budget``), the search built by its registry entry. The
    memory budget ``run.memory_gb`` is shared by ``lanes`` searches run side by side (a
    sweep's runs). ``train``, ``sweep``, ``check``, ``evaluate`` and ``make_train`` all start
    here."""
    if env is None:
        env, env_params = build_env(config)
    check_simulator(env, env_params, config.env.name, values=not _builtin_env(config))
    seconds = check_budget(config, env)
    entry = algorithm_entry(config.experiment.algorithm)
    memory = budget_bytes(config.run.memory_gb) // max(lanes, 1)
    algorithm = entry.build(config, env, env_params, memory)
    _check_search(algorithm, config.experiment.algorithm, entry.build)
    _check_rollout_count(algorithm, config, env)
    return Built(config, env, env_params, algorithm, params_of(config, env_params), seconds)


#: what the driver calls on every search (``algorithms.engine``'s protocol; ``Search`` has
#: ``step``, ``returns`` and the hooks)
SEARCH_MEMBERS = ("init", "step", "best_policy", "returns", "rollouts_per_iteration")


def _check_search(algorithm, name: str, build_fn) -> None:
    """Refuse, naming the registration's code, a ``build`` that returned no search."""
    missing = [m for m in SEARCH_MEMBERS if not hasattr(algorithm, m)]
    if missing:
        where = f"{getattr(build_fn, '__module__', '?')}.{getattr(build_fn, '__qualname__', '?')}"
        raise UsageError(
            f"algorithm {name!r}: its build ({where}) returned {type(algorithm).__name__}, "
            f"not a search (missing {', '.join(missing)}; see cognet_jax.algorithms.engine)"
        )


#: a run's agent-steps (iterations x rollouts per iteration x horizon x agents) stay below this:
#: results.json and the sweep's tables hold them as 64-bit integers
MAX_AGENT_STEPS = 2**63 - 1


def _check_rollout_count(algorithm, config: Config, env) -> None:
    """Refuse, before anything runs, a search whose ``rollouts_per_iteration`` is not a count,
    or makes the run's agent-steps pass ``MAX_AGENT_STEPS`` (they were refused only after the
    search, when its results were written)."""
    rollouts, name = algorithm.rollouts_per_iteration, type(algorithm).__name__
    if isinstance(rollouts, bool) or not isinstance(rollouts, int | np.integer) or rollouts < 0:
        raise UsageError(
            f"{name}.rollouts_per_iteration (the search's code) is {rollouts!r}: expected a "
            "count of rollouts, an integer >= 0"
        )
    iterations = config.algorithm.iterations
    steps = iterations * int(rollouts) * int(env.horizon) * int(env.num_agents)
    if steps > MAX_AGENT_STEPS:
        raise UsageError(
            f"{name}.rollouts_per_iteration (the search's code) is {int(rollouts):.3g}: with "
            f"{iterations} iterations of horizon {env.horizon} and {env.num_agents} agents, "
            f"{steps:.3g} agent-steps, past 64-bit integers (no machine simulates them)"
        )


def build_algorithm(config: Config, env=None, env_params=None, lanes: int = 1):
    """``(algorithm, params)`` of ``build`` (the search and its ``SearchParams``)."""
    built = build(config, env, env_params, lanes)
    return built.algorithm, built.params


def _builtin_env(config: Config) -> bool:
    """Whether ``config`` names the package's own simulator (not a user's object, as
    ``make_algorithm`` passes, nor a registration from outside the package)."""
    try:
        return is_builtin(env_entry(config.env.name))
    except ConfigError:  # an object without a registered name
        return False


def make_env(name: str, algorithm: str = "cognet-dice", **settings):
    """``(env, env_params)`` of simulator ``name`` with ``settings`` (fields of its ``[env]``
    section; for a simulator that reads ``[problem]`` also its fields: ``path``, ``horizon``,
    ``discount``), validated as a config file is, for the search ``algorithm`` (e.g.
    ``"gdice"`` makes tagging with ``obs_division > 0`` return observation indices)."""
    entry = env_entry(name)
    env_fields = {f.name for f in dataclasses.fields(entry.section)} - {"name"}
    problem_fields = {f.name for f in dataclasses.fields(ProblemSection)}
    reads_problem = "problem" in entry.reads
    data: dict = {"experiment": {"algorithm": algorithm}, "env": {"name": name}, "problem": {}}
    for key, value in settings.items():
        if key in env_fields:
            data["env"][key] = value
        elif reads_problem and key in problem_fields:
            data["problem"][key] = value
        else:
            known = sorted(env_fields | (problem_fields if reads_problem else set()))
            raise ConfigError(f"env.{key}", f"unknown setting of {name!r} (known: {known})")
    return build_env(config_from_dict(data))


@dataclasses.dataclass
class ExternalEnvSection:
    """The ``[env]`` of a config whose simulator is passed as an object (``make_algorithm``)."""

    name: str = "external"


def make_algorithm(name: str, env, env_params, network: dict | None = None, **settings):
    """``(algorithm, params)``: the search ``name`` on a simulator object ``env`` (any
    ``envs.base.Environment``, e.g. your own) with ``settings`` (fields of its ``[algorithm]``
    section) and ``network`` (fields of ``[network]``), validated as a config file is."""
    entry = algorithm_entry(name)
    config = Config(
        experiment=ExperimentSection(name=name, algorithm=name),
        env=ExternalEnvSection(),
        algorithm=section_from_dict(entry.section, settings, "algorithm"),
        network=section_from_dict(NetworkSection, network or {}, "network"),
    )
    validate(config, env_reads=())
    return build_algorithm(config, env, env_params)


def seed_key(config: Config, seed: int) -> jax.Array:
    """The key of seed ``seed`` (``run.prng_impl``'s generator): what ``train --seed`` uses.
    Seeds are 0 .. 2^31 - 1 (others would wrap onto these: -1 is 2^32 - 1, 2^32 is 0)."""
    if not 0 <= seed <= INT32_MAX:
        raise ConfigError("seed", f"must be in 0 .. {INT32_MAX}, got {seed}")
    return make_key(seed, config.run.prng_impl)


def seed_keys(configs: list[Config], seeds: list[int]) -> jax.Array:
    """``[runs]`` keys: ``seed_key(configs[r], seeds[r])`` for every run, made in one call per
    PRNG implementation (a sweep of 100,000 seeds makes its keys in milliseconds, not a
    JAX call per seed). The same keys, bit for bit."""
    for seed in (min(seeds), max(seeds)):
        if not 0 <= seed <= INT32_MAX:
            raise ConfigError("seed", f"must be in 0 .. {INT32_MAX}, got {seed}")
    impls = [c.run.prng_impl for c in configs]
    if len(set(impls)) > 1:  # runs of several generators: one at a time
        return jnp.stack([seed_key(c, s) for c, s in zip(configs, seeds)])
    impl = impl_of(impls[0])
    make = jax.jit(jax.vmap(lambda s: jax.random.key(s, impl=impl)))
    return make(jnp.asarray(seeds, jnp.int32))


def split_seed_key(key: jax.Array):
    """``key -> (init_key, run_key, eval_key)``."""
    k_init, k_run, k_eval = jax.random.split(key, 3)
    return k_init, k_run, k_eval


def iteration_step(algorithm):
    """``step(run_key, state, params) -> (state, metrics)``: one iteration of ``algorithm``
    with the key ``fold_in(run_key, i)``, i read from the state (so a resumed run continues the
    same random stream). What ``make_train``, the driver and the sweeps all run."""

    def step(run_key, state, params):
        key = jax.random.fold_in(run_key, state.progress.iteration)
        return algorithm.step(key, state, params)

    return step


def final_returns(algorithm, evaluation):
    """``returns(key, policy, params) -> [evaluation.rollouts]``: the returns of the honest
    evaluation of ``policy``, drawn from the seed key ``key``'s evaluation key (never used by
    the search); ``evaluation`` is the config's ``[evaluation]`` section. The one honest
    evaluation: ``make_evaluate``, ``cognet-jax train``, ``sweep`` and ``evaluate`` run it."""

    def returns(key, policy, params):
        _, _, k_eval = split_seed_key(key)
        return algorithm.returns(k_eval, policy, evaluation.rollouts, params, evaluation.batch)

    return returns


def make_step(config: Config):
    """``(algorithm, params, step)``: the search of ``config``, its params and
    ``step(run_key, state, params)`` (``iteration_step``); ``algorithm.init(init_key, params)``
    starts it."""
    algorithm, params = build_algorithm(config)
    return algorithm, params, iteration_step(algorithm)


def search_program(algorithm, iterations: int):
    """``run(key, params) -> (final_state, metrics)``: the whole search of ``algorithm`` from
    a seed key -- ``init``, ``iterations`` steps (``lax.scan``), ``finish``. Pure."""
    step = iteration_step(algorithm)

    def run(key, params):
        k_init, k_run, _ = split_seed_key(key)
        state = algorithm.init(k_init, params)
        state, metrics = jax.lax.scan(
            lambda s, _: step(k_run, s, params), state, None, length=iterations
        )
        state, _ = algorithm.finish(state, params)
        return state, metrics

    return run


def _built(config: Config | Built) -> Built:
    """``config`` as a ``Built`` run: built here from a ``Config``, taken as it is otherwise
    (so a caller that built once passes what it built)."""
    return config if isinstance(config, Built) else build(config)


def make_train(config: Config | Built):
    """A pure ``train(key, params=None) -> (final_state, metrics)`` running
    ``algorithm.iterations`` iterations and then the algorithm's ``finish``, so
    ``algorithm.best_policy(final_state)`` is the policy ``cognet-jax train --seed s`` writes
    for ``key = seed_key(config, s)``; metrics leaves have a leading ``[iterations]`` axis.

    ``params``: a ``SearchParams`` like ``build_algorithm(config)[1]`` (``None``: that one, as
    constants of the program, as the command line runs it), e.g. with another ``alpha`` or
    noise level, so ``jax.vmap(train, in_axes=(None, 0))(key, stacked_params)`` searches with
    many settings in one program. ``make_evaluate(config)`` gives the honest value.
    ``config`` may be the ``Built`` run of ``build(config)`` (nothing is built again)."""
    built = _built(config)
    algorithm, default = built.algorithm, built.params
    run = search_program(algorithm, built.config.algorithm.iterations)

    def train(key, params=None):
        return run(key, default if params is None else params)

    return train


def make_evaluate(config: Config | Built):
    """A pure ``evaluate(key, policy, params=None) -> (mean, stderr)``: the honest value of
    ``policy``, the mean return of ``evaluation.rollouts`` fresh rollouts drawn from the seed
    key's evaluation key (``final_returns``), which the search never uses. ``results.json``'s
    ``final_value`` sums the same returns in float64; this float32 mean agrees with it to
    float32 rounding. ``config`` may be the ``Built`` run of ``build(config)``."""
    built = _built(config)
    algorithm, default = built.algorithm, built.params
    returns = final_returns(algorithm, built.config.evaluation)

    def evaluate(key, policy, params=None):
        return mean_and_stderr(returns(key, policy, default if params is None else params))

    return evaluate


__all__ = [
    "Built",
    "SearchParams",
    "build",
    "build_algorithm",
    "build_env",
    "final_returns",
    "iteration_step",
    "make_algorithm",
    "make_env",
    "make_evaluate",
    "make_step",
    "make_train",
    "params_of",
    "search_program",
    "seed_key",
    "split_seed_key",
]
