"""COGNet-DICE pieces against slow references; compile-once, determinism and vmap checks."""

import json

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cognet_jax.algorithms.cognet_thesis import (
    candidate_action_probs,
    rollout_action_counts,
    training_pairs,
)
from cognet_jax.api import make_step, make_train, seed_key, split_seed_key
from cognet_jax.registry import load_config
from cognet_jax.rollout import Trajectory

SMALL = [
    "algorithm.iterations=6",
    "algorithm.rollouts=200",
    "algorithm.top=20",
    "algorithm.keep=5",
    "algorithm.eval_rollouts=20",
    "evaluation.rollouts=500",
    "run.plots=false",
    "run.progress=false",
]


def random_trajectories(rng, r=12, h=4, agents=2, nodes=3, actions=3):
    return Trajectory(
        nodes=jnp.asarray(rng.integers(0, nodes, (r, h, agents)), jnp.int32),
        actions=jnp.asarray(rng.integers(0, actions, (r, h, agents)), jnp.int32),
        obs=jnp.asarray(rng.normal(size=(r, h, agents)), jnp.float32),
        next_nodes=jnp.asarray(rng.integers(0, nodes, (r, h, agents)), jnp.int32),
        rewards=jnp.zeros((r, h)),
        ret=jnp.asarray(rng.normal(size=r), jnp.float32),
    )


def test_action_counts_and_clone_rule_match_slow_reference():
    rng = np.random.default_rng(1)
    traj = random_trajectories(rng, r=8, nodes=4)
    counts = np.asarray(rollout_action_counts(traj.nodes, traj.actions, 4, 3))
    current = rng.dirichlet(np.ones(3), size=(2, 4)).astype(np.float32)
    cands = np.asarray(candidate_action_probs(jnp.asarray(current), jnp.asarray(counts)))
    for k in range(8):
        slow = np.zeros((2, 4, 3))
        for t in range(4):
            for i in range(2):
                slow[i, traj.nodes[k, t, i], traj.actions[k, t, i]] += 1
        np.testing.assert_array_equal(counts[k], slow)
        for i in range(2):
            for q in range(4):
                expect = slow[i, q] / slow[i, q].sum() if slow[i, q].sum() else current[i, q]
                np.testing.assert_allclose(cands[k, i, q], expect, rtol=1e-6)
    np.testing.assert_allclose(cands.sum(-1), 1.0, atol=1e-6)


@pytest.mark.parametrize("last", [True, False])
def test_training_pairs_match_slow_reference(last):
    rng = np.random.default_rng(2)
    traj = random_trajectories(rng, r=12, h=4)
    kept_idx = jnp.array([7, 2, 9, 0], jnp.int32)
    kept_mask = jnp.array([True, True, True, False])
    obs, src, tgt, valid = map(np.asarray, training_pairs(traj, kept_idx, kept_mask, last))
    for i in range(2):
        got = sorted(
            (float(obs[i, p]), int(src[i, p]), int(tgt[i, p]))
            for p in range(obs.shape[1])
            if valid[i, p]
        )
        want = []
        for k, keep in zip(np.asarray(kept_idx), np.asarray(kept_mask)):
            if not keep:
                continue
            for t in range(4 if last else 3):
                want.append(
                    (
                        float(traj.obs[k, t, i]),
                        int(traj.nodes[k, t, i]),
                        int(traj.next_nodes[k, t, i]),
                    )
                )
        assert got == sorted(want)


def test_network_training_fits_pairs_and_masks_idle_members():
    config = load_config(
        "tagging-thesis-spec-n3", SMALL + ["network.train_steps=200", "network.learning_rate=0.05"]
    )
    algorithm, params, _ = make_step(config)
    state = algorithm.init(jax.random.key(0), params)
    # agent 0, node 1 sees z<0 -> 0 and z>0 -> 2; nothing else has data
    z = jnp.linspace(-5, 5, 20)
    obs = jnp.stack([z, z])
    src = jnp.stack([jnp.ones(20, jnp.int32), jnp.zeros(20, jnp.int32)])
    tgt = jnp.stack([jnp.where(z < 0, 0, 2), jnp.zeros(20, jnp.int32)])
    valid = jnp.stack([jnp.ones(20, bool), jnp.zeros(20, bool)])
    nets, _ = jax.jit(algorithm.train_networks)(
        state.policy.net_params, state.opt_state, (obs, src, tgt, valid), params.hyper
    )
    logits = algorithm.controller.all_node_logits(nets, jnp.array([-3.0, 3.0]))
    assert int(jnp.argmax(logits[0, 1])) == 0
    logits2 = algorithm.controller.all_node_logits(nets, jnp.array([3.0, 3.0]))
    assert int(jnp.argmax(logits2[0, 1])) == 2
    # members without pairs are bit-identical to before
    for leaf_new, leaf_old in zip(jax.tree.leaves(nets), jax.tree.leaves(state.policy.net_params)):
        np.testing.assert_array_equal(leaf_new[1], leaf_old[1])
        np.testing.assert_array_equal(leaf_new[0, 0], leaf_old[0, 0])


def test_step_compiles_once_and_keeps_distributions_valid():
    config = load_config("tagging-thesis-spec-n3", SMALL)
    algorithm, params, step = make_step(config)
    k_init, k_run, _ = split_seed_key(seed_key(config, 0))
    state = algorithm.init(k_init, params)
    traced = chex.assert_max_traces(step, n=1)
    jitted = jax.jit(traced)
    for _ in range(4):
        state, metrics = jitted(k_run, state, params)
    probs = np.asarray(state.policy.action_probs)
    np.testing.assert_allclose(probs.sum(-1), 1.0, atol=1e-5)
    assert probs.min() >= 0
    assert int(state.progress.iteration) == 4


def test_separate_training_keeps_one_hot_actions():
    config = load_config("tagging-separate-n3", SMALL)
    algorithm, params, step = make_step(config)
    state = algorithm.init(jax.random.key(0), params)
    for _ in range(3):
        state, _ = jax.jit(step)(jax.random.key(1), state, params)
    expected = np.eye(3)[np.arange(3) % 3]
    np.testing.assert_array_equal(np.asarray(state.policy.action_probs[0]), expected)


def test_vmap_over_seeds_equals_separate_runs():
    config = load_config("tagging-thesis-spec-n3", SMALL)
    train = jax.jit(make_train(config))
    keys = jnp.stack([seed_key(config, s) for s in range(2)])
    _, batched = jax.jit(jax.vmap(make_train(config)))(keys)
    for s in range(2):
        _, single = train(keys[s])
        np.testing.assert_array_equal(np.asarray(batched.value[s]), np.asarray(single.value))
        np.testing.assert_array_equal(
            np.asarray(batched.in_loop_best[s]), np.asarray(single.in_loop_best)
        )


def test_same_seed_same_results(tmp_path):
    from cognet_jax.driver import train

    config = load_config("tagging-thesis-spec-n3", SMALL)
    a = train(config, 3, tmp_path / "a", log=lambda *_: None)
    b = train(config, 3, tmp_path / "b", log=lambda *_: None)
    for field in (
        "final_value",
        "in_loop_best",
        "values_per_iteration",
        "in_loop_best_per_iteration",
    ):
        assert a[field] == b[field]
    c = train(config, 4, tmp_path / "c", log=lambda *_: None)
    assert c["values_per_iteration"] != a["values_per_iteration"]
    saved = json.loads((tmp_path / "a" / "results.json").read_text())
    for key in (
        "experiment",
        "algorithm",
        "seed",
        "config",
        "final_value",
        "in_loop_best",
        "iterations",
        "wall_s",
        "compile_s",
        "values_per_iteration",
        "peak_rss_bytes",
    ):
        assert key in saved
    assert saved["peak_rss_bytes"] > 50 * 2**20  # a process with JAX loaded
    assert saved["final_value"]["rollouts"] == 500


def test_best_rollouts_sets_the_step8_evaluation():
    """best_rollouts = N: the recorded value is the updated policy's mean over N rollouts with
    the iteration's ``best`` stream (SPEC step 8 uses K_eval)."""
    from cognet_jax.algorithms.engine import streams
    from cognet_jax.rollout import rollouts

    config = load_config("tagging-thesis-spec-n3", SMALL + ["algorithm.best_rollouts=700"])
    algorithm, params, _ = make_step(config)

    @jax.jit
    def step_and_expected(key):
        state, metrics = algorithm.step(key, algorithm.init(jax.random.key(4), params), params)
        expected = rollouts(
            algorithm.env, algorithm.controller, streams(key).fresh, 700, params.env, state.policy
        ).mean()
        return metrics.value, expected

    value, expected = step_and_expected(jax.random.key(5))
    np.testing.assert_allclose(float(value), float(expected), rtol=1e-6)
    assert algorithm.rollouts_per_iteration == 200 + 20 * 20 + 700


def test_train_on_top_trains_on_more_pairs_than_kept():
    """train_on = "top": the networks see the pairs of all K_top pre-selected rollouts, so the
    same iteration moves the weights differently than with the K_keep kept ones."""
    out = {}
    for where in ("kept", "top"):
        config = load_config("tagging-thesis-spec-n3", SMALL + [f"algorithm.train_on={where}"])
        algorithm, params, _ = make_step(config)
        state, _ = jax.jit(algorithm.step)(
            jax.random.key(2), algorithm.init(jax.random.key(1), params), params
        )
        out[where] = state
    # same rollouts, same candidates, same action update ...
    np.testing.assert_array_equal(
        np.asarray(out["kept"].policy.action_probs), np.asarray(out["top"].policy.action_probs)
    )
    # ... different training data for the networks
    leaves = zip(
        jax.tree.leaves(out["kept"].policy.net_params),
        jax.tree.leaves(out["top"].policy.net_params),
        strict=True,
    )
    assert any(not np.array_equal(np.asarray(a), np.asarray(b)) for a, b in leaves)


@pytest.mark.parametrize("field,value", [("train_on", "all"), ("best_rollouts", "-5")])
def test_quality_options_are_validated(field, value):
    from cognet_jax.config import ConfigError

    with pytest.raises(ConfigError) as err:
        load_config("tagging-thesis-spec-n3", [f"algorithm.{field}={value}"])
    assert err.value.field == f"algorithm.{field}"
