"""Batched rollouts: ``lax.scan`` over time inside ``vmap`` over rollouts (and over candidate
policies one level up). Works with any environment of ``cognet_jax.envs.base`` and any
controller kind of ``cognet_jax.controllers``.

Per time step t (SPEC section 1): every agent draws ``a_t`` from its node, the environment
returns ``r_t = R(s_t, a_t)``, ``s_{t+1}`` and ``z_{t+1}``, every agent moves to
``q_{t+1} ~ g(. | q_t, z_{t+1})``. The return is ``sum_t gamma^t r_t`` with ``gamma`` read from
``env_params.discount``.

Random numbers: one key per rollout; it is split once into the reset key, one block of uniforms
``[horizon, 2, agents]`` for the controller's draws and ``horizon`` step keys for the simulator.
Common random numbers across candidate policies = the same rollout keys for every candidate.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from flax import struct


@struct.dataclass
class Trajectory:
    """What one rollout did; batched rollouts add leading axes.

    ``nodes [H, agents]`` q_t, ``actions [H, agents]`` a_t, ``obs [H, agents, *obs_shape]``
    z_{t+1}, ``next_nodes [H, agents]`` q_{t+1}, ``rewards [H]`` r_t, ``ret []`` discounted return.
    """

    nodes: jax.Array
    actions: jax.Array
    obs: jax.Array
    next_nodes: jax.Array
    rewards: jax.Array
    ret: jax.Array


def rollout(env, controller, key: jax.Array, env_params: Any, policy: Any, record: bool = False):
    """One rollout of ``policy``; returns the discounted return ``[]``, or a ``Trajectory`` when
    ``record`` is true."""
    n, h = env.num_agents, env.horizon
    k_reset, k_u, k_env = jax.random.split(key, 3)
    state = env.reset(k_reset, env_params)
    uniforms = jax.random.uniform(k_u, (h, 2, n))
    step_keys = jax.random.split(k_env, h)
    gamma = jnp.asarray(env_params.discount, jnp.float32)

    def body(carry, xs):
        state, nodes, ret, disc = carry
        u, k = xs
        actions = controller.act(u[0], policy, nodes)
        state, obs, reward = env.step(k, state, actions, env_params)
        next_nodes = controller.next_node(u[1], policy, nodes, obs)
        ret = ret + disc * reward
        out = (nodes, actions, obs, next_nodes, reward) if record else None
        return (state, next_nodes, ret, disc * gamma), out

    init = (state, jnp.zeros(n, jnp.int32), jnp.float32(0.0), jnp.float32(1.0))
    (_, _, ret, _), out = jax.lax.scan(body, init, (uniforms, step_keys))
    if not record:
        return ret
    nodes, actions, obs, next_nodes, rewards = out
    return Trajectory(nodes, actions, obs, next_nodes, rewards, ret)


def rollouts(env, controller, keys: jax.Array, env_params: Any, policy: Any, record: bool = False):
    """Rollouts of one policy, one per key in ``keys [R]``: returns ``[R]`` or a batched
    ``Trajectory`` with leading axis R."""
    return jax.vmap(lambda k: rollout(env, controller, k, env_params, policy, record))(keys)


def evaluate_candidates(
    env, controller, keys: jax.Array, env_params: Any, policies: Any, policy_axes: Any = 0
) -> jax.Array:
    """Mean return ``[C]`` of C candidate policies, each rolled out on the same ``keys [R]``
    (common random numbers). ``policy_axes`` is the vmap ``in_axes`` prefix of ``policies``
    (e.g. batch only the action tables and share the networks)."""

    def one(policy):
        return rollouts(env, controller, keys, env_params, policy).mean()

    return jax.vmap(one, in_axes=(policy_axes,))(policies)


def mean_and_stderr(returns: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Mean and standard error of a 1-D array of returns."""
    r = returns.astype(jnp.float32)
    return r.mean(), r.std(ddof=1) / jnp.sqrt(r.shape[0])


def many_returns(env, controller, key: jax.Array, env_params: Any, policy: Any, num: int,
                 batch: int = 10_000) -> jax.Array:
    """Returns ``[num]`` of ``num`` rollouts, computed ``batch`` at a time (bounded memory)."""
    keys = jax.random.split(key, num)
    if num <= batch:
        return rollouts(env, controller, keys, env_params, policy)
    chunks = -(-num // batch)
    pad = chunks * batch - num
    keys = jnp.concatenate([keys, keys[:pad]]).reshape(chunks, batch)
    out = jax.lax.map(lambda ks: rollouts(env, controller, ks, env_params, policy), keys)
    return out.reshape(-1)[:num]
