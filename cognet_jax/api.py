"""Public entry points: build an environment and algorithm from a ``Config`` and get pure
functions to run it.

* ``make_step(config) -> (algorithm, init, step)`` with ``init(key) -> state`` and
  ``step(run_key, state) -> (state, metrics)``; iteration i uses ``fold_in(run_key, i)`` where i is
  read from the state, so a resumed run continues the same random stream.
* ``make_train(config) -> train(key)``: the whole search as one pure function (``lax.scan`` over
  iterations) returning ``(final_state, metrics per iteration)``; ``jax.jit(jax.vmap(train))``
  runs many seeds at once.

Key layout for a seed: ``key -> (init_key, run_key, eval_key)``; ``eval_key`` is reserved for the
honest final evaluation and never touches the search.
"""

from __future__ import annotations

import dataclasses

import jax

from cognet_jax.config import (
    CogDiceAlgorithmSection,
    CognetAlgorithmSection,
    CognetWeightsAlgorithmSection,
    Config,
    DpomdpEnvSection,
    GDiceAlgorithmSection,
    HeatmapEnvSection,
    TaggingEnvSection,
)


def build_env(config: Config):
    """The environment and its params pytree described by ``config.env`` / ``config.problem``."""
    e = config.env
    if isinstance(e, TaggingEnvSection):
        from cognet_jax.envs.tagging import make_tagging

        overrides = dict(motion_noise=e.motion_noise, obs_noise=e.obs_noise)
        if e.discount is not None:
            overrides["discount"] = e.discount
        if e.respawn is not None:
            overrides["respawn"] = e.respawn
        # G-DICE's tabular controllers read the discretised observation as an index
        obs_index = isinstance(config.algorithm, GDiceAlgorithmSection) and e.obs_division > 0
        return make_tagging(
            e.setting,
            horizon=e.horizon,
            obs_division=e.obs_division,
            obs_index=obs_index,
            **overrides,
        )
    if isinstance(e, HeatmapEnvSection):
        from cognet_jax.envs.heatmap import make_heatmap

        return make_heatmap(
            e.start,
            horizon=e.horizon,
            discount=e.discount,
            obs_noise_amplitude=e.obs_noise_amplitude,
            obs_noise_mean=e.obs_noise_mean,
            obs_noise_std=e.obs_noise_std,
            obs_signal=e.obs_signal,
            near_reward=e.near_reward,
            mid_reward=e.mid_reward,
            far_reward=e.far_reward,
        )
    if isinstance(e, DpomdpEnvSection):
        from cognet_jax.envs.tabular import make_tabular

        return make_tabular(load_problem(config), config.problem.horizon, config.problem.discount)
    raise NotImplementedError(f"environment {e.name!r} is not available yet")


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
    if env is None:
        env, env_params = build_env(config)
    a = config.algorithm
    if isinstance(a, CognetWeightsAlgorithmSection):
        from cognet_jax.algorithms.cognet_weights import (
            CognetWeights,
            WeightsHyper,
            WeightsSettings,
        )

        settings = WeightsSettings(
            nodes=a.nodes,
            iterations=a.iterations,
            candidates=a.candidates,
            eval_rollouts=a.eval_rollouts,
            elites=a.elites,
            hidden=config.network.hidden,
            best_rollouts=a.best_rollouts,
            common_random_numbers=a.common_random_numbers,
            init_scale=a.init_scale,
            vote_mean=a.vote_mean,
            vote_std=a.vote_std,
            standardize_inputs=a.standardize_inputs,
            paired_best=a.paired_best,
        )
        hyper = WeightsHyper(
            alpha=a.alpha, action_floor=a.action_floor, category_floor=a.category_floor
        )
        return CognetWeights(env, env_params, settings, hyper, build_pipeline(config, env))
    if isinstance(a, CognetAlgorithmSection):
        from cognet_jax.algorithms.cognet_dice import CognetDice, CognetHyper, CognetSettings
        from cognet_jax.algorithms.cross_entropy import EntropyConfig

        net = config.network
        settings = CognetSettings(
            nodes=a.nodes,
            iterations=a.iterations,
            rollouts=a.rollouts,
            top=a.top,
            keep=a.keep,
            eval_rollouts=a.eval_rollouts,
            hidden=net.hidden,
            train_steps=net.train_steps,
            optimizer=net.optimizer,
            momentum=net.momentum,
            threshold_rule=a.threshold_rule,
            separate=a.separate,
            common_random_numbers=a.common_random_numbers,
            train_last_transition=a.train_last_transition,
            train_on=a.train_on,
            best_rollouts=a.best_rollouts,
            entropy_window=a.entropy_window,
        )
        hyper = CognetHyper(
            alpha=a.alpha,
            learning_rate=net.learning_rate,
            entropy=EntropyConfig(
                enabled=a.entropy_injection,
                rate=a.entropy_rate,
                std_threshold=a.entropy_std,
                patience=a.entropy_patience,
            ),
        )
        return CognetDice(env, env_params, settings, hyper, build_pipeline(config, env))
    if isinstance(a, GDiceAlgorithmSection):
        from cognet_jax.algorithms.cross_entropy import EntropyConfig
        from cognet_jax.algorithms.gdice import GDice, GDiceHyper, GDicePortfolio, GDiceSettings

        evaluator = a.evaluator
        if evaluator == "auto":
            cost = exact_iteration_cost(env, a, env_params)
            hybrid_cost = cost * min(a.exact_top, a.samples) // a.samples
            evaluator = (
                "exact"
                if cost <= EXACT_AUTO_LIMIT
                else "hybrid"
                if hybrid_cost <= EXACT_AUTO_LIMIT
                else "rollouts"
            )
        settings = GDiceSettings(
            nodes=a.nodes,
            iterations=a.iterations,
            samples=a.samples,
            elites=a.elites,
            eval_rollouts=a.eval_rollouts,
            common_random_numbers=a.common_random_numbers,
            entropy_window=a.entropy_window,
            best_rollouts=a.best_rollouts,
            evaluator=evaluator,
            exact_top=a.exact_top,
            shared_controller=a.shared_controller,
            layered=a.layered,
            restarts=a.restarts,
            polish_sweeps=a.polish_sweeps,
        )
        if evaluator in ("exact", "hybrid"):
            _check_exact_cost(env, a, env_params, evaluator)
        if settings.polish_sweeps and evaluator in ("exact", "hybrid"):
            from cognet_jax.exact_jax import exact_cost

            moves = len(GDice(env, env_params, settings).polish_moves())
            if moves * exact_cost(env, a.nodes, env_params) > POLISH_SWEEP_LIMIT:
                # too costly for this model: no polish (results.json's "resolved" shows it)
                settings = dataclasses.replace(settings, polish_sweeps=0)
        hyper = GDiceHyper(
            alpha=a.alpha,
            entropy=EntropyConfig(
                enabled=a.entropy_injection,
                rate=a.entropy_rate,
                std_threshold=a.entropy_std,
                patience=a.entropy_patience,
            ),
        )
        if a.restarts > 1 or a.shared_restarts > 0 or a.explore_restarts > 0:
            return GDicePortfolio(
                env,
                env_params,
                settings,
                hyper,
                a.shared_restarts,
                a.explore_restarts,
                a.explore_entropy_rate,
            )
        return GDice(env, env_params, settings, hyper)
    if isinstance(a, CogDiceAlgorithmSection):
        from cognet_jax.algorithms.cogdice import CogDice, CogDiceHyper, CogDiceSettings
        from cognet_jax.algorithms.cross_entropy import EntropyConfig

        settings = CogDiceSettings(
            nodes=a.nodes,
            regions=a.regions,
            iterations=a.iterations,
            samples=a.samples,
            elites=a.elites,
            eval_rollouts=a.eval_rollouts,
            common_random_numbers=a.common_random_numbers,
            entropy_window=a.entropy_window,
            best_rollouts=a.best_rollouts,
            beta_eps=a.beta_eps,
            min_denominator=a.min_denominator,
        )
        hyper = CogDiceHyper(
            alpha=a.alpha,
            entropy=EntropyConfig(
                enabled=a.entropy_injection,
                rate=a.entropy_rate,
                std_threshold=a.entropy_std,
                patience=a.entropy_patience,
            ),
        )
        return CogDice(env, env_params, settings, hyper)
    raise NotImplementedError(f"algorithm {config.experiment.algorithm!r} is not available yet")


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


def exact_iteration_cost(env, a, env_params=None) -> int:
    """Multiply-adds of exact values for one iteration's samples (all restarts)."""
    from cognet_jax.exact_jax import exact_cost

    # a layered controller's recursion runs over one layer (``nodes`` per agent) per step
    searches = a.restarts + a.shared_restarts + a.explore_restarts
    return exact_cost(env, a.nodes, env_params) * a.samples * searches


def _check_exact_cost(env, a, env_params=None, evaluator: str = "exact") -> None:
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


def make_step(config: Config):
    """``(algorithm, init, step)``: ``init(init_key)``; ``step(run_key, state)``."""
    algorithm = build_algorithm(config)

    def step(run_key, state):
        return algorithm.step(jax.random.fold_in(run_key, state.progress.iteration), state)

    return algorithm, algorithm.init, step


def make_train(config: Config):
    """A pure ``train(key) -> (final_state, metrics)`` running ``algorithm.iterations``
    iterations; metrics leaves have a leading ``[iterations]`` axis."""
    algorithm, init, step = make_step(config)
    iterations = config.algorithm.iterations

    def train(key):
        k_init, k_run, _ = split_seed_key(key)
        state = init(k_init)
        return jax.lax.scan(lambda s, _: step(k_run, s), state, None, length=iterations)

    return train
