"""Exact best response of one agent in a time-layered tabular controller (JESP-style polish).

The single-entry polish (:mod:`cognet_jax.algorithms.polish`) stops where no *one* table
entry helps. Box pushing h 4 showed the limit: most searches stopped at 97.28 where changing
one agent's action *and* its transitions together reaches 97.69. An agent's exact best
response to the others' fixed controllers makes every such change at once:

1. **Forward** over the agent's own (action, observation) histories, time step by time step:
   the unnormalised joint distribution ``B[path, s, r]`` of the state and the others' joint
   node ``r`` (mixed radix over the other agents' local nodes in the current layer) for every
   path ``(a_0, z_1, a_1, z_2, ...)``; ``(A_i Z_i)^t`` paths at step t.
2. **Backward**: ``V_t[path] = max_a ( gamma^t sum_{s,r} B R[s, ja(r, a)] + sum_z
   V_{t+1}[path a z] )``. ``V_0`` is the best value over every deterministic policy *tree* of
   the agent (Nair et al. 2003's JESP step), so no single-entry move of this agent beats it.
3. **Compression** into the agent's layers: from the last layer back, the reachable
   observation histories of the best tree are merged greedily into at most ``width`` classes
   per layer -- same action and the same child class after every observation, where a child
   of zero probability matches anything. When a layer needs more than ``width`` classes the
   response does not fit (``fits = False``) and the caller keeps the old controller;
   otherwise the new controller plays the best tree on every history of positive
   probability, so its exact value is ``V_0``.

What is maximised: the joint controller's exact expected return over the horizon, by the rows
of one agent. Cost (see :func:`best_response_cost`): ``sum_{t < h-1} (A Z)^t * A * r * S *
(K + JO)`` multiply-adds for agent i (the last step only sums rewards; ``r =
width^(agents-1)``, K = S or the successors per row), memory about ``(A Z)^(h-2) * S * r``
floats (the last step's beliefs are reduced as they are made).
"""

from __future__ import annotations

import itertools

import jax
import jax.numpy as jnp
import numpy as np

from cognet_jax.controllers.tabular import DeterministicTabularPolicy
from cognet_jax.envs.tabular import TabularEnv, TabularParams
from cognet_jax.exact_jax import push_belief

#: paths pushed forward together in one ``lax.map`` batch
PATH_BATCH = 64
#: :func:`best_response_cost` reports at most this (far above any limit it is compared with)
COST_CAP = 1 << 80


def best_response_cost(env: TabularEnv, width: int, agent: int, params=None) -> tuple[int, int]:
    """``(multiply-adds, floats held)`` of :func:`best_response` for ``agent``, each at most
    ``COST_CAP``."""
    h, s = env.horizon, env.num_states
    a, z = env.action_counts[agent], env.obs_counts[agent]
    r = width ** (env.num_agents - 1)
    k = s
    if params is not None and params.successors is not None:
        k = params.successors.shape[-1]
    paths = [1]  # histories with actions, per time step, capped (a long horizon would build
    for _ in range(h - 1):  # integers of millions of digits)
        paths.append(min(paths[-1] * a * z, COST_CAP))
    flops = sum(paths[:-1]) * a * r * s * (k + env.num_joint_obs) + paths[-1] * a * r * s
    memory = paths[max(h - 2, 0)] * s * r + paths[-1] * a
    return min(int(flops), COST_CAP), min(int(memory), COST_CAP)


def _other_tables(env: TabularEnv, policy: DeterministicTabularPolicy, width: int, agent: int):
    """Per layer t, for the others' joint local node ``r`` (first other agent slowest):
    ``ja [h, r, A_i]`` the joint action with the agent's own action, and ``nxt [h, r, JO]`` the
    others' joint local node at layer t + 1 after joint observation ``jo`` (0 at the last
    layer), with ``own_obs [JO]`` the agent's share of each joint observation."""
    n, h, w = env.num_agents, env.horizon, width
    others = [j for j in range(n) if j != agent]
    digits = np.array(list(itertools.product(range(w), repeat=len(others))), np.int32)
    digits = digits.reshape(-1, len(others))  # [r, others] (one row of nothing for n = 1)
    r_count = digits.shape[0]
    strides = w ** np.arange(len(others) - 1, -1, -1, dtype=np.int32)  # [others]
    jo = jnp.arange(env.num_joint_obs, dtype=jnp.int32)
    split = jax.vmap(env.split_joint_obs)(jo)  # [JO, agents]
    own_actions = jnp.arange(env.action_counts[agent], dtype=jnp.int32)

    def layer(t):
        nodes = t * w + jnp.asarray(digits)  # [r, others] node indices
        acts = jnp.zeros((r_count, n), jnp.int32)
        for k, j in enumerate(others):
            acts = acts.at[:, j].set(policy.actions[j, nodes[:, k]])
        full = jnp.broadcast_to(acts[:, None, :], (r_count, own_actions.size, n))
        full = full.at[:, :, agent].set(own_actions[None, :])
        ja = jax.vmap(jax.vmap(env.joint_action))(full)  # [r, A_i]
        nxt = jnp.zeros((r_count, env.num_joint_obs), jnp.int32)
        if t < h - 1:
            for k, j in enumerate(others):
                target = policy.transitions[j, nodes[:, k][:, None], split[None, :, j]]
                local = jnp.clip(target - (t + 1) * w, 0, w - 1)  # [r, JO]
                nxt = nxt + local * int(strides[k])
        return ja, nxt

    tables = [layer(t) for t in range(h)]
    ja = jnp.stack([t[0] for t in tables])
    nxt = jnp.stack([t[1] for t in tables])
    return ja, nxt, split[:, agent], r_count


def _merge_layer(acts, children, reach, width: int):
    """Greedy classes of one layer's histories: ``acts [U]``, ``children [U, Z]`` (child class
    or -1 for a child of zero probability), ``reach [U]``. Returns ``(cls [U]`` (-1 when
    unreachable), ``table_act [W]``, ``table_child [W, Z]``, ``count``, ``fits)``."""
    u_count, z = children.shape

    def assign(u, carry):
        cls, t_act, t_child, count, fits = carry
        a, ch = acts[u], children[u]
        agree = (t_child == ch[None, :]) | (t_child < 0) | (ch[None, :] < 0)
        ok = (jnp.arange(width) < count) & (t_act == a) & jnp.all(agree, axis=1)
        found = jnp.any(ok)
        c = jnp.where(found, jnp.argmax(ok), jnp.minimum(count, width - 1))
        room = found | (count < width)
        live = reach[u]
        merged = jnp.where(t_child[c] < 0, ch, t_child[c])
        t_act = jnp.where(live, t_act.at[c].set(a), t_act)
        t_child = jnp.where(live, t_child.at[c].set(merged), t_child)
        count = count + (live & ~found & room)
        cls = cls.at[u].set(jnp.where(live, c, -1))
        return cls, t_act, t_child, count, fits & (room | ~live)

    start = (
        jnp.full((u_count,), -1, jnp.int32),
        jnp.zeros((width,), jnp.int32),
        jnp.full((width, z), -1, jnp.int32),
        jnp.int32(0),
        jnp.bool_(True),
    )
    return jax.lax.fori_loop(0, u_count, assign, start)


def _path_expansion(env: TabularEnv, params: TabularParams, tables, agent: int):
    """``expand(t, belief)``: one history's ``belief [S, r]`` at step t -> its immediate
    rewards ``[A]`` and its children's beliefs ``[A, Z, S, r]`` (``None`` at the last step)."""
    ja, nxt, own_obs, r_count = tables
    h, s_count = env.horizon, env.num_states
    a_count, z_count = env.action_counts[agent], env.obs_counts[agent]
    gamma = jnp.asarray(params.discount, jnp.float32)
    # joint observation -> the agent's child slot z * r + r' (per others' node r)
    slot = own_obs * r_count + nxt  # [h, r, JO]

    def expand(t, belief):
        ja_t = ja[t]  # [r, A]
        rew = params.reward[:, ja_t]  # [S, r, A]
        imm = jnp.einsum("sr,sra->a", belief, rew) * gamma**t
        if t == h - 1:
            return imm, None
        pre = jax.vmap(
            lambda a: jax.vmap(lambda r: push_belief(params, belief[:, r], ja_t[r, a]))(
                jnp.arange(r_count)
            )
        )(jnp.arange(a_count))  # [A, r, S']
        joint = pre[..., None] * params.observation[ja_t.T]  # [A, r, S', JO]
        joint = jnp.moveaxis(joint, 2, 1).reshape(a_count, s_count, -1)  # [A, S', r*JO]
        seg = slot[t].reshape(-1)  # [r*JO]
        child = jnp.zeros((a_count, s_count, z_count * r_count), jnp.float32)
        child = child.at[:, :, seg].add(joint)
        child = child.reshape(a_count, s_count, z_count, r_count)
        return imm, jnp.moveaxis(child, 2, 1)  # [A, Z, S, r]

    return expand


def _forward(env: TabularEnv, params: TabularParams, tables, agent: int):
    """Step 1 of the module docstring: ``(immediate, masses)``, per step t the immediate
    rewards ``[P_t, A]`` and the probabilities ``[P_t]`` of the agent's ``P_t`` histories (the
    last step's beliefs are reduced as they are made)."""
    h, s_count, r_count = env.horizon, env.num_states, tables[3]
    a_count = env.action_counts[agent]
    expand = _path_expansion(env, params, tables, agent)

    def expand_last(t, belief):
        """Step ``h - 2``: immediate rewards ``[A]``, the children's ``[A, Z, A]`` and the
        children's probabilities ``[A, Z]`` (their beliefs are not kept)."""
        imm, kids = expand(t, belief)
        kid_imm = jax.vmap(jax.vmap(lambda b: expand(t + 1, b)[0]))(kids)
        return imm, kid_imm, kids.sum(axis=(2, 3))

    beliefs = jnp.zeros((1, s_count, r_count), jnp.float32)
    beliefs = beliefs.at[0, :, 0].set(params.initial_belief.astype(jnp.float32))
    immediate, masses = [], []
    if h == 1:
        masses.append(beliefs.sum(axis=(1, 2)))
        immediate.append(jax.vmap(lambda b: expand(0, b)[0])(beliefs))
    for t in range(h - 1):
        masses.append(beliefs.sum(axis=(1, 2)))
        if t == h - 2:
            imm, kid_imm, kid_mass = jax.lax.map(
                lambda b, t=t: expand_last(t, b), beliefs, batch_size=PATH_BATCH
            )
            immediate += [imm, kid_imm.reshape(-1, a_count)]  # [P, A], [P * A * Z, A]
            masses.append(kid_mass.reshape(-1))
            break
        imm, kids = jax.lax.map(lambda b, t=t: expand(t, b), beliefs, batch_size=PATH_BATCH)
        immediate.append(imm)  # [P, A]
        beliefs = kids.reshape(-1, s_count, r_count)  # [P * A * Z, S, r]
    return immediate, masses


def _best_tree(immediate, masses, a_count: int, z_count: int):
    """Step 2: ``(value [], acts, reach)`` -- the best tree's value and, per layer t, the action
    ``[Z^t]`` and whether it is reached ``[Z^t]`` for each of the agent's observation
    histories."""
    h = len(immediate)
    best_action = [None] * h
    value = None
    for t in reversed(range(h)):
        q = immediate[t]
        if value is not None:
            q = q + value.reshape(q.shape[0], a_count, z_count).sum(-1)
        best_action[t] = jnp.argmax(q, axis=1).astype(jnp.int32)
        value = jnp.max(q, axis=1)
    paths = [jnp.zeros((1,), jnp.int32)]
    for t in range(h - 1):
        p = paths[-1]
        nxt_p = (p * a_count + best_action[t][p])[:, None] * z_count + jnp.arange(z_count)
        paths.append(nxt_p.reshape(-1))
    acts = [best_action[t][paths[t]] for t in range(h)]
    reach = [masses[t][paths[t]] > 0 for t in range(h)]
    return value[0], acts, reach


def _compress(policy, agent: int, acts, reach, width: int, z_count: int):
    """Step 3: the best tree written into ``agent``'s layers; ``(policy, fits)``."""
    h = len(acts)
    rows_a, rows_t = policy.actions[agent], policy.transitions[agent]
    fits = jnp.bool_(True)
    child_cls = None
    for t in reversed(range(h)):
        u_count = z_count**t
        if child_cls is None:
            children = jnp.full((u_count, z_count), -1, jnp.int32)
        else:
            children = child_cls.reshape(u_count, z_count)
        cls, t_act, t_child, count, ok = _merge_layer(acts[t], children, reach[t], width)
        fits = fits & ok
        used = jnp.arange(width) < count
        base = t * width
        rows_a = rows_a.at[base : base + width].set(
            jnp.where(used, t_act, rows_a[base : base + width])
        )
        if t < h - 1:
            target = (t + 1) * width + jnp.maximum(t_child, 0)  # [W, Z_i]
            old = rows_t[base : base + width, :z_count]
            rows_t = rows_t.at[base : base + width, :z_count].set(
                jnp.where(used[:, None], target, old)
            )
        child_cls = cls
    new = DeterministicTabularPolicy(
        actions=policy.actions.at[agent].set(rows_a.astype(policy.actions.dtype)),
        transitions=policy.transitions.at[agent].set(rows_t.astype(policy.transitions.dtype)),
    )
    return new, fits


def best_response(
    env: TabularEnv,
    params: TabularParams,
    policy: DeterministicTabularPolicy,
    width: int,
    agent: int,
) -> tuple[DeterministicTabularPolicy, jax.Array, jax.Array]:
    """``agent``'s exact best response to the others' rows of the layered ``policy``
    (``actions [agents, horizon * width]``, ``transitions [agents, horizon * width, obs]``),
    written into its rows. Returns ``(policy, value, fits)``: ``value`` ``[]`` is the best
    tree's exact return (float32); when ``fits`` is False the response needs more than
    ``width`` nodes in some layer and ``policy`` is returned unchanged. jit-able."""
    a_count, z_count = env.action_counts[agent], env.obs_counts[agent]
    tables = _other_tables(env, policy, width, agent)
    immediate, masses = _forward(env, params, tables, agent)
    best_value, acts, reach = _best_tree(immediate, masses, a_count, z_count)
    new, fits = _compress(policy, agent, acts, reach, width, z_count)
    out = jax.tree.map(lambda x, y: jnp.where(fits, x, y), new, policy)
    return out, best_value, fits
