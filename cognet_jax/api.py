"""Public entry points: build an environment and algorithm from a ``Config`` and get pure
functions to run it.

* ``make_step(config) -> (algorithm, init, step)`` with ``init(key) -> state`` and
  ``step(run_key, state) -> (state, metrics)``; iteration i uses ``fold_in(run_key, i)`` where i is
  read from the state, so a resumed run continues the same random stream.
* ``make_train(config) -> train(key, hyper=None)``: the whole search as one pure function
  (``lax.scan`` over iterations) returning ``(final_state, metrics per iteration)``;
  ``jax.jit(jax.vmap(train))`` runs many seeds at once, ``vmap`` over ``hyper`` many settings.
* ``make_evaluate(config) -> evaluate(key, policy)``: the honest value (mean, standard error).

Key layout for a seed: ``key -> (init_key, run_key, eval_key)``; ``eval_key`` is reserved for the
honest final evaluation and never touches the search.
"""

from __future__ import annotations

import jax

from cognet_jax.config import Config


def build_env(config: Config):
    """The environment and its params pytree described by ``config.env`` (and, for a tabular
    problem, ``config.problem``), built by the simulator's registry entry."""
    from cognet_jax.registry import env_entry

    return env_entry(config.env.name).build(config.env, config)


#: the last parsed model, keyed by (resolved path, mtime, size, discount): a run builds the
#: env, the exact evaluation and the plots' names from one parse
_PARSED: dict = {}
#: files larger than this get a "parsing ..." line on stderr
PARSE_PROGRESS_BYTES = 1_000_000


def load_problem(config: Config):
    """The parsed ``TabularModel`` of ``config.problem.path`` (ConfigError if unreadable);
    parsed once per file version and discount, then reused."""
    import sys
    import time
    from pathlib import Path

    from cognet_jax.config import ConfigError
    from cognet_jax.io.dpomdp import parse_dpomdp

    path = Path(config.problem.path).expanduser()
    if not path.is_file():
        raise ConfigError("problem.path", f"no such file: {config.problem.path}")
    st = path.stat()
    key = (str(path.resolve()), st.st_mtime_ns, st.st_size, config.problem.discount)
    if key not in _PARSED:
        _PARSED.clear()
        large = st.st_size > PARSE_PROGRESS_BYTES
        if large:
            print(f"parsing {path} ({st.st_size / 1e6:.1f} MB) ...", file=sys.stderr, flush=True)
        t0 = time.perf_counter()
        _PARSED[key] = parse_dpomdp(str(path), discount=config.problem.discount)
        if large:
            print(f"parsed {path} in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    return _PARSED[key]


def build_algorithm(config: Config, env=None, env_params=None, lanes: int = 1):
    """The algorithm object (``init``/``step``/``evaluate``) for ``config``, with the memory
    budget ``run.memory_gb`` shared by ``lanes`` searches run side by side (a sweep's runs)."""
    from cognet_jax.memory import budget_bytes

    algorithm = _build_algorithm(config, env, env_params)
    algorithm.memory = budget_bytes(config.run.memory_gb) // max(lanes, 1)
    return algorithm


def _build_algorithm(config: Config, env=None, env_params=None):
    """The algorithm's registry entry builds it (``cognet_jax.registry``)."""
    from cognet_jax.registry import algorithm_entry

    if env is None:
        env, env_params = build_env(config)
    return algorithm_entry(config.experiment.algorithm).build(config, env, env_params)


def build_pipeline(config: Config, env):
    """The COGNet-DICE observation pipeline of ``config.network`` (trains or loads the VAE
    only when the encoded pipeline or augmentation needs it)."""
    from cognet_jax.observations import ObservationPipeline, resolve_vae

    net = config.network
    vae = None
    if net.observation == "encoded" or net.augment:
        vae = resolve_vae(
            net.vae_path, net.vae_seed, net.vae_epochs, net.vae_latent, net.vae_kl_weight
        )
    return ObservationPipeline(
        kind=net.observation,
        raw_shape=env.obs_shape,
        vae=vae,
        augment_samples=net.augment_samples if net.augment else 0,
    )


#: Largest exact evaluation one G-DICE iteration may do (multiply-adds over all samples).
EXACT_EVALUATOR_LIMIT = 2_000_000_000
#: ``evaluator = "auto"`` ranks samples exactly up to this many multiply-adds per iteration
#: (about 0.1-0.3 s on two cores), by rollouts above it.
EXACT_AUTO_LIMIT = 300_000_000


#: Largest exact cost of one polish sweep (every single-entry change of the best controller,
#: ``GDice.polish_moves``); above it the polish is skipped.
POLISH_SWEEP_LIMIT = 3_000_000_000
#: Largest working set (float32 numbers) of one agent's best response in the polish
#: (``algorithms.best_response.best_response_cost``); above it, or above
#: ``POLISH_SWEEP_LIMIT`` multiply-adds, the best responses are skipped.
BEST_RESPONSE_FLOATS = 1 << 25


def exact_iteration_cost(env, a, env_params=None) -> int:
    """Multiply-adds of exact values for one iteration's samples (all restarts)."""
    from cognet_jax.exact_jax import exact_cost

    # a layered controller's recursion runs over one layer (``nodes`` per agent) per step
    searches = a.restarts + a.shared_restarts + a.explore_restarts
    return exact_cost(env, a.nodes, env_params) * a.samples * searches


def check_exact_cost(env, a, env_params=None, evaluator: str = "exact") -> None:
    """``ConfigError`` on ``algorithm.evaluator`` when exact values would cost more than
    ``EXACT_EVALUATOR_LIMIT`` per iteration."""
    from cognet_jax.config import ConfigError

    cost = exact_iteration_cost(env, a, env_params)
    if evaluator == "hybrid":
        cost = cost * min(a.exact_top, a.samples) // a.samples
    if cost > EXACT_EVALUATOR_LIMIT:
        raise ConfigError(
            "algorithm.evaluator",
            f"{evaluator!r} would need {cost:.2e} multiply-adds per iteration (nodes^agents * S "
            f"* (S + joint observations) * horizon * samples * searches > "
            f"{EXACT_EVALUATOR_LIMIT:.0e}); use "
            "'rollouts' or fewer nodes/samples"
            + (" or exact_top" if evaluator == "hybrid" else ""),
        )


def seed_key(config: Config, seed: int) -> jax.Array:
    from cognet_jax.prng import make_key

    return make_key(seed, config.run.prng_impl)


def split_seed_key(key: jax.Array):
    """``key -> (init_key, run_key, eval_key)``."""
    k_init, k_run, k_eval = jax.random.split(key, 3)
    return k_init, k_run, k_eval


def iteration_step(algorithm):
    """``step(run_key, state, hyper=None) -> (state, metrics)``: one iteration of
    ``algorithm`` with the key ``fold_in(run_key, i)``, i read from the state (so a resumed run
    continues the same random stream). What ``make_step``, ``make_train``, the runner and the
    sweeps all run."""

    def step(run_key, state, hyper=None):
        key = jax.random.fold_in(run_key, state.progress.iteration)
        if hyper is None:
            return algorithm.step(key, state)
        return algorithm.step(key, state, hyper)

    return step


def honest_returns(algorithm, evaluation):
    """``returns(key, policy) -> [evaluation.rollouts]``: the returns of the honest evaluation
    of ``policy``, drawn from the seed key ``key``'s evaluation key (never used by the
    search); ``evaluation`` is the config's ``[evaluation]`` section."""

    def returns(key, policy):
        _, _, k_eval = split_seed_key(key)
        return algorithm.policy_returns(k_eval, policy, evaluation.rollouts, evaluation.batch)

    return returns


def make_step(config: Config):
    """``(algorithm, init, step)``: ``init(init_key)``; ``step(run_key, state, hyper=None)``
    (``iteration_step``; ``hyper``: the algorithm's dynamic hyper-parameters, default
    ``algorithm.hyper``)."""
    algorithm = build_algorithm(config)
    return algorithm, algorithm.init, iteration_step(algorithm)


def make_train(config: Config):
    """A pure ``train(key, hyper=None) -> (final_state, metrics)`` running
    ``algorithm.iterations`` iterations; metrics leaves have a leading ``[iterations]`` axis.

    ``key`` is a seed key (``seed_key(config, seed)`` gives the CLI's); ``hyper`` the dynamic
    hyper-parameters (a pytree like ``build_algorithm(config).hyper``, e.g. with another
    ``alpha``), so ``jax.vmap(train, in_axes=(None, 0))(key, stacked_hypers)`` searches with
    many settings in one program. ``make_evaluate(config)`` gives the honest value."""
    algorithm, init, step = make_step(config)
    iterations = config.algorithm.iterations

    def train(key, hyper=None):
        k_init, k_run, _ = split_seed_key(key)
        state = init(k_init)
        return jax.lax.scan(lambda s, _: step(k_run, s, hyper), state, None, length=iterations)

    return train


def make_evaluate(config: Config):
    """A pure ``evaluate(key, policy) -> (mean, stderr)``: the honest value of ``policy``, the
    mean return of ``evaluation.rollouts`` fresh rollouts drawn from the seed key's evaluation
    key, which the search never uses -- what ``cognet-jax train`` reports for the seed (up to
    float summation order)."""
    from cognet_jax.rollout import mean_and_stderr

    returns = honest_returns(build_algorithm(config), config.evaluation)

    def evaluate(key, policy):
        return mean_and_stderr(returns(key, policy))

    return evaluate
