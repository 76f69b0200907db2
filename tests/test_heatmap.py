"""Heatmap simulator against an independent plain-numpy step, and the SPEC section 8 values."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cognet_jax.controllers.neural import NeuralController
from cognet_jax.envs.heatmap import (
    START_RANGES,
    HeatmapState,
    all_patches,
    distance_only_value,
    first_move_blind_value,
    full_knowledge_value,
    make_heatmap,
    random_value,
)
from cognet_jax.rollout import mean_and_stderr, rollouts


def numpy_step(pos, actions, normals, amplitude, mean, std):
    """Plain re-statement of SPEC 7.2 with the noise normals given explicitly."""
    img = np.array(
        [[math.exp(-(x * x + y * y) / 50.0) for y in range(16)] for x in range(16)], np.float32
    )
    reward = 0.0
    new_pos, obs = [], []
    for (x, y), a, nrm in zip(pos, actions, normals):
        d = x * x + y * y
        reward += 50.0 if d < 9 else (1.0 if d < 16 else -1.0)
        if a == 0:
            x += 1
        elif a == 1:
            x -= 1
        elif a == 2:
            y -= 1
        else:
            y += 1
        x, y = min(max(x, 2), 13), min(max(y, 2), 13)
        new_pos.append((x, y))
        patch = img[x - 2 : x + 2, y - 2 : y + 2].reshape(-1)
        obs.append(patch + amplitude * (mean + std * nrm))
    return np.array(new_pos), np.array(obs), reward


def test_step_matches_numpy_reference():
    from statistics import NormalDist

    env, params = make_heatmap("thesis", obs_noise_std=0.05, obs_noise_mean=0.01)
    params = params.replace(obs_noise_amplitude=1.1)
    rng = np.random.default_rng(0)
    step = jax.jit(env.step)
    for _ in range(40):
        pos = rng.integers(-1, 14, size=(2, 2))
        actions = rng.integers(0, 4, size=2)
        u = rng.uniform(0.01, 0.99, size=env.step_noise).astype(np.float32)
        normals = np.array([NormalDist().inv_cdf(float(v)) for v in u]).reshape(2, 16)
        state, obs, reward = step(
            jnp.asarray(u),
            HeatmapState(pos=jnp.asarray(pos, jnp.int32)),
            jnp.asarray(actions),
            params,
        )
        ref_pos, ref_obs, ref_reward = numpy_step(pos, actions, normals, 1.1, 0.01, 0.05)
        np.testing.assert_array_equal(np.asarray(state.pos), ref_pos)
        np.testing.assert_allclose(np.asarray(obs), ref_obs, atol=2e-5)
        assert float(reward) == ref_reward


def test_zero_signal_replaces_the_patch_by_noise_or_a_constant():
    env, params = make_heatmap("default", obs_signal=0.0, obs_noise_mean=0.3)
    pos = jnp.array([[5, 7], [2, 2]], jnp.int32)
    u = jax.random.uniform(jax.random.key(0), (env.step_noise,))
    np.testing.assert_array_equal(np.asarray(env.observe(pos, u, params)), np.float32(0.3))
    noisy = np.asarray(env.observe(pos, u, params.replace(obs_noise_std=1.0)))
    other = np.asarray(env.observe(pos[::-1], u, params.replace(obs_noise_std=1.0)))
    np.testing.assert_array_equal(noisy, other)  # the position no longer shows
    assert noisy.std() > 0.5


def test_noise_free_observation_is_patch_and_agent_cell():
    env, params = make_heatmap("default")
    pos = jnp.array([[5, 7], [13, 2]], jnp.int32)
    obs = env.observe(pos, jnp.full(env.step_noise, 0.5), params)
    patches = all_patches()
    for i, (x, y) in enumerate(np.asarray(pos)):
        np.testing.assert_allclose(np.asarray(obs[i]), patches[(x - 2) * 13 + (y - 2)], atol=1e-6)
        assert float(obs[i].reshape(4, 4)[2, 2]) == pytest.approx(math.exp(-(x * x + y * y) / 50))


def test_reset_covers_start_range():
    env, params = make_heatmap("thesis")
    u = jax.random.uniform(jax.random.key(1), (20000, env.reset_noise))
    pos = np.asarray(jax.vmap(env.reset, (0, None))(u, params).pos)
    assert pos.min() == -1 and pos.max() == 12
    counts = np.bincount((pos + 1).reshape(-1), minlength=14)
    assert counts.min() > 0.8 * counts.mean()


def test_full_knowledge_optimum_is_53_14():
    assert full_knowledge_value("thesis") == pytest.approx(53.14, abs=0.005)


def test_first_move_blind_bound_and_the_reactive_controller_that_attains_it():
    """No policy that moves before it observes beats 46.898 in the thesis range (the target 50
    of the issue is above it), and the 2-node reactive controller reaches it exactly when run
    through the simulator's own step: x-1 first, then x-1 while the patch says x > 2, else
    y-1. The patch gives x: log v(x-1, y) - log v(x, y) = (2x - 1) / 50."""
    x_minus, y_minus = 1, 2  # actions
    for start, bound in (("thesis", 46.898), ("default", 4.431)):
        assert first_move_blind_value(start) == pytest.approx(bound, abs=5e-4)
        assert first_move_blind_value(start) < full_knowledge_value(start)
        env, params = make_heatmap(start)
        lo, hi = START_RANGES[start]
        grid = np.array([(x, y) for x in range(lo, hi + 1) for y in range(lo, hi + 1)])
        pos = np.stack([grid, grid[::-1]], axis=1)  # [starts, agents, 2]: both agents, all starts
        state = HeatmapState(pos=jnp.asarray(pos, jnp.int32))
        actions = jnp.full(pos.shape[:2], x_minus)
        total = jnp.zeros(len(grid))
        step = jax.vmap(env.step, (None, 0, 0, None))
        for _ in range(env.horizon):
            state, obs, reward = step(jnp.zeros(env.step_noise), state, actions, params)
            total = total + reward
            x_seen = jnp.round((50 * (jnp.log(obs[..., 6]) - jnp.log(obs[..., 10])) + 1) / 2)
            np.testing.assert_array_equal(x_seen, state.pos[..., 0])  # the patch tells x
            actions = jnp.where(x_seen > 2, x_minus, y_minus)
        assert float(total.mean()) == pytest.approx(first_move_blind_value(start), abs=1e-4)


def test_distance_only_bound_lies_between_blind_and_full_position_knowledge():
    """An agent that observes only its distance to the source does worse than one that knows
    its position after the first move, and better than a random walk; with horizon 2 no
    observation is ever used, so the two bounds coincide."""
    for start in ("thesis", "default"):
        distance = distance_only_value(start)
        assert random_value(start) < distance < first_move_blind_value(start) - 1.0
        assert distance_only_value(start, horizon=2) == pytest.approx(
            first_move_blind_value(start, horizon=2)
        )
    assert distance_only_value("thesis") == pytest.approx(42.7347, abs=1e-3)


def test_random_policy_value_19_37():
    env, params = make_heatmap("thesis")
    ctrl = NeuralController(2, 1, 4, obs_shape=(16,), hidden=4)
    policy = ctrl.init(jax.random.key(0))  # uniform actions
    ret = jax.jit(lambda k: rollouts(env, ctrl, k, 50_000, params, policy))(jax.random.key(3))
    mean, se = mean_and_stderr(ret)
    assert abs(float(mean) - 19.37) < 3 * float(se), (float(mean), float(se))
