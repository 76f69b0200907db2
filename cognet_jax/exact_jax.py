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

import functools

import jax
import jax.numpy as jnp

from cognet_jax.controllers.tabular import DeterministicTabularPolicy
from cognet_jax.envs.tabular import TabularEnv, TabularParams, _strides


def exact_cost(env: TabularEnv, nodes: int, params: TabularParams | None = None) -> int:
    """Multiply-adds of one controller's evaluation: ``h * nodes^agents * S * (K + JO)`` with
    K = S, or the successors per row of a sparse model (``params.successors``); ``nodes``: the
    joint nodes of one time step are ``nodes^agents`` (for a layered controller, its width)."""
    q = nodes**env.num_agents
    k = env.num_states
    if params is not None and params.successors is not None:
        k = params.successors.shape[-1]
    return env.horizon * q * env.num_states * (k + env.num_joint_obs)


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


def _after_observation(params: TabularParams, ja, nxt, v_next) -> jax.Array:
    """``[Q, S']``: the expected ``v_next`` over the joint observation drawn in state ``s'``
    under joint action ``ja [Q]``, moving to joint node ``nxt [Q, JO]``; over the listed
    outcomes where the observation rows are sparse (``obs_outcomes``: one of 81 on the 3 x 3
    grid), else over every joint observation."""
    if params.obs_outcomes is None:
        return jnp.einsum("qpo,qop->qp", params.observation[ja], v_next[nxt])
    outcomes = params.obs_outcomes[ja]  # [Q, S', Ko]
    probs = params.obs_outcome_probs[ja]  # [Q, S', Ko]
    nodes = jax.vmap(lambda n, o: n[o])(nxt, outcomes)  # [Q, S', Ko]
    states = jnp.arange(v_next.shape[1])[None, :, None]
    return jnp.sum(probs * v_next[nodes, states], axis=-1)


def _backup(params: TabularParams, ja, nxt, v_next, gamma):
    """One step of the recursion for joint nodes with joint actions ``ja [Q]`` and successors
    ``nxt [Q, JO]`` (indices into ``v_next [Q', S']``); returns ``V [Q, S]``."""
    reward = params.reward[:, ja].T  # [Q, S]
    if params.successors is None and params.obs_outcomes is None:
        trans = jnp.moveaxis(params.transition[:, ja, :], 1, 0)  # [Q, S, S']
        obs, succ = params.observation[ja], v_next[nxt]  # [Q, S', JO], [Q, JO, S']
        return reward + gamma * jnp.einsum("qsp,qpo,qop->qs", trans, obs, succ)
    after = _after_observation(params, ja, nxt, v_next)  # [Q, S']
    if params.successors is None:
        trans = jnp.moveaxis(params.transition[:, ja, :], 1, 0)  # [Q, S, S']
        cont = jnp.einsum("qsp,qp->qs", trans, after)
    else:  # sparse rows: E over jo first, then over the K successors of every (s, ja)
        nxt_s = jnp.moveaxis(params.successors[:, ja, :], 1, 0)  # [Q, S, K]
        probs = jnp.moveaxis(params.successor_probs[:, ja, :], 1, 0)  # [Q, S, K]
        cont = jnp.sum(probs * jax.vmap(lambda w, i: w[i])(after, nxt_s), axis=-1)
    return reward + gamma * cont


@functools.partial(jax.jit, static_argnums=(0, 3))
def exact_value(
    env: TabularEnv, params: TabularParams, policy: DeterministicTabularPolicy, nodes: int
) -> jax.Array:
    """Exact ``E[sum_{t<h} gamma^t r_t]`` ``[]`` of one deterministic joint controller
    (``policy.actions [agents, nodes]``, ``policy.transitions [agents, nodes, obs]``) over the
    env's horizon, from node 0 and ``s_0 ~ b0``. vmap it over a batch of controllers. A ``jit``
    (``env`` and ``nodes`` static; inlined inside a program): one program where it is called
    eagerly, not each operation of the joint tables."""
    ja, nxt = _joint_tables(env, policy, nodes)
    gamma = jnp.asarray(params.discount, jnp.float32)
    q, s = nxt.shape[0], env.num_states
    v0, _ = jax.lax.scan(
        lambda v, _: (_backup(params, ja, nxt, v, gamma), None),
        jnp.zeros((q, s), jnp.float32),
        None,
        length=env.horizon,
    )
    return v0[0] @ params.initial_belief


@functools.partial(jax.jit, static_argnums=(0, 3))
def exact_value_layered(
    env: TabularEnv, params: TabularParams, policy: DeterministicTabularPolicy, width: int
) -> jax.Array:
    """:func:`exact_value` of a time-layered controller with ``env.horizon`` layers of
    ``width`` nodes (``TabularController(layers=horizon)``): the recursion at time t runs over
    the ``width^agents`` joint nodes of layer t only, so one evaluation costs
    ``h * width^agents * S * (S' + JO)`` instead of ``h * (h * width)^agents * ...``."""
    acts, local = _layer_tables(env, policy, width)  # [h, agents, W], [h, agents, W, obs]
    gamma = jnp.asarray(params.discount, jnp.float32)
    ja, nxt = jax.vmap(lambda a, t: _joint_tables(env, DeterministicTabularPolicy(a, t), width))(
        acts, local
    )  # [h, Q], [h, Q, JO]
    # the last layer earns its rewards only: h - 1 backups instead of h, the same numbers;
    # from h 4 on, of the first layer only joint node 0 (where every run starts) is computed
    # too, which saves time; not below h 4, where the separate first layer raised the peak
    # memory of the largest test model's run above the suite's bound (tests/test_models.py;
    # benchmarks/NOTES.md, "Measurements behind code choices")
    v = params.reward[:, ja[-1]].T  # [Q, S]: V at the last step
    if env.horizon == 1:
        return v[0] @ params.initial_belief

    def backup(v_next, layer):
        return _backup(params, layer[0], layer[1], v_next, gamma), None

    if env.horizon < 4:
        v, _ = jax.lax.scan(backup, v, (ja[:-1], nxt[:-1]), reverse=True)
        return v[0] @ params.initial_belief
    v, _ = jax.lax.scan(backup, v, (ja[1:-1], nxt[1:-1]), reverse=True)
    v0 = _backup(params, ja[0, :1], nxt[0, :1], v, gamma)  # [1, S]: joint node 0 only
    return v0[0] @ params.initial_belief


def _layer_tables(env: TabularEnv, policy: DeterministicTabularPolicy, width: int):
    """A layered controller's per-layer local tables: ``acts [h, agents, W]`` and ``local
    [h, agents, W, obs]`` (next nodes as indices into the next layer; the last layer's are
    never used and read as 0)."""
    h, n = env.horizon, env.num_agents
    acts = jnp.moveaxis(policy.actions.reshape(n, h, width), 1, 0)
    trans = policy.transitions.reshape(n, h, width, -1)
    first_of_next = jnp.minimum(jnp.arange(h) + 1, h - 1) * width  # [h]
    local = jnp.clip(trans - first_of_next[None, :, None, None], 0, width - 1)
    return acts, jnp.moveaxis(local, 1, 0)


def push_belief(params: TabularParams, belief: jax.Array, ja: jax.Array) -> jax.Array:
    """``sum_s belief[s] T[s, ja, s']`` ``[S']`` for one joint action (dense or sparse rows)."""
    if params.successors is None:
        return belief @ params.transition[:, ja, :]
    probs = params.successor_probs[:, ja, :] * belief[:, None]  # [S, K]
    return jnp.zeros_like(belief).at[params.successors[:, ja, :]].add(probs)


def _occupancy_step(params: TabularParams, alpha, ja, nxt):
    """``alpha' [Q', S']``: the probability of joint node and state one step after ``alpha
    [Q, S]``, with joint actions ``ja [Q]`` and next joint nodes ``nxt [Q, JO]``."""
    mass = jax.vmap(lambda b, a: push_belief(params, b, a))(alpha, ja)  # [Q, S']
    split = mass[:, :, None] * params.observation[ja]  # [Q, S', JO]
    return jnp.zeros_like(alpha).at[nxt].add(jnp.moveaxis(split, 2, 1))


def layered_move_values(
    env: TabularEnv,
    params: TabularParams,
    policy: DeterministicTabularPolicy,
    width: int,
    moves: jax.Array,
    batch: int = 16,
) -> jax.Array:
    """Exact values ``[M]`` of ``policy`` (a layered controller, ``exact_value_layered``) with
    each one of ``moves [M, 5]`` applied (rows ``(kind, agent, node, obs, value)`` of
    :func:`cognet_jax.algorithms.polish.neighbour_moves`; ``agent = -1``: every agent).

    A move in layer t changes only what happens from time t on, and only through layer t's
    tables, so with the current controller's occupancy ``alpha_t [Q, S]`` (probability of
    joint node and state at time t), its rewards before t and its values ``V_{t+1}``, the
    changed controller's value is ``sum_{t'<t} gamma^t' E[r_t'] + gamma^t sum alpha_t V'_t``
    where ``V'_t`` is one backup of the changed layer: one layer per move instead of the
    whole horizon (the same numbers as evaluating each changed controller, up to float32
    rounding)."""
    h, n = env.horizon, env.num_agents
    acts, local = _layer_tables(env, policy, width)
    ja, nxt = jax.vmap(lambda a, t: _joint_tables(env, DeterministicTabularPolicy(a, t), width))(
        acts, local
    )  # [h, Q], [h, Q, JO]
    gamma = jnp.asarray(params.discount, jnp.float32)
    q_count = width**n

    def backward(v_next, layer):
        v = _backup(params, layer[0], layer[1], v_next, gamma)
        return v, v_next

    zero = jnp.zeros((q_count, env.num_states), jnp.float32)
    _, v_after = jax.lax.scan(backward, zero, (ja, nxt), reverse=True)  # [h]: V_{t+1}

    def forward(alpha, layer):
        return _occupancy_step(params, alpha, layer[0], layer[1]), alpha

    alpha0 = zero.at[0].set(params.initial_belief.astype(jnp.float32))
    _, alphas = jax.lax.scan(forward, alpha0, (ja, nxt))  # [h]: alpha_t
    rewards = jnp.einsum("tqs,tqs->t", alphas, jax.vmap(lambda a: params.reward[:, a].T)(ja))
    powers = gamma ** jnp.arange(h, dtype=jnp.float32)
    before = jnp.cumsum(powers * rewards) - powers * rewards  # [h]: sum over t' < t

    def value_of(move):
        kind, agent, node, obs, target = move[0], move[1], move[2], move[3], move[4]
        t, at = node // width, node % width
        rows = (agent < 0) | (jnp.arange(n) == agent)  # [agents]
        here = rows[:, None] & (jnp.arange(width) == at)[None, :]  # [agents, W]
        a_t = jnp.where((kind == 0) & here, target, acts[t])
        first = jnp.minimum(t + 1, h - 1) * width
        changed = here[..., None] & (jnp.arange(local.shape[-1]) == obs)
        l_t = jnp.where((kind == 1) & changed, jnp.clip(target - first, 0, width - 1), local[t])
        ja_t, nxt_t = _joint_tables(env, DeterministicTabularPolicy(a_t, l_t), width)
        v_t = _backup(params, ja_t, nxt_t, v_after[t], gamma)
        return before[t] + powers[t] * jnp.sum(alphas[t] * v_t)

    return jax.lax.map(value_of, moves, batch_size=batch)
