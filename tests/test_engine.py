"""The search engine's protocol (``algorithms.engine``): ``ask``, ``evaluate`` and ``tell`` with
the iteration key are what ``step`` runs, for every algorithm; a
fitness of one's own goes through ``tell``; ``fresh`` replaces the anytime best's rollouts."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from shared_files import dpomdp_file

from cognet_jax.api import make_step
from cognet_jax.config import load_config

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


def _config(name):
    experiment, sets = CASES[name]
    if experiment == "gdice-dpomdp":
        sets = [f'problem.path="{dpomdp_file("dectiger")}"', *sets]
    return load_config(experiment, sets)


def _same(a, b):
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def test_tabular_search_with_own_fitness_and_fresh_values():
    from cognet_jax.api import build_algorithm
    from cognet_jax.exact_jax import exact_value

    config = load_config(
        "gdice-dpomdp-spec",
        [f'problem.path="{dpomdp_file("dectiger")}"', "problem.horizon=2", "algorithm.nodes=2"],
    )
    algorithm = build_algorithm(config)

    def fitness(policies):  # the exact value, computed by the user
        return jax.vmap(lambda p: exact_value(algorithm.env, algorithm.env_params, p, 2))(policies)

    calls = []

    def fresh(key, policy):
        calls.append(1)
        return fitness(jax.tree.map(lambda x: x[None], policy))[0]

    @jax.jit
    def iteration(key, state):
        samples, policies = algorithm.ask(key, state)
        return algorithm.tell(key, state, samples, fitness(policies), fresh=fresh)

    state = algorithm.init(jax.random.key(0))
    for i in range(30):
        state, metrics = iteration(jax.random.fold_in(jax.random.key(1), i), state)
    assert calls  # traced once: the anytime best was valued by `fresh`
    best = float(fitness(jax.tree.map(lambda x: x[None], algorithm.best_policy(state)))[0])
    # Dec-Tiger h 2 optimum -4 (listen twice); the in-loop best is the exact value of the policy
    assert best == pytest.approx(-4.0, abs=1e-4)
    assert float(metrics.best_value) == pytest.approx(best, abs=1e-5)
    assert jnp.isfinite(metrics.threshold)


def test_make_train_takes_hyper_parameters_and_make_evaluate_is_honest(tmp_path):
    from cognet_jax import build_algorithm, make_evaluate, make_train, seed_key
    from cognet_jax.api import split_seed_key
    from cognet_jax.controllers.regions import reactive_tagging_policy
    from cognet_jax.runner import honest_evaluation, run_training

    config = load_config(
        "tagging-thesis-cogdice-n3",
        [
            "algorithm.iterations=3",
            "algorithm.samples=40",
            "evaluation.rollouts=2000",
            "env.motion_noise=0.5",
            "env.obs_noise=0.5",
        ],
    )
    train = jax.jit(make_train(config))
    key = seed_key(config, 0)
    default = build_algorithm(config).hyper
    state_a, metrics_a = train(key)
    state_b, metrics_b = train(key, default)
    _same((state_a, metrics_a), (state_b, metrics_b))
    # three smoothing rates in one program; alpha 0 never moves the distribution
    alphas = jnp.array([0.0, 0.1, 0.5])
    hypers = jax.vmap(lambda a: default.replace(alpha=a))(alphas)
    states, _ = jax.jit(jax.vmap(train, in_axes=(None, 0)))(key, hypers)
    start = build_algorithm(config).init_distribution()
    np.testing.assert_array_equal(
        np.asarray(states.distribution.action_probs[0]), np.asarray(start.action_probs)
    )
    # 0.1 is the experiment's alpha (the batched program may round a last bit differently)
    for x, y in zip(
        jax.tree.leaves(jax.tree.map(lambda x: x[1], states)), jax.tree.leaves(state_a)
    ):
        np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=1e-5)
    # the honest value of make_evaluate is the one `cognet-jax train --seed 0` reports: the
    # run's best policy here, and a policy whose returns vary (the reactive controller)
    mean, _ = jax.jit(make_evaluate(config))(key, state_a.best_policy)
    results = run_training(config, 0, tmp_path / "run", log=lambda *_: None)
    assert float(mean) == pytest.approx(results["final_value"]["mean"], rel=1e-5, abs=1e-4)
    _, reactive = reactive_tagging_policy()
    mean, stderr = jax.jit(make_evaluate(config))(key, reactive)
    e = config.evaluation
    ref = honest_evaluation(
        build_algorithm(config), split_seed_key(key)[2], reactive, e.rollouts, e.batch
    )
    assert float(mean) == pytest.approx(ref["mean"], rel=1e-5)
    assert float(stderr) == pytest.approx(ref["stderr"], rel=1e-3) and ref["stderr"] > 0


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
    """Every algorithm speaks the protocol (``step`` is ``ask``, ``evaluate``, ``tell`` with
    the same iteration key, so a search driven by hand draws what ``step`` draws); values of
    one's own go through ``tell``: with every candidate valued 0 and ``fresh`` giving 7, the
    anytime best value is 7."""
    algorithm, init, _ = make_step(_config(name))
    if name == "gdice-portfolio":
        assert len(algorithm.members) == 3  # independent, shared, exploring
    state = init(jax.random.key(0))

    @jax.jit
    def iteration(key, state):
        asked, policies = algorithm.ask(key, state)
        values = jax.tree.map(jnp.zeros_like, algorithm.evaluate(key, policies))
        return algorithm.tell(key, state, asked, values, fresh=lambda k, p: jnp.float32(7.0))

    state, metrics = iteration(jax.random.key(5), state)
    assert float(metrics.best_value) == 7.0
    assert float(metrics.value) == OWN_VALUE[name]
