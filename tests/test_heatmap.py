"""Heatmap simulator against an independent plain-numpy step, and the SPEC section 8 values."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cognet_jax.controllers.neural import NeuralController
from cognet_jax.envs.heatmap import (
    HeatmapState,
    all_patches,
    full_knowledge_value,
    make_heatmap,
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


def test_random_policy_value_19_37():
    env, params = make_heatmap("thesis")
    ctrl = NeuralController(2, 1, 4, obs_shape=(16,), hidden=4)
    policy = ctrl.init(jax.random.key(0))  # uniform actions
    ret = jax.jit(lambda k: rollouts(env, ctrl, k, 50_000, params, policy))(jax.random.key(3))
    mean, se = mean_and_stderr(ret)
    assert abs(float(mean) - 19.37) < 3 * float(se), (float(mean), float(se))
