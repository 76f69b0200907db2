"""The single-thread numpy reference of the rollout benchmark runs the same process as the JAX
engine: same controller (weights converted), same simulator, so the same mean return up to
sampling noise (the random streams differ)."""

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks import numpy_reference
from cognet_jax.controllers.neural import NeuralController, NeuralPolicy
from cognet_jax.envs.tagging import make_tagging
from cognet_jax.rollout import rollouts


def _as_jax(policy: dict) -> NeuralPolicy:
    net = {
        "params": {
            "Dense_0": {"kernel": jnp.asarray(policy["w1"])[:, :, None, :], "bias": policy["b1"]},
            "Dense_1": {"kernel": jnp.asarray(policy["w2"]), "bias": policy["b2"]},
        }
    }
    return NeuralPolicy(action_probs=jnp.asarray(policy["action_probs"]), net_params=net)


def test_numpy_rollouts_have_the_jax_engines_mean():
    policy = numpy_reference.random_policy(nodes=3, seed=1)
    # a non-uniform action table, so the nodes matter
    policy["action_probs"] = np.array(
        [[[0.7, 0.2, 0.1], [0.1, 0.8, 0.1], [0.2, 0.1, 0.7]]] * 2, np.float32
    )
    # sharper node networks, so the observation matters
    policy["w2"] = policy["w2"] * 20.0
    num = 40_000
    ours = numpy_reference.rollout_returns(policy, num, seed=3)
    env, params = make_tagging("thesis")
    ctrl = NeuralController(num_agents=2, num_nodes=3, num_actions=3, hidden=10)
    ref = np.asarray(
        jax.jit(lambda k: rollouts(env, ctrl, k, num, params, _as_jax(policy)))(jax.random.key(0))
    )
    se = np.sqrt(ours.var() / num + ref.var() / num)
    assert abs(ours.mean() - ref.mean()) < 4 * se, (ours.mean(), ref.mean(), se)
    # a controller that differs only in its transitions has a measurably different value
    other = dict(policy, w2=-policy["w2"])
    moved = numpy_reference.rollout_returns(other, num, seed=3)
    assert abs(moved.mean() - ours.mean()) > 4 * se


def test_throughput_reports_agent_steps():
    timing, rate = numpy_reference.throughput(nodes=3, num=1_000, runs=2)
    assert timing.median_s > 0 and rate == 1_000 * 3 * 2 / timing.median_s
