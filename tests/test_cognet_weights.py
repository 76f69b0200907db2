"""The default COGNet-DICE: cross-entropy over node-network weights (cognet_weights.py)."""

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cognet_jax.algorithms.cognet_weights import CognetWeights, WeightSample, WeightsSettings
from cognet_jax.api import build_algorithm, make_train, split_seed_key
from cognet_jax.config import ConfigError, load_config
from cognet_jax.envs.tagging import make_tagging


def small_algorithm(**kw):
    env, params = make_tagging("thesis")
    settings = WeightsSettings(**{"nodes": 3, "candidates": 8, "eval_rollouts": 16, **kw})
    return CognetWeights(env, params, settings)


def test_sampled_policy_is_an_ordinary_neural_policy():
    alg = small_algorithm()
    template = alg.controller.init(jax.random.key(0))
    samples = alg.draw(jax.random.key(1), alg.init_distribution(), 5)
    policy = alg.to_policy(jax.tree.map(lambda x: x[0], samples))
    assert jax.tree.structure(policy) == jax.tree.structure(template)
    for got, want in zip(jax.tree.leaves(policy), jax.tree.leaves(template)):
        assert got.shape == want.shape
    # one-hot actions; each hidden unit votes for exactly one next node
    assert np.allclose(np.asarray(policy.action_probs).sum(-1), 1.0)
    w2 = np.asarray(policy.net_params["params"]["Dense_1"]["kernel"])  # [agents, Q, H, Q]
    assert ((w2 != 0).sum(-1) <= 1).all()


def test_refit_to_identical_elites_concentrates_up_to_the_floors():
    alg = small_algorithm(elites=4)
    dist = alg.init_distribution()
    one = jax.tree.map(lambda x: x[0], alg.draw(jax.random.key(2), dist, 1))
    elites = jax.tree.map(lambda x: jnp.stack([x] * 4), one)
    hyper = alg.hyper.replace(alpha=1.0, action_floor=0.1, category_floor=0.2)
    new = alg.update_distribution(dist, elites, hyper)
    chosen = np.take_along_axis(
        np.asarray(new.action_probs), np.asarray(one.actions)[..., None], -1
    )
    assert np.allclose(chosen, 0.9 + 0.1 / alg.env.num_actions)
    assert np.allclose(np.asarray(new.w1_mean), np.asarray(one.w1))
    assert np.allclose(np.asarray(new.w1_std), 0.0)
    q = alg.settings.nodes
    top = np.asarray(new.unit_target_probs).max(-1)
    assert np.allclose(top, 0.8 + 0.2 / q)


def test_common_random_numbers_give_equal_values_to_equal_candidates():
    alg = small_algorithm()
    one = jax.tree.map(lambda x: x[:1], alg.draw(jax.random.key(3), alg.init_distribution(), 1))
    twice = jax.tree.map(lambda x: jnp.concatenate([x, x]), one)
    values = alg.evaluate_policies(jax.random.key(4), alg.to_policy(twice))
    assert float(values[0]) == float(values[1])


def best_open_loop_value(alg, key) -> float:
    """Largest mean return of any open-loop joint controller of ``alg``'s 3 nodes (node q
    always moves to q + 1: actions fixed per time step, observations ignored), 2000 rollouts
    each with common random numbers (the maximum is biased upwards)."""
    env = alg.env
    a, q = env.num_agents, alg.settings.nodes
    seqs = list(itertools.product(range(env.num_actions), repeat=q))
    joint = np.array(list(itertools.product(seqs, repeat=a)), np.int32)  # [n, agents, Q]
    n = joint.shape[0]
    h = alg.settings.hidden
    f = alg.controller.in_features
    nxt = np.minimum(np.arange(q) + 1, q - 1)
    sample = WeightSample(
        actions=jnp.asarray(joint),
        w1=jnp.zeros((n, a, q, f, h)),
        b1=jnp.zeros((n, a, q, h)),
        unit_targets=jnp.zeros((n, a, q, h), jnp.int32),
        m=jnp.zeros((n, a, q, h)),
        default=jnp.broadcast_to(jnp.asarray(nxt, jnp.int32), (n, a, q)),
        bias=jnp.full((n, a, q), 50.0),
    )
    blind = CognetWeights(
        env, alg.env_params, WeightsSettings(nodes=q, hidden=h, eval_rollouts=2000)
    )
    return float(jnp.max(jax.jit(blind.evaluate_policies)(key, blind.to_policy(sample))))


def test_cognet_dice_learns_to_use_observations_on_tagging():
    """A short default search (seed 0) on the thesis tagging problem beats every open-loop
    controller by a wide margin, and so does the *mode* of its final distribution: a search
    that does not learn (its distribution stays where it started) can at best pick a lucky
    random candidate, never a good mode."""
    sets = [
        "algorithm.iterations=100",
        "algorithm.candidates=100",
        "algorithm.eval_rollouts=200",
        "algorithm.best_rollouts=500",
    ]
    config = load_config("tagging-thesis-n3", sets)
    alg = build_algorithm(config)
    key = jax.random.key(0)
    state, metrics = jax.jit(make_train(config))(key)
    _, _, k_eval = split_seed_key(key)
    best = float(alg.policy_returns(k_eval, alg.best_policy(state), 10_000).mean())
    mode = alg.to_policy(alg.mode(state.distribution))
    mode_value = float(alg.policy_returns(k_eval, mode, 10_000).mean())
    blind = best_open_loop_value(alg, jax.random.key(5))
    assert blind < 0.0
    assert best > blind + 16.0, (best, blind)
    assert mode_value > blind + 12.0, (mode_value, blind)
    assert metrics.value.shape == (100,)


@pytest.mark.parametrize(
    "field,value",
    [
        ("elites", 1),
        ("elites", 300),
        ("candidates", 0),
        ("alpha", 1.5),
        ("action_floor", -0.1),
        ("best_rollouts", 0),
        ("vote_std", float("nan")),
    ],
)
def test_bad_settings_name_the_field(field, value):
    with pytest.raises(ConfigError) as err:
        load_config("tagging-thesis-n3", [f"algorithm.{field}={value}"])
    assert f"algorithm.{field}" in str(err.value)


def test_thesis_algorithm_keeps_its_own_name():
    config = load_config("tagging-thesis-spec-n3")
    assert config.experiment.algorithm == "cognet-dice-thesis"
    assert type(build_algorithm(config)).__name__ == "CognetDice"
    assert type(build_algorithm(load_config("tagging-thesis-n3"))).__name__ == "CognetWeights"
