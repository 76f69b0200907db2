"""The sized G-DICE defaults (``gdice-dpomdp``): time-layered controllers, their exact values,
sparse transition rows, and the portfolio of independent and shared searches."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from shared_files import dpomdp_file as _file

from cognet_jax.algorithms.engine import SearchParams, ThresholdHyper, streams
from cognet_jax.algorithms.gdice_portfolio import GDicePortfolio
from cognet_jax.algorithms.gdice_search import GDice, GDiceSettings
from cognet_jax.controllers.tabular import TabularController
from cognet_jax.envs.tabular import make_tabular, sparse_rows
from cognet_jax.exact import exact_value as exact_numpy
from cognet_jax.exact_jax import exact_value, exact_value_layered
from cognet_jax.io.dpomdp import parse_dpomdp


def test_layered_support_allows_only_the_next_layer():
    ctrl = TabularController(2, 6, 3, 2, layers=3)
    support = np.asarray(ctrl.transition_support())[:, 0, :]
    assert ctrl.layer_width == 2
    for q in range(6):
        target = min(q // 2 + 1, 2)
        assert support[q].tolist() == [n // 2 == target for n in range(6)]
    dist = ctrl.init_distribution()
    probs = np.asarray(dist.transition_probs)
    np.testing.assert_allclose(probs.sum(-1), 1.0, rtol=1e-6)
    outside = np.broadcast_to(~support[None, :, None, :], probs.shape)
    assert np.all(probs[outside] == 0)
    # every sampled controller stays layered
    pol = jax.vmap(lambda k: ctrl.sample(k, dist))(jax.random.split(jax.random.key(0), 64))
    nxt = np.asarray(pol.transitions)  # [64, agents, nodes, obs]
    layer_of_next = nxt // 2
    expected = np.minimum(np.arange(6) // 2 + 1, 2)[None, None, :, None]
    assert np.all(layer_of_next == expected)


@pytest.mark.parametrize(
    "name,horizon",
    # every branch of exact_value_layered: h 1, below 4, 4 and beyond (sparse observation rows
    # on GridSmall, full rows on Dec-Tiger)
    [("dectiger", 1), ("dectiger", 2), ("dectiger", 4), ("GridSmall", 3), ("GridSmall", 5)],
)
def test_layered_exact_equals_generic_exact_and_numpy(name, horizon):
    model = parse_dpomdp(_file(name), discount=1.0)
    env, params = make_tabular(model, horizon)
    width = 2
    ctrl = TabularController(
        env.num_agents, width * horizon, env.num_actions, env.num_obs, layers=horizon
    )
    dist = ctrl.init_distribution()
    pols = jax.jit(jax.vmap(lambda k: ctrl.sample(k, dist)))(
        jax.random.split(jax.random.key(3), 16)
    )
    layered = jax.jit(jax.vmap(lambda p: exact_value_layered(env, params, p, width)))(pols)
    generic = jax.jit(jax.vmap(lambda p: exact_value(env, params, p, width * horizon)))(pols)
    ref = [
        exact_numpy(model, np.asarray(a), np.asarray(t), horizon, 1.0)
        for a, t in zip(pols.actions, pols.transitions)
    ]
    np.testing.assert_allclose(layered, generic, rtol=1e-5, atol=1e-4)
    np.testing.assert_allclose(layered, ref, rtol=1e-5, atol=1e-4)


def test_sparse_rows_exact_equals_dense():
    rng = np.random.default_rng(0)
    S, JA, JO = 12, 4, 4
    T = np.zeros((S, JA, S))
    for s in range(S):
        for a in range(JA):
            cols = rng.choice(S, size=3, replace=False)
            T[s, a, cols] = rng.dirichlet(np.ones(3))
    idx, probs = sparse_rows(T)
    assert idx.shape == (S, JA, 3)
    dense = np.zeros_like(T)
    np.put_along_axis(dense, np.asarray(idx), np.asarray(probs), -1)
    np.testing.assert_allclose(dense, T, rtol=1e-6)
    assert sparse_rows(np.full((4, 2, 4), 0.25)) == (None, None)  # dense: no lists

    from cognet_jax.envs.tabular import TabularEnv, TabularParams

    env = TabularEnv(2, S, (2, 2), (2, 2), horizon=3)
    obs = rng.dirichlet(np.ones(JO), size=(JA, S))
    base = dict(
        transition=jnp.asarray(T, jnp.float32),
        observation=jnp.asarray(obs, jnp.float32),
        reward=jnp.asarray(rng.normal(size=(S, JA)), jnp.float32),
        initial_belief=jnp.full(S, 1 / S, jnp.float32),
    )
    p_dense = TabularParams(**base)
    p_sparse = TabularParams(**base, successors=idx, successor_probs=probs)
    ctrl = TabularController(2, 3, 2, 2)
    pols = jax.vmap(lambda k: ctrl.sample(k, ctrl.init_distribution()))(
        jax.random.split(jax.random.key(1), 8)
    )
    a = jax.jit(jax.vmap(lambda p: exact_value(env, p_dense, p, 3)))(pols)
    b = jax.jit(jax.vmap(lambda p: exact_value(env, p_sparse, p, 3)))(pols)
    np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-5)


def _portfolio(path, horizon, **kw):
    model = parse_dpomdp(path, discount=1.0)
    env, env_params = make_tabular(model, horizon)
    settings = GDiceSettings(
        nodes=2, iterations=5, samples=64, elites=8, evaluator="exact", layered=True, **kw
    )
    return env, SearchParams(env_params, ThresholdHyper()), settings


def test_portfolio_keeps_the_best_member_and_is_anytime():
    env, params, settings = _portfolio(_file("dectiger"), 3, restarts=2)
    algo = GDicePortfolio(env, settings, shared_restarts=1)
    assert algo.restarts == (2, 1) and algo.members[1].settings.shared_controller
    state = algo.init(jax.random.key(0), params)
    step = jax.jit(algo.step)
    for i in range(4):
        state, metrics = step(jax.random.key(i), state, params)
        member_best = max(float(m.progress.in_loop_best.max()) for m in state.members)
        assert float(metrics.in_loop_best) == pytest.approx(member_best)
    best = jax.device_get(state.best_policy)
    value = float(exact_value_layered(env, params.env, best, settings.nodes))
    assert value == pytest.approx(float(state.progress.in_loop_best), abs=1e-4)


def test_portfolio_skips_shared_search_for_different_agents(tmp_path):
    path = tmp_path / "asym.dpomdp"
    path.write_text(
        "agents: 2\ndiscount: 1\nvalues: reward\nstates: 1\nstart:\nuniform\n"
        "actions:\n2\n3\nobservations:\n1\n1\n"
        "T: * :\nuniform\nO: * :\nuniform\nR: 1 2 : * : * : * : 1\n"
    )
    env, params, settings = _portfolio(path, 2)
    algo = GDicePortfolio(env, settings, shared_restarts=1)
    assert len(algo.members) == 1  # no shared search: the agents differ
    state, _ = jax.jit(algo.step)(jax.random.key(0), algo.init(jax.random.key(1), params), params)
    assert float(state.progress.in_loop_best) == pytest.approx(2.0)  # (1, 2) twice


@pytest.mark.optimised
def test_default_gdice_reaches_dectiger_h4_optimum():
    """``gdice-dpomdp`` as shipped, with fewer iterations: Dec-Tiger h 4 (optimum 4.802755),
    where the earlier defaults (SPEC settings, ``gdice-dpomdp-spec``) ended at -3.40."""
    from cognet_jax.api import build_algorithm, make_train
    from cognet_jax.envs.tabular import load_problem
    from cognet_jax.registry import load_config

    config = load_config(
        "gdice-dpomdp",
        [
            f"problem.path={str(_file('dectiger'))!r}",
            "problem.horizon=4",
            "algorithm.iterations=30",
        ],
    )
    algo, _ = build_algorithm(config)
    assert isinstance(algo, GDicePortfolio) and algo.settings.evaluator == "exact"
    state, _ = jax.jit(make_train(config))(jax.random.key(0))
    best = jax.device_get(state.best_policy)
    value = exact_numpy(load_problem(config.problem), best.actions, best.transitions, 4, 1.0)
    assert value == pytest.approx(4.802755, abs=1e-5)


def test_auto_evaluator_picks_hybrid_then_rollouts_for_costly_models(tmp_path):
    from cognet_jax.api import build_algorithm
    from cognet_jax.registry import load_config

    base = [
        f"problem.path={str(_file('GridSmall'))!r}",
        "problem.horizon=5",
        "algorithm.samples=100000",
        "algorithm.elites=10",
    ]
    algo, _ = build_algorithm(load_config("gdice-dpomdp", base))
    assert algo.settings.evaluator == "hybrid"  # exact for 50 of 100000 samples is cheap
    algo, _ = build_algorithm(load_config("gdice-dpomdp", [*base, "algorithm.exact_top=100000"]))
    assert algo.settings.evaluator == "rollouts"
    assert isinstance(algo.members[0], GDice)


def test_hybrid_ranks_the_best_samples_by_rollouts_with_exact_values():
    """``evaluator="hybrid"``: the ``exact_top`` best samples by rollouts get their exact
    values, the others ``-inf``; elites and the anytime best then compare exact values."""
    from cognet_jax.rollout import evaluate_candidates

    env, params, settings = _portfolio(_file("dectiger"), 3)
    settings = dataclasses.replace(settings, evaluator="hybrid", exact_top=10)
    algo = GDice(env, settings)
    state = algo.init(jax.random.key(0), params)

    @jax.jit
    def parts(state):
        pols = algo.sample_policies(jax.random.key(1), state.distribution)
        values = algo.evaluate(jax.random.key(2), pols, params)
        k_eval = streams(jax.random.key(2)).evaluate
        means = evaluate_candidates(env, algo.controller, k_eval, 100, params.env, pols)
        return values, means, algo.exact_values(pols, params)

    values, means, exact = (np.asarray(x) for x in parts(state))
    top = np.argsort(-means, kind="stable")[:10]
    assert set(np.flatnonzero(np.isfinite(values))) == set(top.tolist())
    np.testing.assert_array_equal(values[top], exact[top])
    # a step keeps an exact best value, with no fresh rollouts
    state, metrics = jax.jit(algo.step)(jax.random.key(3), state, params)
    best = jax.device_get(state.best_policy)
    value = float(exact_value_layered(env, params.env, best, settings.nodes))
    assert float(state.progress.in_loop_best) == pytest.approx(value, abs=1e-5)
    assert np.isfinite(float(metrics.mean_value))
    assert algo.rollouts_per_iteration == settings.samples * settings.eval_rollouts


def test_explore_search_leaves_the_others_unchanged_and_uses_its_rate():
    """The portfolio's explore member is a plain independent search with entropy rate
    ``explore_rate``; adding it changes no number of the other members."""
    from cognet_jax.algorithms.cross_entropy import EntropyConfig

    env, params, settings = _portfolio(_file("dectiger"), 3)
    hyper = ThresholdHyper(alpha=0.3, entropy=EntropyConfig(enabled=True, rate=0.02, patience=1))
    params = params.replace(hyper=hyper)
    plain = GDicePortfolio(env, settings, shared_restarts=1)
    both = GDicePortfolio(env, settings, None, 1, explore_restarts=1, explore_rate=0.5)
    assert both.rates == (None, None, 0.5) and len(both.members) == 3
    key = jax.random.key(4)
    s_plain, s_both = plain.init(key, params), both.init(key, params)
    alone = GDice(env, settings)
    p_alone = params.replace(hyper=hyper.replace(entropy=hyper.entropy.replace(rate=0.5)))
    s_alone = jax.vmap(alone.init, (0, None))(
        jax.random.split(jax.random.fold_in(key, 2), 1), p_alone
    )
    alone_step = jax.vmap(alone.step, (0, 0, None))

    @jax.jit
    def steps(k, s_plain, s_both, s_alone):  # one program for the three searches' steps
        keys = jax.random.split(jax.random.fold_in(k, 2), 1)
        return (
            plain.step(k, s_plain, params)[0],
            both.step(k, s_both, params)[0],
            alone_step(keys, s_alone, p_alone)[0],
        )

    for i in range(4):
        s_plain, s_both, s_alone = steps(jax.random.key(10 + i), s_plain, s_both, s_alone)
    for a, b in zip(jax.tree.leaves(s_plain.members), jax.tree.leaves(s_both.members[:2])):
        np.testing.assert_array_equal(a, b)
    for a, b in zip(jax.tree.leaves(s_alone), jax.tree.leaves(s_both.members[2])):
        np.testing.assert_array_equal(a, b)
    assert int(s_both.members[2].progress.injections.sum()) > 0  # the rate was used


def test_portfolio_is_a_pure_function_of_the_env_params():
    """The env params are an argument of every member search: a step ``vmap``-ed over two
    discounts equals the two steps run one at a time, and the discount changes the values."""
    env, params, settings = _portfolio(_file("dectiger"), 2)
    algo = GDicePortfolio(env, settings, shared_restarts=1)
    other = params.replace(env=params.env.replace(discount=jnp.float32(0.5)))
    both = jax.tree.map(lambda a, b: jnp.stack([a, b]), params, other)
    state = algo.init(jax.random.key(0), params)
    key = jax.random.key(1)
    batched, m = jax.jit(jax.vmap(algo.step, (None, None, 0)))(key, state, both)
    step = jax.jit(algo.step)
    for r, p in enumerate((params, other)):
        alone, m_alone = step(key, state, p)
        for a, b in zip(jax.tree.leaves(alone), jax.tree.leaves(batched)):
            np.testing.assert_allclose(np.asarray(a), np.asarray(b)[r], rtol=1e-6)
    assert float(m.in_loop_best[0]) != float(m.in_loop_best[1])


def test_layered_draws_read_only_the_next_layer_and_equal_full_rows():
    """A layered controller draws each next node from its next layer's ``layer_width``
    entries only; with probabilities whose sums are exact (multiples of 1/4), the draws equal
    the inverse-CDF draws over the whole rows with the same uniforms, for independent and
    shared controllers."""
    from cognet_jax.controllers.base import sample_categorical

    for shared in (False, True):
        ctrl = TabularController(2, 12, 3, 2, layers=4, shared=shared)
        support = np.asarray(ctrl.transition_support())
        weights = jax.random.randint(jax.random.key(0), (2, 12, 2, 12), 0, 4)
        probs = np.where(support, np.asarray(weights, np.float32), 0.0)
        empty = probs.sum(-1, keepdims=True) == 0
        probs = np.where(empty, support.astype(np.float32), probs) / 4.0
        dist = ctrl.init_distribution().replace(transition_probs=jnp.asarray(probs))
        keys = jax.random.split(jax.random.key(1), 500)
        drawn = jax.vmap(lambda k, c=ctrl, d=dist: c.sample(k, d).transitions)(keys)
        rows = probs[:1] if shared else probs

        def full(k, rows=rows):
            u = jax.random.uniform(jax.random.split(k)[1], rows.shape[:-1])
            return sample_categorical(u, jnp.asarray(rows))

        expected = np.broadcast_to(np.asarray(jax.vmap(full)(keys)), drawn.shape)
        np.testing.assert_array_equal(np.asarray(drawn), expected)
        assert len(np.unique(np.asarray(drawn))) > 4  # not a constant draw


def _dpomdp_config(name, horizon, *sets):
    from cognet_jax.registry import load_config

    path = f"problem.path={str(_file(name))!r}"
    return load_config("gdice-dpomdp", [path, f"problem.horizon={horizon}", *sets])


@pytest.mark.parametrize(
    "name,horizon,sets,expected",
    [
        ("dectiger", 10, (), 8),  # cheap exact values: the most repeats
        ("GridSmall", 2, (), 6),  # 6 x 3 searches x 4.8e7 multiply-adds <= 3e8
        ("GridSmall", 5, (), 2),
        ("GridSmall", 8, (), 1),
        ("dectiger", 4, ("algorithm.evaluator='hybrid'",), 1),  # not every sample exact
        ("dectiger", 4, ("algorithm.repeats=3",), 3),
    ],
)
def test_repeats_follow_the_exact_limit(name, horizon, sets, expected):
    """``repeats = "auto"`` repeats every search as often as one iteration's exact values stay
    within ``EXACT_AUTO_LIMIT`` (at most ``AUTO_REPEATS_MAX``), and the evaluator stays
    exact; results.json's ``resolved`` shows the count and every member's restarts."""
    from cognet_jax.algorithms.gdice import (
        AUTO_REPEATS_MAX,
        EXACT_AUTO_LIMIT,
        exact_iteration_cost,
    )
    from cognet_jax.api import build_algorithm, build_env

    config = _dpomdp_config(name, horizon, *sets)
    algo, _ = build_algorithm(config)
    assert algo.settings.repeats == expected
    assert algo.restarts == (expected,) * 3
    assert [s["restarts"] for s in algo.settings_record()["searches"]] == [expected] * 3
    if config.algorithm.repeats == "auto" and algo.settings.evaluator == "exact":
        env, env_params = build_env(config)
        once = exact_iteration_cost(env, config.algorithm, env_params)  # 3 searches
        assert expected * once <= EXACT_AUTO_LIMIT
        assert expected == AUTO_REPEATS_MAX or (expected + 1) * once > EXACT_AUTO_LIMIT


def test_repeats_settings_are_checked():
    from cognet_jax.config import ConfigError

    with pytest.raises(ConfigError, match="algorithm.repeats.*must be >= 1"):
        _dpomdp_config("dectiger", 3, "algorithm.repeats=0")
    with pytest.raises(ConfigError, match="algorithm.repeats.*expected int or 'auto'"):
        _dpomdp_config("dectiger", 3, "algorithm.repeats=twice")


def test_repeated_searches_include_the_unrepeated_ones():
    """With ``repeats = 2`` the first search of every kind keeps its keys, so it runs exactly
    the search of ``repeats = 1``; the repeated portfolio's best is at least as good."""
    from cognet_jax.api import build_algorithm, iteration_step

    sets = ("algorithm.iterations=4", "algorithm.samples=64", "algorithm.elites=8")
    states = []
    for repeats in (1, 2):
        config = _dpomdp_config("dectiger", 3, *sets, f"algorithm.repeats={repeats}")
        algo, params = build_algorithm(config)
        step = jax.jit(iteration_step(algo))
        state = algo.init(jax.random.key(0), params)
        for _ in range(4):
            state, _ = step(jax.random.key(1), state, params)
        states.append(state)
    once, twice = states
    for m_once, m_twice in zip(once.members, twice.members):
        first = jax.tree.map(lambda x: x[:1], m_twice)
        for a, b in zip(jax.tree.leaves(m_once), jax.tree.leaves(first)):
            np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-6, atol=1e-6)
    assert float(twice.progress.in_loop_best) >= float(once.progress.in_loop_best) - 1e-6


def test_hybrid_exact_part_sizes_from_the_model():
    """``exact_top = "auto"`` (sizes only, no arrays): the auto evaluator is hybrid where
    ``HYBRID_MIN_TOP`` samples' exact values fit ``HYBRID_EXACT_LIMIT``, rollouts where fewer
    do; an explicit hybrid whose single exact value per iteration costs more than
    ``EXACT_EVALUATOR_LIMIT`` is refused rather than run."""
    from cognet_jax.algorithms.gdice import exact_iteration_cost, resolve_evaluator
    from cognet_jax.algorithms.gdice_search import (
        EXACT_EVALUATOR_LIMIT,
        HYBRID_EXACT_LIMIT,
        HYBRID_MIN_TOP,
        GDiceSection,
    )
    from cognet_jax.config import ConfigError
    from cognet_jax.envs.tabular import TabularEnv

    def env(states):
        return TabularEnv(2, states, (5, 5), (5, 5), 5)

    section = GDiceSection(evaluator="auto", nodes=5, samples=1000, explore_restarts=1)
    sizes = {}
    for states in (100, 300, 600, 1200, 5000):
        per_sample = exact_iteration_cost(env(states), section) / section.samples
        sizes[states] = (
            HYBRID_EXACT_LIMIT // per_sample,
            resolve_evaluator(env(states), section, None),
        )
    for fits, evaluator in sizes.values():
        if evaluator == "hybrid":
            assert fits >= HYBRID_MIN_TOP
        elif evaluator == "rollouts":
            assert fits < HYBRID_MIN_TOP
    assert {e for _, e in sizes.values()} >= {"hybrid", "rollouts"}
    huge = GDiceSection(evaluator="hybrid", nodes=20, samples=1000)
    assert exact_iteration_cost(env(5000), huge) / huge.samples > EXACT_EVALUATOR_LIMIT
    with pytest.raises(ConfigError, match="algorithm.evaluator"):
        resolve_evaluator(env(5000), huge, None)
