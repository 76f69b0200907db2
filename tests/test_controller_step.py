"""controller_step: a pure, jit/vmap-able controller step that runs the same process as the
rollout engine (checked against ``rollouts`` on the tagging problem), and the README example."""

import re
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cognet_jax import controller_step
from cognet_jax.controllers.neural import NeuralController
from cognet_jax.controllers.regions import reactive_tagging_policy
from cognet_jax.controllers.tabular import TabularController
from cognet_jax.envs.tagging import make_tagging
from cognet_jax.rollout import rollouts


def user_returns(env, params, policy, key, num):
    """Returns ``[num]`` of a hand-written simulation loop driven by ``controller_step``; the
    environment's random numbers are drawn exactly as ``rollouts`` draws them."""
    n = env.num_agents
    k_reset, k_steps = jax.random.split(key)
    states = jax.vmap(env.reset, (0, None))(
        jax.random.uniform(k_reset, (num, env.reset_noise)), params
    )
    ctrl_keys = jax.random.split(jax.random.fold_in(key, 99), (env.horizon, num))

    def one(state, env_u, keys):  # env_u [H, noise], keys [H]
        action, node = controller_step(policy, jnp.zeros(n, jnp.int32), None, keys[0])

        def body(carry, xs):
            state, action, node, ret, disc = carry
            u, k = xs
            state, obs, reward = env.step(u, state, action, params)
            action, node = controller_step(policy, node, obs, k)
            return (state, action, node, ret + disc * reward, disc * params.discount), None

        init = (state, action, node, jnp.float32(0.0), jnp.float32(1.0))
        (_, _, _, ret, _), _ = jax.lax.scan(body, init, (env_u, jnp.roll(keys, -1, axis=0)))
        return ret

    env_u = jax.vmap(lambda k: jax.random.uniform(k, (num, 2 * n + env.step_noise)))(
        jax.random.split(k_steps, env.horizon)
    )[:, :, 2 * n :]  # [H, num, noise]
    return jax.jit(jax.vmap(one, (0, 1, 1)))(states, env_u, ctrl_keys)


def engine_returns(env, params, controller, policy, key, num):
    return jax.jit(lambda k: rollouts(env, controller, k, num, params, policy))(key)


def test_region_controller_matches_rollouts_exactly():
    env, params = make_tagging("thesis", horizon=6, motion_noise=0.3, obs_noise=0.5)
    ctrl, policy = reactive_tagging_policy()
    key = jax.random.key(3)
    ours = user_returns(env, params, policy, key, 500)
    ref = engine_returns(env, params, ctrl, policy, key, 500)
    np.testing.assert_array_equal(np.asarray(ours), np.asarray(ref))
    assert np.unique(np.asarray(ref)).size > 3  # the episodes really differ


def test_tabular_controller_matches_rollouts_exactly():
    env, params = make_tagging("thesis", horizon=5, obs_division=2.0, obs_index=True)
    ctrl = TabularController(
        num_agents=2, num_nodes=4, num_actions=3, num_obs=env.num_obs, action_counts=(3, 3)
    )
    policy = ctrl.sample(jax.random.key(1), ctrl.init_distribution())
    key = jax.random.key(4)
    ours = user_returns(env, params, policy, key, 500)
    ref = engine_returns(env, params, ctrl, policy, key, 500)
    np.testing.assert_array_equal(np.asarray(ours), np.asarray(ref))


def _neural(sharpen: float):
    ctrl = NeuralController(num_agents=2, num_nodes=3, num_actions=3, hidden=10)
    policy = ctrl.init(jax.random.key(7))
    probs = jax.random.dirichlet(jax.random.key(8), jnp.ones(3), (2, 3))
    if sharpen > 1:  # one-hot actions, near-deterministic transitions
        probs = jax.nn.one_hot(jnp.argmax(probs, -1), 3)
        dense1 = policy.net_params["params"]["Dense_1"]
        scaled = jax.tree.map(lambda x: x * sharpen, dense1)
        policy.net_params["params"]["Dense_1"] = scaled
    return ctrl, policy.replace(action_probs=probs)


def test_neural_controller_deterministic_limit_matches_rollouts_exactly():
    env, params = make_tagging("thesis", horizon=5, obs_noise=0.3)
    ctrl, policy = _neural(sharpen=1e4)
    key = jax.random.key(5)
    ours = user_returns(env, params, policy, key, 400)
    ref = engine_returns(env, params, ctrl, policy, key, 400)
    np.testing.assert_array_equal(np.asarray(ours), np.asarray(ref))


def test_neural_controller_stochastic_same_value_as_rollouts():
    env, params = make_tagging("thesis")
    ctrl, policy = _neural(sharpen=1.0)
    num = 20_000
    ours = np.asarray(user_returns(env, params, policy, jax.random.key(1), num))
    ref = np.asarray(engine_returns(env, params, ctrl, policy, jax.random.key(2), num))
    se = np.sqrt(ours.var() / num + ref.var() / num)
    assert abs(ours.mean() - ref.mean()) < 4 * se
    assert abs(ours.mean() - ref.mean()) > 0 or se == 0  # different draws, not a copy


def test_action_frequencies_follow_the_policy():
    _, policy = _neural(sharpen=1.0)
    keys = jax.random.split(jax.random.key(0), 20_000)
    nodes = jnp.array([1, 2], jnp.int32)
    actions, _ = jax.vmap(lambda k: controller_step(policy, nodes, None, k))(keys)
    freq = np.stack([np.bincount(np.asarray(actions[:, i]), minlength=3) for i in range(2)])
    freq = freq / keys.shape[0]
    expected = np.asarray(policy.action_probs)[[0, 1], [1, 2]]
    np.testing.assert_allclose(freq, expected, atol=0.015)


def test_jit_vmap_equals_single_calls():
    ctrl, policy = _neural(sharpen=1.0)
    keys = jax.random.split(jax.random.key(0), 6)
    nodes = jnp.array([[0, 1], [2, 2], [1, 0], [0, 0], [2, 1], [1, 1]], jnp.int32)
    obs = jax.random.normal(jax.random.key(1), (6, 2))
    batched = jax.jit(jax.vmap(controller_step, (None, 0, 0, 0)))(policy, nodes, obs, keys)
    for b in range(6):
        single = controller_step(policy, nodes[b], obs[b], keys[b])
        np.testing.assert_array_equal(np.asarray(batched[0][b]), np.asarray(single[0]))
        np.testing.assert_array_equal(np.asarray(batched[1][b]), np.asarray(single[1]))


def test_tabular_distribution_and_bad_policy():
    ctrl = TabularController(num_agents=2, num_nodes=3, num_actions=3, num_obs=5)
    dist = ctrl.init_distribution()
    action, node = jax.jit(controller_step)(
        dist, jnp.array([0, 2]), jnp.array([4, 1]), jax.random.key(0)
    )
    assert action.shape == node.shape == (2,)
    assert int(node.max()) < 3 and int(action.max()) < 3
    with pytest.raises(TypeError, match="unsupported policy type"):
        controller_step({"not": "a policy"}, jnp.zeros(2, jnp.int32), None, jax.random.key(0))


def _encoded_case(sharpen: float = 1e4):
    """Heatmap (noisy sensors), an encoded 3-node controller over a random 2-D VAE encoder."""
    from types import SimpleNamespace

    from cognet_jax.controllers.encoded import portable_policy
    from cognet_jax.envs.heatmap import make_heatmap
    from cognet_jax.observations import ObservationPipeline, neural_controller
    from cognet_jax.vae import PatchVAE, TrainedVAE

    env, params = make_heatmap("default", horizon=5, obs_noise_std=0.01)
    model = PatchVAE(latent=2)
    vae = TrainedVAE(model, model.init(jax.random.key(0), jnp.zeros((1, 16)), jnp.zeros((1, 2))))
    pipeline = ObservationPipeline("encoded", env.obs_shape, vae)
    _, ctrl = neural_controller(env, 3, 10, pipeline)
    policy = ctrl.init(jax.random.key(7))
    probs = jax.random.dirichlet(jax.random.key(8), jnp.ones(4), (2, 3))
    policy = policy.replace(action_probs=jax.nn.one_hot(jnp.argmax(probs, -1), 4))
    dense1 = policy.net_params["params"]["Dense_1"]
    policy.net_params["params"]["Dense_1"] = jax.tree.map(lambda x: x * sharpen, dense1)
    portable = portable_policy(SimpleNamespace(pipeline=pipeline), policy)
    return env, params, ctrl, policy, portable


def test_encoded_policy_matches_rollouts_exactly():
    from cognet_jax.controllers.encoded import EncodedPolicy

    env, params, ctrl, policy, portable = _encoded_case()
    assert isinstance(portable, EncodedPolicy)
    key = jax.random.key(6)
    ours = user_returns(env, params, portable, key, 300)
    ref = engine_returns(env, params, ctrl, policy, key, 300)
    np.testing.assert_array_equal(np.asarray(ours), np.asarray(ref))
    assert np.unique(np.asarray(ref)).size > 3


def test_wrong_observation_shapes_are_refused():
    env, params, ctrl, policy, portable = _encoded_case()
    nodes = jnp.zeros(2, jnp.int32)
    patch = jnp.zeros((2, 16))
    # the bare policy of an encoded search reads 2 latent numbers, not the 16-pixel patch
    with pytest.raises(ValueError, match=r"reading 2 network inputs.*portable_policy"):
        controller_step(policy, nodes, patch, jax.random.key(0))
    with pytest.raises(ValueError, match=r"reading 16 raw observation values"):
        controller_step(portable, nodes, jnp.zeros((2, 2)), jax.random.key(0))
    with pytest.raises(ValueError, match=r"node of shape \(3,\).*2 agents"):
        controller_step(portable, jnp.zeros(3, jnp.int32), patch, jax.random.key(0))
    _, region = reactive_tagging_policy()
    with pytest.raises(ValueError, match=r"reading 1 scalar observation"):
        jax.jit(controller_step)(region, nodes, jnp.zeros((2, 3)), jax.random.key(0))
    action, node = jax.jit(controller_step)(portable, nodes, patch, jax.random.key(0))
    assert action.shape == node.shape == (2,)


def test_readme_embedding_example_runs():
    text = (Path(__file__).parents[1] / "README.md").read_text()
    section = text.split("## In your own JAX code", 1)[1]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    small = [  # the block as written, on a smaller search (its code is under test, not values)
        "algorithm.iterations=2",
        "algorithm.candidates=16",
        "algorithm.eval_rollouts=32",
        "algorithm.best_rollouts=64",
        "evaluation.rollouts=500",
    ]
    for old, new in (
        ('"algorithm.iterations=100"', ", ".join(f'"{x}"' for x in small)),
        ("jax.random.key(0), 8)", "jax.random.key(0), 2)"),
    ):
        assert old in code
        code = code.replace(old, new)
    assert "controller_step" in code
    namespace = {}
    exec(compile(code, "README.md", "exec"), namespace)
    assert np.isfinite(np.asarray(namespace["returns"])).all()
