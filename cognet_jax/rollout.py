"""Batched rollouts: ``lax.scan`` over time, vectorised over rollouts (and over candidate
policies one level up). Works with any environment of ``cognet_jax.envs.base`` and any
controller kind of ``cognet_jax.controllers``.

Per time step t (SPEC section 1): every agent draws ``a_t`` from its node, the environment
returns ``r_t = R(s_t, a_t)``, ``s_{t+1}`` and ``z_{t+1}``, every agent moves to
``q_{t+1} ~ g(. | q_t, z_{t+1})``. The return is ``sum_t gamma^t r_t`` with ``gamma`` read from
``env_params.discount``. All agents start in node 0.

Random numbers: one key drives a whole batch of rollouts. Each time step draws one block of
uniforms ``[rollouts, 2 agents + env.step_noise]`` (the controller's action and transition draws,
then the simulator's noise), so there is one generator call per step for all rollouts instead of
one per rollout. Common random numbers across candidate policies = the same key for every
candidate: under ``vmap`` over candidates the block is drawn once and shared.

Speed without changing a number: a step's block is drawn one step ahead and carried through
the scan, so it is computed once, in a kernel of its own, and stored; drawn inside the step,
XLA fused the generator into every kernel that reads the block (the action draw, the env
step's outputs, the node draw) and computed it again in each, without vectorising it. Threefry
keys are drawn through ``prng.fast_key`` (the same stream, written out without JAX's CPU loop).
tests/test_rollout.py checks both against the plain scan that draws inside each step.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from cognet_jax.memory import candidate_chunk
from cognet_jax.prng import fast_key


@struct.dataclass
class Trajectory:
    """What a batch of R rollouts did (leading axis R).

    ``nodes [R, H, agents]`` q_t, ``actions [R, H, agents]`` a_t, ``obs [R, H, agents, *obs_shape]``
    z_{t+1}, ``next_nodes [R, H, agents]`` q_{t+1}, ``rewards [R, H]`` r_t, ``ret [R]`` discounted
    return.
    """

    nodes: jax.Array
    actions: jax.Array
    obs: jax.Array
    next_nodes: jax.Array
    rewards: jax.Array
    ret: jax.Array


def shard_rollouts(tree):
    """Lay the leading ``[rollouts]`` axis of every leaf over the ``"rollouts"`` axis of the
    active mesh (``jax.set_mesh``); without such a mesh the arrays are returned unchanged."""
    mesh = jax.sharding.get_abstract_mesh()
    if mesh.empty or "rollouts" not in mesh.axis_names:
        return tree
    spec = jax.sharding.PartitionSpec("rollouts")
    return jax.tree.map(lambda x: jax.lax.with_sharding_constraint(x, spec), tree)


def rollouts(
    env, controller, key: jax.Array, num: int, env_params: Any, policy: Any, record: bool = False
):
    """``num`` rollouts of one (stochastic or deterministic) joint ``policy``.

    Returns the discounted returns ``[num]``, or a ``Trajectory`` when ``record`` is true.
    """
    n, h = env.num_agents, env.horizon
    k_reset, k_steps = jax.random.split(key)
    states = jax.vmap(env.reset, (0, None))(
        shard_rollouts(jax.random.uniform(fast_key(k_reset), (num, env.reset_noise))), env_params
    )
    gamma = jnp.asarray(env_params.discount, jnp.float32)
    act = jax.vmap(controller.act, (0, None, 0))
    move = jax.vmap(controller.next_node, (0, None, 0, 0))
    env_step = jax.vmap(env.step, (0, 0, 0, None))

    width = 2 * n + env.step_noise

    def draw(k):
        u = shard_rollouts(jax.random.uniform(fast_key(k), (num, width)))
        return u[:, : 2 * n], u[:, 2 * n :]

    def one_step(carry, u):
        states, nodes, ret, disc = carry
        u_ctrl, u_env = u
        actions = act(u_ctrl[:, :n], policy, nodes)
        states, obs, reward = env_step(u_env, states, actions, env_params)
        next_nodes = move(u_ctrl[:, n:], policy, nodes, obs)
        ret = ret + disc * reward
        out = (nodes, actions, obs, next_nodes, reward) if record else None
        return (states, next_nodes, ret, disc * gamma), out

    def body(carry, k_next):
        carry, u = carry
        carry, out = one_step(carry, u)
        return (carry, draw(k_next)), out

    step_keys = jax.random.split(k_steps, h)
    init = (states, jnp.zeros((num, n), jnp.int32), jnp.zeros(num, jnp.float32), jnp.float32(1.0))
    (carry, u_last), out = jax.lax.scan(body, (init, draw(step_keys[0])), step_keys[1:])
    (_, _, ret, _), out_last = one_step(carry, u_last)
    if not record:
        return ret
    out = jax.tree.map(lambda a, b: jnp.concatenate([a, b[None]]), out, out_last)
    nodes, actions, obs, next_nodes, rewards = (jnp.swapaxes(x, 0, 1) for x in out)
    return Trajectory(nodes, actions, obs, next_nodes, rewards, ret)


def evaluate_candidates(
    env,
    controller,
    key: jax.Array,
    num: int,
    env_params: Any,
    policies: Any,
    policy_axes: Any = 0,
    memory: int | None = None,
    common_random_numbers: bool = True,
) -> jax.Array:
    """Mean return ``[C]`` of C candidate policies, each rolled out ``num`` times: all with the
    same ``key`` (common random numbers) or, with ``common_random_numbers=False``, candidate c
    with ``split(key, C)[c]``. ``policy_axes`` is the vmap ``in_axes`` prefix of ``policies``
    (e.g. batch only the action tables and share the networks).

    ``memory``: bytes the ``C x num`` rollouts in flight may take (None: half the machine,
    ``memory.budget_bytes``). When they do not fit, the candidates are evaluated a chunk at a
    time (``lax.map`` with ``batch_size``): every rollout's return is bit for bit the same as
    unchunked, and so is each mean up to its last bit (XLA sums a row in an order that depends
    on the batch shape). One candidate's ``num`` rollouts over the budget raise
    ``errors.ResourceError`` while tracing, before anything compiles.
    """

    def one(k, policy):
        return rollouts(env, controller, k, num, env_params, policy).mean()

    def mapped(fn):
        """``fn`` applied to the batched part of a subtree of ``policies``, per its axis."""
        return lambda ax, sub: sub if ax is None else jax.tree.map(fn, sub)

    def candidate(fn):
        return jax.tree.map(mapped(fn), policy_axes, policies, is_leaf=lambda x: x is None)

    count = jax.tree.leaves(candidate(lambda x: x))[0].shape[0]
    keys = key if common_random_numbers else jax.random.split(key, count)
    key_axis = None if common_random_numbers else 0
    chunk = candidate_chunk(
        lambda k, p, n, e: rollouts(env, controller, k, n, e, p),
        env_params,
        candidate(lambda x: x[0]),
        count,
        num,
        memory,
        cache=(id(env), id(controller)),
    )
    if chunk >= count:
        return jax.vmap(one, in_axes=(key_axis, policy_axes))(keys, policies)

    def by_index(i):
        return one(keys if common_random_numbers else keys[i], candidate(lambda x: x[i]))

    return jax.lax.map(by_index, jnp.arange(count), batch_size=chunk)


def many_returns(
    env, controller, key: jax.Array, env_params: Any, policy: Any, num: int, batch: int = 10_000
) -> jax.Array:
    """Returns ``[num]`` of ``num`` rollouts, computed ``batch`` at a time (bounded memory);
    chunk c uses ``fold_in(key, c)``."""
    if num <= batch:
        return rollouts(env, controller, key, num, env_params, policy)
    chunks = -(-num // batch)
    out = jax.lax.map(
        lambda c: rollouts(env, controller, jax.random.fold_in(key, c), batch, env_params, policy),
        jnp.arange(chunks),
    )
    return out.reshape(-1)[:num]


def mean_and_stderr(returns: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Mean and standard error of a 1-D array of returns."""
    r = returns.astype(jnp.float32)
    return r.mean(), r.std(ddof=1) / jnp.sqrt(r.shape[0])
