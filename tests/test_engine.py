"""The search protocol (``algorithms.engine``) for every algorithm: ``ask``, ``evaluate`` and
``tell`` with the iteration key are what ``step`` runs; values and fresh values of one's own go
through ``tell``; the iteration's random streams are independent, so a winner's fresh
rollouts never reuse the rollouts it was selected on."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from shared_files import dpomdp_file

from cognet_jax.algorithms.engine import streams
from cognet_jax.api import make_step
from cognet_jax.registry import load_config

CASES = {
    "cogdice": (
        "tagging-thesis-cogdice-n3",
        ["algorithm.samples=60", "algorithm.best_rollouts=20"],
    ),
    "cognet-dice": ("tagging-thesis-n3", ["algorithm.candidates=40", "algorithm.elites=4"]),
    "gdice": ("tagging-paper-gdice-d1", ["env.horizon=5", "algorithm.samples=50"]),
    "cognet-dice-thesis": (
        "tagging-thesis-spec-n3",
        ["algorithm.rollouts=200", "algorithm.top=20", "algorithm.keep=4"],
    ),
    "cognet-dice-thesis-separate": (
        "tagging-separate-n3",
        ["algorithm.rollouts=200", "network.train_steps=3"],
    ),
    # the G-DICE portfolio (independent, shared and exploring searches) with rollout values
    "gdice-portfolio": (
        "gdice-dpomdp",
        ["algorithm.samples=40", 'algorithm.evaluator="rollouts"', "algorithm.nodes=2"],
    ),
}


def _config(name, extra=()):
    experiment, sets = CASES[name]
    if experiment == "gdice-dpomdp":
        sets = [f'problem.path="{dpomdp_file("dectiger")}"', *sets]
    return load_config(experiment, [*sets, *extra])


def test_tabular_search_with_own_fitness_and_fresh_values():
    from cognet_jax.api import build_algorithm
    from cognet_jax.exact_jax import exact_value

    config = load_config(
        "gdice-dpomdp-spec",
        [f'problem.path="{dpomdp_file("dectiger")}"', "problem.horizon=2", "algorithm.nodes=2"],
    )
    algorithm, params = build_algorithm(config)

    def fitness(policies):  # the exact value, computed by the user
        return jax.vmap(lambda p: exact_value(algorithm.env, params.env, p, 2))(policies)

    calls = []

    def fresh(key, policy):
        calls.append(1)
        return fitness(jax.tree.map(lambda x: x[None], policy))[0]

    @jax.jit
    def iteration(key, state):
        samples, policies = algorithm.ask(key, state, params)
        return algorithm.tell(key, state, samples, fitness(policies), params, fresh_value=fresh)

    state = algorithm.init(jax.random.key(0), params)
    for i in range(30):
        state, metrics = iteration(jax.random.fold_in(jax.random.key(1), i), state)
    assert calls  # traced once: the anytime best was valued by `fresh`
    best = float(fitness(jax.tree.map(lambda x: x[None], algorithm.best_policy(state)))[0])
    # Dec-Tiger h 2 optimum -4 (listen twice); the in-loop best is the exact value of the policy
    assert best == pytest.approx(-4.0, abs=1e-4)
    assert float(metrics.in_loop_best) == pytest.approx(best, abs=1e-5)
    assert jnp.isfinite(metrics.threshold)


@functools.cache
def _driven_by_hand(name):
    """One iteration of case ``name`` two ways: ``ask``, ``evaluate`` and ``tell`` by hand and
    ``step``, as traced programs (``(by_hand, step)`` jaxprs, not compiled); and, compiled, by
    hand with every candidate valued 0 and ``fresh_value`` giving 7. Returns ``(algorithm,
    (by_hand, step), outputs)``."""
    algorithm, params, _ = make_step(_config(name))
    state = algorithm.init(jax.random.key(0), params)

    def by_hand(key, state, own_values=False):
        asked, policies = algorithm.ask(key, state, params)
        values = algorithm.evaluate(key, policies, params)
        if not own_values:
            return algorithm.tell(key, state, asked, values, params)
        values = jax.tree.map(jnp.zeros_like, values)
        seven = lambda k, p: jnp.float32(7.0)  # noqa: E731
        return algorithm.tell(key, state, asked, values, params, fresh_value=seven)

    key = jax.random.key(5)
    traced = [
        jax.make_jaxpr(f)(key, state) for f in (by_hand, lambda k, s: algorithm.step(k, s, params))
    ]
    own = jax.jit(functools.partial(by_hand, own_values=True))(key, state)
    return algorithm, traced, own


@pytest.mark.parametrize("name", sorted(CASES))
def test_ask_evaluate_tell_is_step(name):
    """A search driven by hand with one iteration key is the program ``step`` runs: the same
    operations on the same values (equal jaxprs, so equal numbers however it is compiled)."""
    _, (by_hand, step), _ = _driven_by_hand(name)
    assert len(by_hand.eqns) > 10  # a whole iteration was traced
    assert str(by_hand) == str(step)
    for a, b in zip(by_hand.consts, step.consts, strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


#: iteration value each algorithm reports when every candidate is valued 0 and ``fresh`` gives 7:
#: the best sample's value (threshold searches) or the freshly valued policy's (the others)
OWN_VALUE = {
    "cogdice": 0.0,
    "gdice": 0.0,
    "gdice-portfolio": 0.0,
    "cognet-dice": 7.0,
    "cognet-dice-thesis": 7.0,
    "cognet-dice-thesis-separate": 7.0,
}


@pytest.mark.parametrize("name", sorted(CASES))
def test_ask_evaluate_tell_with_own_values_and_fresh(name):
    """Values of one's own go through ``tell``: with every candidate valued 0 and
    ``fresh_value`` giving 7, the anytime best value is 7."""
    algorithm, _, (_, metrics) = _driven_by_hand(name)
    if name == "gdice-portfolio":
        assert len(algorithm.members) == 3  # independent, shared, exploring
    assert float(metrics.in_loop_best) == 7.0
    assert float(metrics.value) == OWN_VALUE[name]


def test_streams_are_one_split_into_independent_keys():
    key = jax.random.key(11)
    s = streams(key)
    data = [tuple(np.asarray(jax.random.key_data(k)).tolist()) for k in s]
    assert len(set(data)) == 4
    # one split: the first two streams are those of a two-way split of the same key
    two = jax.random.split(key)
    for a, b in zip(s[:2], two):
        np.testing.assert_array_equal(jax.random.key_data(a), jax.random.key_data(b))


#: settings under which a winner's fresh mean would equal its in-loop mean exactly if both
#: were drawn from the same key: noisy observations and motion, as many fresh rollouts as
#: in-loop ones, common random numbers
NOISY = ["env.motion_noise=0.5", "env.obs_noise=0.5"]


THRESHOLD_CASES = {
    # Dec-Tiger: every controller's return depends on where the tiger is
    "gdice": (
        "gdice-dpomdp-spec",
        ["problem.horizon=3", "algorithm.nodes=2", "algorithm.samples=50"],
    ),
    "cogdice": ("tagging-thesis-cogdice-n3", ["algorithm.samples=60", *NOISY]),
}


@pytest.mark.parametrize("name", sorted(THRESHOLD_CASES))
def test_threshold_winner_is_revalued_on_rollouts_it_was_not_selected_on(name):
    """The engine's anytime best: the winner of the candidates' rollouts (``evaluate``
    stream) is valued on fresh rollouts (``best`` stream). Drawn from the same key, with as many
    rollouts, the fresh mean would repeat the in-loop mean to the last bit."""
    experiment, sets = THRESHOLD_CASES[name]
    n = 20
    sets = [*sets, f"algorithm.eval_rollouts={n}", f"algorithm.best_rollouts={n}"]
    if experiment.startswith("gdice"):
        sets.append(f'problem.path="{dpomdp_file("dectiger")}"')
    algorithm, params, _ = make_step(load_config(experiment, sets))
    state = algorithm.init(jax.random.key(0), params)

    @jax.jit
    def iteration(key, state):
        samples, policies = algorithm.ask(key, state, params)
        values = algorithm.evaluate(key, policies, params)
        state, _ = algorithm.tell(key, state, samples, values, params)
        winner = jax.tree.map(lambda x: x[jnp.argmax(values)], policies)
        recorded = state.progress.recent[-1]  # the value the anytime best compared
        fresh = algorithm.fresh_value(streams(key).fresh, winner, params)
        reused = algorithm.fresh_value(streams(key).evaluate, winner, params)
        return state, (recorded, fresh, reused, values.max())

    fresh_differs = 0
    for i in range(6):
        state, out = iteration(jax.random.key(30 + i), state)
        recorded, fresh, reused, in_loop = (float(x) for x in out)
        assert recorded == pytest.approx(fresh, rel=1e-6)
        assert reused == pytest.approx(in_loop, rel=1e-6)  # the in-loop mean
        fresh_differs += recorded != in_loop
    assert fresh_differs >= 1, fresh_differs  # 0 when both come from one key


def test_weight_search_values_winner_and_mode_on_their_own_streams():
    """The default COGNet-DICE values its winner on the ``best`` stream and the distribution's
    mode on the ``other`` one, neither of them the candidates' ``evaluate`` stream."""
    n = 30
    sets = [*NOISY, f"algorithm.eval_rollouts={n}", f"algorithm.best_rollouts={n}"]
    algorithm, params, _ = make_step(_config("cognet-dice", sets))
    state = algorithm.init(jax.random.key(0), params)

    @jax.jit
    def iteration(key, state):
        samples, policies = algorithm.ask(key, state, params)
        values = algorithm.evaluate(key, policies, params)
        new, metrics = algorithm.tell(key, state, samples, values, params)
        winner = jax.tree.map(lambda x: x[jnp.argmax(values)], policies)
        mode = algorithm.to_policy(algorithm.mode(new.distribution))
        s = streams(key)
        v_winner = algorithm.fresh_value(s.fresh, winner, params)
        v_mode = algorithm.fresh_value(s.other, mode, params)
        reused = algorithm.fresh_value(s.evaluate, winner, params)
        # every candidate on the best stream and on the evaluate stream (a winner whose
        # return is the same on every stream, e.g. one that never tags, shows nothing)
        on = lambda k: jax.vmap(lambda p: algorithm.fresh_value(k, p, params))(policies)  # noqa: E731
        return metrics.value, v_winner, v_mode, reused, values.max(), on(s.fresh), on(s.evaluate)

    value, v_winner, v_mode, reused, in_loop, on_best, on_evaluate = iteration(
        jax.random.key(3), state
    )
    assert float(value) == pytest.approx(max(float(v_winner), float(v_mode)), rel=1e-6)
    assert float(reused) == pytest.approx(float(in_loop), rel=1e-6)
    assert not np.allclose(np.asarray(on_best), np.asarray(on_evaluate))


@pytest.mark.parametrize("name", ["cognet-dice-thesis", "cognet-dice-thesis-separate"])
def test_thesis_step8_values_the_updated_policy_on_its_own_stream(name):
    """Step 8 of the thesis algorithm values the updated policy on the ``best`` stream, not on
    the rollouts that trained it (``sample``) or valued the candidates (``evaluate``)."""
    algorithm, params, _ = make_step(_config(name, NOISY))
    state = algorithm.init(jax.random.key(0), params)

    @jax.jit
    def iteration(key, state):
        new, metrics = algorithm.step(key, state, params)
        s = streams(key)
        values = [
            algorithm.fresh_value(k, new.policy, params) for k in (s.fresh, s.sample, s.evaluate)
        ]
        return metrics.value, values

    value, (expected, *others) = iteration(jax.random.key(3), state)
    assert float(value) == pytest.approx(float(expected), rel=1e-6)
    for other in others:
        assert float(other) != float(value)
