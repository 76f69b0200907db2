"""Tagging simulator against an independent plain-numpy step, and SPEC section 8 values."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cognet_jax.controllers.neural import NeuralController
from cognet_jax.controllers.regions import reactive_tagging_policy
from cognet_jax.envs.tagging import TaggingState, make_tagging
from cognet_jax.rollout import rollouts


def scipy_norm_ppf(u):
    from statistics import NormalDist

    return np.array([NormalDist().inv_cdf(float(x)) for x in u])


def numpy_step(
    taggers, evader, actions, motion_noise, obs_noise, respawn_pos, respawn, length=10.0
):
    """Plain re-statement of SPEC 7.1 with the noise draws given explicitly."""
    reward = 0.0
    hit_any = False
    for p, a in zip(taggers, actions):
        if a == 0:
            if abs(p - evader) <= 1.0:
                reward += 50.0
                hit_any = True
            else:
                reward -= 20.0
        else:
            reward -= 1.0
    new_p = []
    for p, a, n in zip(taggers, actions, motion_noise):
        delta = {0: 0.0, 1: -1.0, 2: 1.0}[int(a)]
        new_p.append(min(max(p + delta + n, 0.0), length))
    d = sum(q - evader for q in new_p)
    e = evader + (1.0 if d < 0 else (-1.0 if d > 0 else 0.0))
    e = min(max(e, 0.0), length)
    if respawn and hit_any:
        new_p, e = list(respawn_pos[:-1]), respawn_pos[-1]
    obs = [e - q + n for q, n in zip(new_p, obs_noise)]
    return np.array(new_p), e, np.array(obs), reward


@pytest.mark.parametrize("setting", ["thesis", "cogdice-paper"])
@pytest.mark.parametrize("noise", [0.0, 0.3])
def test_step_matches_numpy_reference(setting, noise):
    env, params = make_tagging(setting, motion_noise=noise, obs_noise=noise)
    rng = np.random.default_rng(0)
    step = jax.jit(env.step)
    for _i in range(300):
        # include positions near the tag radius and the walls
        pos = rng.choice([rng.uniform(0, 10), rng.integers(0, 11) * 1.0], size=3)
        actions = rng.integers(0, 3, size=2)
        u = rng.uniform(size=env.step_noise)
        state = TaggingState(taggers=jnp.asarray(pos[:2], jnp.float32), evader=jnp.float32(pos[2]))
        nxt, obs, reward = step(
            jnp.asarray(u, jnp.float32), state, jnp.asarray(actions, jnp.int32), params
        )
        # the documented layout of u: motion noise, observation noise, respawn positions
        m = noise * scipy_norm_ppf(u[:2])
        o = noise * scipy_norm_ppf(u[2:4])
        r = u[4:] * 10.0
        ref = numpy_step(
            np.asarray(state.taggers), float(state.evader), actions, m, o, r, bool(params.respawn)
        )
        np.testing.assert_allclose(np.asarray(nxt.taggers), ref[0], atol=1e-5)
        np.testing.assert_allclose(float(nxt.evader), ref[1], atol=1e-5)
        np.testing.assert_allclose(np.asarray(obs), ref[2], atol=1e-5)
        assert float(reward) == ref[3]


def _value(env, params, ctrl, policy, n=20000, seed=0):
    ret = jax.jit(lambda k: rollouts(env, ctrl, k, n, params, policy))(jax.random.key(seed))
    ret = np.asarray(ret, np.float64)
    return ret.mean(), ret.std(ddof=1) / np.sqrt(n)


def test_random_policy_value_thesis():
    env, params = make_tagging("thesis")
    ctrl = NeuralController(2, 3, 3)
    mean, se = _value(env, params, ctrl, ctrl.init(jax.random.key(1)))
    assert abs(mean - (-23.68)) < 3 * se


@pytest.mark.parametrize(
    "setting,reference,ref_se", [("thesis", 20.76, 0.09), ("cogdice-paper", 108.0, 0.35)]
)
def test_reactive_controller_value(setting, reference, ref_se):
    env, params = make_tagging(setting)
    ctrl, policy = reactive_tagging_policy()
    mean, se = _value(env, params, ctrl, policy, n=20000 if setting == "thesis" else 4000)
    assert abs(mean - reference) < 3 * np.hypot(se, ref_se)


def test_discretised_observations():
    from cognet_jax.envs.tagging import discretise

    z = jnp.array([-3.7, -1.2, 0.3, 2.5, 4.49, 7.9])
    np.testing.assert_allclose(discretise(z, 1.0), [-4, -1, 0, 2, 4, 8])  # round half to even
    np.testing.assert_allclose(discretise(z, 2.0), [-4, 0, 0, 2, 4, 8])
    np.testing.assert_allclose(discretise(z, 4.0), [-4, 0, 0, 0, 4, 8])
    np.testing.assert_allclose(discretise(z, 0.5), [-3.5, -1.0, 0.5, 2.5, 4.5, 8.0])


def test_a_constant_zero_noise_level_skips_the_normal_draws():
    """``scaled_normal`` with a constant zero scale traces no inverse CDF and no ``cond``; a
    traced scale keeps the ``cond``; every way, zero noise is exactly zero and a nonzero level
    scales the same normal draws."""
    from cognet_jax.envs.base import normal_from_uniform, scaled_normal

    u = jax.random.uniform(jax.random.key(0), (64,))

    def primitives(fn, *args):
        return {e.primitive.name for e in jax.make_jaxpr(fn)(*args).eqns}

    assert "cond" not in primitives(lambda u: scaled_normal(0.0, u), u)
    assert "cond" in primitives(lambda s, u: scaled_normal(s, u), 0.0, u)
    assert "cond" in primitives(lambda u: scaled_normal(0.5, u), u)
    traced = jax.jit(scaled_normal)
    np.testing.assert_array_equal(scaled_normal(0.0, u), traced(jnp.float32(0.0), u))
    assert not np.any(np.asarray(scaled_normal(0.0, u)))
    np.testing.assert_allclose(traced(0.5, u), 0.5 * normal_from_uniform(u), rtol=1e-6)
