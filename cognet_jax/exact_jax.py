"""Exact finite-horizon values of deterministic joint controllers on tabular Dec-POMDPs, in JAX.

The compiled counterpart of :func:`cognet_jax.exact.exact_values` (numpy), for use *inside* a
search iteration: G-DICE with ``algorithm.evaluator = "exact"`` ranks its samples by these
values instead of Monte Carlo means, so the elite threshold compares noise-free numbers.

Recursion over joint nodes ``q = (q_1, ..., q_n)`` (mixed radix, last agent fastest) and states,
with the joint action ``ja(q)`` and the next joint node ``next(q, jo)`` read from the per-agent
tables::

    V_h[q, s] = 0
    V_t[q, s] = R[s, ja(q)] + gamma * sum_{s', jo} T[s, ja(q), s'] O[ja(q), s', jo]
                                                   V_{t+1}[next(q, jo), s']
    value     = sum_s b0[s] V_0[0, s]          (every agent starts in node 0)

which is ``E[sum_{t<h} gamma^t r_t]``, exactly what the rollouts estimate. Cost per controller:
``h * Q * S * S' * JO`` multiply-adds with ``Q = nodes^agents``, so this is meant for the small
controllers and models G-DICE is run on (``exact_cost`` lets callers refuse large ones).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from cognet_jax.controllers.tabular import DeterministicTabularPolicy
from cognet_jax.envs.tabular import TabularEnv, TabularParams, _strides


def exact_cost(env: TabularEnv, nodes: int) -> int:
    """Multiply-adds of one controller's evaluation: ``h * nodes^agents * S^2 * JO``."""
    q = nodes**env.num_agents
    return env.horizon * q * env.num_states**2 * env.num_joint_obs


def _joint_tables(env: TabularEnv, policy: DeterministicTabularPolicy, nodes: int):
    """``ja [Q]`` joint action of each joint node and ``nxt [Q, JO]`` next joint node."""
    n = env.num_agents
    node_strides = jnp.asarray(_strides((nodes,) * n), jnp.int32)  # [agents]
    q = jnp.arange(nodes**n, dtype=jnp.int32)
    q_agents = (q[:, None] // node_strides) % nodes  # [Q, agents]
    agents = jnp.arange(n)
    acts = policy.actions[agents[None, :], q_agents]  # [Q, agents]
    ja = jax.vmap(env.joint_action)(acts)  # [Q]
    jo = jnp.arange(env.num_joint_obs, dtype=jnp.int32)
    obs = jax.vmap(env.split_joint_obs)(jo)  # [JO, agents]
    nxt_agents = policy.transitions[
        agents[None, None, :], q_agents[:, None, :], obs[None, :, :]
    ]  # [Q, JO, agents]
    nxt = jnp.sum(nxt_agents * node_strides, axis=-1)  # [Q, JO]
    return ja, nxt


def exact_value(
    env: TabularEnv, params: TabularParams, policy: DeterministicTabularPolicy, nodes: int
) -> jax.Array:
    """Exact ``E[sum_{t<h} gamma^t r_t]`` ``[]`` of one deterministic joint controller
    (``policy.actions [agents, nodes]``, ``policy.transitions [agents, nodes, obs]``) over the
    env's horizon, from node 0 and ``s_0 ~ b0``. vmap it over a batch of controllers."""
    ja, nxt = _joint_tables(env, policy, nodes)
    reward = params.reward[:, ja].T  # [Q, S]
    trans = jnp.moveaxis(params.transition[:, ja, :], 1, 0)  # [Q, S, S']
    obs = params.observation[ja]  # [Q, S', JO]
    gamma = jnp.asarray(params.discount, jnp.float32)

    def backup(v_next, _):
        # v_next [Q, S'] -> value of the successor joint node per (q, jo, s')
        succ = v_next[nxt]  # [Q, JO, S']
        cont = jnp.einsum("qsp,qpo,qop->qs", trans, obs, succ)
        return reward + gamma * cont, None

    q, s = reward.shape
    v0, _ = jax.lax.scan(backup, jnp.zeros((q, s), jnp.float32), None, length=env.horizon)
    return v0[0] @ params.initial_belief


def exact_values_numpy_layout(env, params, actions, transitions, nodes: int) -> np.ndarray:
    """Convenience for tests: values ``[B]`` of ``actions [B, agents, nodes]``,
    ``transitions [B, agents, nodes, obs]`` given as arrays."""
    pol = DeterministicTabularPolicy(
        actions=jnp.asarray(actions, jnp.int32), transitions=jnp.asarray(transitions, jnp.int32)
    )
    return np.asarray(jax.vmap(lambda p: exact_value(env, params, p, nodes))(pol))
