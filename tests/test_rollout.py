"""``rollout.rollouts`` draws each step's uniforms one step ahead (carried through the scan) and
through the unrolled Threefry: its returns and trajectories equal those of the plain scan that
draws the uniforms inside each step with JAX's own threefry, on every kind of env and
controller, for any horizon."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cognet_jax.controllers.neural import NeuralController
from cognet_jax.controllers.tabular import TabularController
from cognet_jax.envs.heatmap import make_heatmap
from cognet_jax.envs.tabular import make_tabular
from cognet_jax.envs.tagging import make_tagging
from cognet_jax.rollout import Trajectory, evaluate_candidates, rollouts
from tests.test_tabular_env import asymmetric_model


def plain_rollouts(env, controller, key, num, env_params, policy, record=False):
    """The straightforward engine: one uniform block drawn inside every step."""
    n = env.num_agents
    k_reset, k_steps = jax.random.split(key)
    states = jax.vmap(env.reset, (0, None))(
        jax.random.uniform(k_reset, (num, env.reset_noise)), env_params
    )
    gamma = jnp.asarray(env_params.discount, jnp.float32)

    def body(carry, k):
        states, nodes, ret, disc = carry
        u = jax.random.uniform(k, (num, 2 * n + env.step_noise))
        actions = jax.vmap(controller.act, (0, None, 0))(u[:, :n], policy, nodes)
        states, obs, reward = jax.vmap(env.step, (0, 0, 0, None))(
            u[:, 2 * n :], states, actions, env_params
        )
        next_nodes = jax.vmap(controller.next_node, (0, None, 0, 0))(
            u[:, n : 2 * n], policy, nodes, obs
        )
        ret = ret + disc * reward
        return (states, next_nodes, ret, disc * gamma), (nodes, actions, obs, next_nodes, reward)

    init = (states, jnp.zeros((num, n), jnp.int32), jnp.zeros(num, jnp.float32), jnp.float32(1))
    (_, _, ret, _), out = jax.lax.scan(body, init, jax.random.split(k_steps, env.horizon))
    if not record:
        return ret
    return Trajectory(*(jnp.swapaxes(x, 0, 1) for x in out), ret)


@functools.cache
def _cases():
    """Every case's ``(env, controller, env params, policy)``, built at the first test (not
    while pytest collects the file)."""
    tag_env, tag_params = make_tagging("thesis")
    noisy = tag_params.replace(obs_noise=0.3, motion_noise=0.2)
    paper_env, paper_params = make_tagging("cogdice-paper", horizon=12)
    heat_env, heat_params = make_heatmap("thesis", obs_noise_std=0.1)
    tab_env, tab_params = make_tabular(asymmetric_model(), horizon=4)
    tab = TabularController(2, 3, tab_env.num_actions, tab_env.num_obs, tab_env.action_counts)
    tab_policy = tab.sample(jax.random.key(5), tab.init_distribution())
    one_env, one_params = make_tagging("thesis", horizon=1)
    cases = {}
    for name, env, params in [
        ("tagging", tag_env, tag_params),
        ("tagging-noisy", tag_env, noisy),
        ("tagging-paper", paper_env, paper_params),
        ("horizon-1", one_env, one_params),
    ]:
        ctrl = NeuralController(env.num_agents, 3, env.num_actions)
        cases[name] = (env, ctrl, params, ctrl.init(jax.random.key(1)))
    heat = NeuralController(heat_env.num_agents, 4, heat_env.num_actions, heat_env.obs_shape, 16)
    cases["heatmap-noisy"] = (heat_env, heat, heat_params, heat.init(jax.random.key(2)))
    cases["tabular"] = (tab_env, tab, tab_params, tab_policy)
    return cases


NAMES = ["heatmap-noisy", "horizon-1", "tabular", "tagging", "tagging-noisy", "tagging-paper"]


def test_the_names_are_the_cases():
    assert sorted(_cases()) == NAMES


@pytest.mark.parametrize("name", NAMES)
def test_rollouts_equal_the_plain_engine(name):
    env, ctrl, params, policy = _cases()[name]

    @jax.jit
    def both(k):  # one program: the returns of 257 rollouts and the record of 33
        return (
            rollouts(env, ctrl, k, 257, params, policy),
            plain_rollouts(env, ctrl, k, 257, params, policy),
            rollouts(env, ctrl, k, 33, params, policy, record=True),
            plain_rollouts(env, ctrl, k, 33, params, policy, record=True),
        )

    returns, plain, got, want = both(jax.random.key(11))
    np.testing.assert_allclose(returns, plain, rtol=1e-6, atol=1e-5)
    for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(want)):
        if jnp.issubdtype(a.dtype, jnp.integer):
            np.testing.assert_array_equal(a, b)  # nodes, actions: the same draws
        else:  # floats may differ in the last bit where XLA fuses differently (noise)
            np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6)
    assert got.nodes.shape[:2] == (33, env.horizon)


def _three_candidates(name):
    """Three policies of case ``name`` stacked on a leading axis, and ``(policies, axes)`` of
    three that share the case's networks (None for a tabular controller)."""
    _, ctrl, _, policy = _cases()[name]
    keys = jax.random.split(jax.random.key(4), 3)
    if isinstance(ctrl, TabularController):
        return jax.vmap(ctrl.sample, (0, None))(keys, ctrl.init_distribution()), None
    stacked = jax.vmap(ctrl.init)(keys)
    shape = stacked.action_probs.shape
    probs = jax.random.dirichlet(jax.random.key(6), jnp.ones(shape[-1]), shape[:-1])
    stacked = stacked.replace(action_probs=probs)
    # the case's networks for all three: only the action tables are batched
    shared = stacked.replace(net_params=policy.net_params)
    return stacked, (shared, type(policy)(action_probs=0, net_params=None))


@pytest.mark.parametrize("name", ["tabular", "tagging-noisy"])
def test_candidates_evaluated_together_equal_each_one_alone(name):
    """``evaluate_candidates`` advances all candidates in one scan: its means are those of
    ``vmap`` over the candidates of one policy's rollouts, bit for bit, with common random
    numbers or a key per candidate, and with networks shared by the candidates."""
    env, ctrl, params, _ = _cases()[name]
    stacked, shared = _three_candidates(name)

    def alone(k, policy):
        return rollouts(env, ctrl, k, 65, params, policy).mean()

    @jax.jit
    def both(k):
        out = {
            "crn": (
                evaluate_candidates(env, ctrl, k, 65, params, stacked),
                jax.vmap(alone, (None, 0))(k, stacked),
            ),
            "own keys": (
                evaluate_candidates(env, ctrl, k, 65, params, stacked, common_random_numbers=False),
                jax.vmap(alone)(jax.random.split(k, 3), stacked),
            ),
        }
        if shared is not None:
            policies, axes = shared
            out["shared networks"] = (
                evaluate_candidates(env, ctrl, k, 65, params, policies, policy_axes=axes),
                jax.vmap(alone, (None, axes))(k, policies),
            )
        return out

    for what, (together, each) in both(jax.random.key(9)).items():
        np.testing.assert_array_equal(together, each, err_msg=what)
        assert len(set(np.asarray(each).tolist())) > 1, what  # three different candidates


def test_long_horizon_returns_are_summed_without_drift():
    """Past ``COMPENSATED_AFTER`` steps the returns are a compensated sum: 200,000 steps of
    reward 0.1 (undiscounted) sum to 20,000 within float32's rounding of the total, where a plain
    float32 sum drifts by 0.2% (a wrong fourth digit); up to it, the plain sum as before."""
    from cognet_jax.io.dpomdp import parse_dpomdp
    from cognet_jax.rollout import COMPENSATED_AFTER

    text = "\n".join(
        [
            "agents: 2",
            "discount: 1",
            "values: reward",
            "states: 1",
            "start: uniform",
            "actions:",
            "1",
            "1",
            "observations:",
            "1",
            "1",
            "T: * : * : * : 1",
            "O: * : * : * : 1",
            "R: * : * : * : * : 0.1",
        ]
    )
    reward = float(np.float32(0.1))
    for horizon in (COMPENSATED_AFTER // 4, 200_000):
        env, params = make_tabular(parse_dpomdp(text + "\n"), horizon=horizon)
        ctrl = TabularController(2, 1, env.num_actions, env.num_obs, env.action_counts)
        policy = ctrl.sample(jax.random.key(0), ctrl.init_distribution())
        got = np.asarray(rollouts(env, ctrl, jax.random.key(1), 3, params, policy))
        plain = np.cumsum(np.full(horizon, reward, np.float32), dtype=np.float32)[-1]
        want = plain if horizon <= COMPENSATED_AFTER else horizon * reward
        np.testing.assert_allclose(got, want, rtol=1e-6)
    assert abs(plain - want) > 1e-3 * want  # the plain sum would have failed at this horizon
