"""Exact evaluation of deterministic joint controllers on tabular Dec-POMDPs (SPEC section 3),
and brute-force optimal values of small finite-horizon problems (SPEC section 8).

Controllers are deterministic Moore FSCs, one per agent, as sampled by G-DICE:
``actions[i, q]`` is agent i's action in node q and ``transitions[i, q, z]`` its next node after
observing z. All agents start in node 0. One time step (SPEC section 1): every agent acts, the
reward ``R(s, ja)`` is collected on the pre-step state, the state moves to ``s' ~ T(.|s, ja)``,
the joint observation ``jo ~ O(.|ja, s')`` is split into per-agent observations (last agent
fastest) and every agent moves to ``transitions[i, q_i, z_i]``.

Dynamic programming over (joint node, state)::

    V_k(q, s) = R(s, a) + gamma sum_{s', jo} T(s'|s, a) O(jo|a, s') V_{k-1}(q'(q, jo), s')

where ``a = ja(q)`` is the joint action of joint node q, ``q'(q, jo)`` its successor, and
``V_0 = 0``. The value of the controller is ``sum_s b0(s) V_h(0, s)``, i.e.
``E[sum_{t<h} gamma^t r_t]``.

* Finite horizon (``horizon=h``): h backward steps, exact up to floating point.
* Infinite horizon (``horizon=None``, ``discount < 1``): the same operator is iterated from
  ``V = 0`` until ``gamma / (1 - gamma) * max|V_k - V_{k-1}| <= tol``. Because the operator is a
  gamma-contraction in the max norm, the returned value is then within ``tol`` of the true
  infinite-horizon value (``|V_k - V*| <= gamma/(1-gamma) |V_k - V_{k-1}|``); ``tol`` defaults
  to ``1e-10``. Iteration also stops when ``max|V_k - V_{k-1}|`` falls to the floating-point
  resolution of V (``8 eps max(1, |V|)``; only reachable first when gamma is close to 1 and
  ``tol`` below what float64 can resolve), in which case the bound above still applies with
  that change. ``RuntimeError`` if ``max_iter`` iterations do not get there.

The work is vectorised with numpy: one step is a gather of ``V`` at the successor joint nodes,
a product with ``O`` and one matrix product with ``T`` per joint action. Many controllers can be
evaluated at once (:func:`exact_values`); they are stacked as independent blocks of joint nodes
and processed in memory-bounded chunks.

Brute force (:func:`brute_force_optimum`): a deterministic policy tree of depth h is the
tree-shaped FSC of :func:`policy_tree_transitions` (``1 + |Z| + ... + |Z|^(h-1)`` nodes, one per
observation history). The default ``method="best_response"`` enumerates every joint tree of
agents ``0..n-2`` and, for each of them at once (vectorised), computes the last agent's exact
best response by backward induction over its observation histories; the maximum over the
enumeration is the optimum over *all* joint policy trees. ``method="exhaustive"`` evaluates
every joint policy tree with :func:`exact_values` (only for the smallest problems; the tests use
it to cross-check the best-response search).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

__all__ = [
    "Optimum",
    "brute_force_optimum",
    "exact_value",
    "exact_values",
    "policy_tree_transitions",
    "tree_num_nodes",
]

#: Largest intermediate array (in float64 entries) the evaluators build at once.
CHUNK_ENTRIES = 1 << 22
#: Largest intermediate array the brute-force search may build.
MAX_BRUTE_ENTRIES = 1 << 26


class _Arrays(NamedTuple):
    trans: np.ndarray  # T[S, JA, S']
    obs: np.ndarray  # O[JA, S', JO]
    rew: np.ndarray  # R[S, JA]
    b0: np.ndarray  # [S]
    action_counts: tuple[int, ...]
    obs_counts: tuple[int, ...]


def _arrays(model: Any) -> _Arrays:
    """Accept a ``TabularModel`` (or anything with its attribute names) or a tuple
    ``(transition, observation, reward, initial_belief, action_counts, obs_counts)``."""
    if isinstance(model, tuple | list):
        if len(model) != 6:
            raise ValueError(
                "expected (transition, observation, reward, initial_belief, action_counts, "
                "obs_counts)"
            )
        trans, obs, rew, b0, ac, oc = model
    else:
        trans, obs, rew = model.transition, model.observation, model.reward
        b0 = model.initial_belief
        ac, oc = model.action_counts, model.obs_counts
    obs, rew, b0 = (np.asarray(x, dtype=np.float64) for x in (obs, rew, b0))
    # the largest table keeps its float dtype (float32 from the parser): every product with it
    # is computed in float64 all the same, and a 2025-state model's copy would take 0.5 GB
    trans = np.asarray(trans)
    if trans.dtype not in (np.float32, np.float64):
        trans = trans.astype(np.float64)
    ac, oc = tuple(int(a) for a in ac), tuple(int(o) for o in oc)
    S = b0.shape[0]
    JA, JO = int(np.prod(ac)), int(np.prod(oc))
    if trans.shape != (S, JA, S) or obs.shape != (JA, S, JO) or rew.shape != (S, JA):
        raise ValueError(
            f"inconsistent shapes: T {trans.shape}, O {obs.shape}, R {rew.shape}, "
            f"b0 {b0.shape} for action counts {ac} and observation counts {oc}"
        )
    return _Arrays(trans, obs, rew, b0, ac, oc)


def _check_controllers(m: _Arrays, actions, transitions) -> tuple[np.ndarray, np.ndarray]:
    actions = np.asarray(actions)
    transitions = np.asarray(transitions)
    n = len(m.action_counts)
    if actions.ndim != 3 or actions.shape[1] != n:
        raise ValueError(f"actions must be [batch, agents={n}, nodes], got {actions.shape}")
    B, _, N = actions.shape
    if transitions.ndim != 4 or transitions.shape[:3] != (B, n, N):
        raise ValueError(
            f"transitions must be [batch, agents, nodes, obs] = [{B}, {n}, {N}, >="
            f"{max(m.obs_counts)}], got {transitions.shape}"
        )
    if transitions.shape[3] < max(m.obs_counts):
        raise ValueError(
            f"transitions have {transitions.shape[3]} observation columns, need {max(m.obs_counts)}"
        )
    if not (
        np.issubdtype(actions.dtype, np.integer) and np.issubdtype(transitions.dtype, np.integer)
    ):
        raise ValueError("actions and transitions must be integer arrays")
    for i in range(n):
        a = actions[:, i]
        if a.min(initial=0) < 0 or a.max(initial=0) >= m.action_counts[i]:
            raise ValueError(f"agent {i}: actions must lie in [0, {m.action_counts[i]})")
        t = transitions[:, i, :, : m.obs_counts[i]]
        if t.min(initial=0) < 0 or t.max(initial=0) >= N:
            raise ValueError(f"agent {i}: next nodes must lie in [0, {N})")
    return actions.astype(np.int64), transitions.astype(np.int64)


def _joint_tables(m: _Arrays, actions: np.ndarray, transitions: np.ndarray):
    """Joint action ``ja[b, q]`` and next joint node ``nxt[b, q, jo]`` (last agent fastest)."""
    B, n, N = actions.shape
    Q = N**n
    JO = int(np.prod(m.obs_counts))
    qs = np.unravel_index(np.arange(Q), (N,) * n)  # per-agent node of each joint node
    zs = np.unravel_index(np.arange(JO), m.obs_counts)  # per-agent obs of each joint obs
    ja = np.zeros((B, Q), dtype=np.int64)
    nxt = np.zeros((B, Q, JO), dtype=np.int64)
    a_stride = 1
    q_stride = 1
    for i in reversed(range(n)):
        ja += actions[:, i, qs[i]] * a_stride
        nxt += transitions[:, i][:, qs[i][:, None], zs[i][None, :]] * q_stride
        a_stride *= m.action_counts[i]
        q_stride *= N
    return ja, nxt


def _evaluate_block(m: _Arrays, ja, nxt, horizon, discount, tol, max_iter) -> np.ndarray:
    """Values of a block of controllers: ``ja [B, Q]``, ``nxt [B, Q, JO]`` -> ``[B]``."""
    B, Q = ja.shape
    S = m.b0.shape[0]
    rows = B * Q
    ja_f = ja.reshape(rows)
    nxt_f = (nxt + (np.arange(B) * Q)[:, None, None]).reshape(rows, -1)  # [rows, JO]
    o_rows = np.ascontiguousarray(m.obs[ja_f].transpose(0, 2, 1))  # [rows, JO, S']
    r_rows = m.rew.T[ja_f]  # [rows, S]
    gamma = float(discount)
    if rows * S * S <= CHUNK_ENTRIES:
        t_rows = np.ascontiguousarray(m.trans[:, ja_f, :].transpose(1, 0, 2))  # [rows, S, S']
        groups = None
    else:  # one matrix product per joint action instead of a [rows, S, S'] gather
        order = np.argsort(ja_f, kind="stable")
        bounds = np.flatnonzero(np.diff(ja_f[order])) + 1
        groups = [(int(ja_f[g[0]]), g) for g in np.split(order, bounds) if len(g)]

    def bellman(V):
        X = np.einsum("rjt,rjt->rt", o_rows, V[nxt_f])  # E[V(q', s') | s'] per row
        if groups is None:
            out = np.einsum("rst,rt->rs", t_rows, X)
        else:
            out = np.empty_like(r_rows)
            for a, idx in groups:  # (BLAS; the table's float32 slice is promoted)
                out[idx] = X[idx] @ m.trans[:, a, :].T
        return r_rows + gamma * out

    V = np.zeros((rows, S))
    if horizon is not None:
        for _ in range(int(horizon)):
            V = bellman(V)
    else:
        factor = gamma / (1.0 - gamma)
        eps = np.finfo(np.float64).eps
        for _ in range(int(max_iter)):
            V_new = bellman(V)
            delta = np.max(np.abs(V_new - V)) if rows else 0.0
            V = V_new
            if factor * delta <= tol:
                break
            if delta <= 8 * eps * max(1.0, float(np.max(np.abs(V)))):
                break  # no further progress is representable
        else:
            raise RuntimeError(
                f"value iteration did not reach tol={tol:g} in {max_iter} iterations "
                f"(last bound {factor * delta:.3g})"
            )
    return V.reshape(B, Q, S)[:, 0, :] @ m.b0


def exact_values(
    model: Any,
    actions,
    transitions,
    horizon: int | None,
    discount: float,
    tol: float = 1e-10,
    max_iter: int = 100_000,
) -> np.ndarray:
    """Exact values ``[B]`` of B deterministic joint controllers.

    ``actions [B, agents, nodes]`` and ``transitions [B, agents, nodes, obs]`` (integers;
    observation columns beyond an agent's count are ignored). ``horizon=None`` evaluates the
    infinite discounted sum (needs ``discount < 1``; the result is within ``tol`` of the true
    value). See the module docstring for the recursion.
    """
    m = _arrays(model)
    if horizon is None:
        if not 0.0 <= discount < 1.0:
            raise ValueError(f"an infinite horizon needs 0 <= discount < 1, got {discount}")
    elif int(horizon) != horizon or horizon < 0:
        raise ValueError(f"horizon must be a non-negative integer or None, got {horizon!r}")
    actions, transitions = _check_controllers(m, actions, transitions)
    B, n, N = actions.shape
    Q = N**n
    S = m.b0.shape[0]
    JO = int(np.prod(m.obs_counts))
    per_controller = Q * max(S, 1) * max(JO, S, 1)
    chunk = max(1, CHUNK_ENTRIES // per_controller)
    out = np.empty(B)
    for lo in range(0, B, chunk):
        hi = min(B, lo + chunk)
        ja, nxt = _joint_tables(m, actions[lo:hi], transitions[lo:hi])
        out[lo:hi] = _evaluate_block(m, ja, nxt, horizon, discount, tol, max_iter)
    return out


def exact_value(model: Any, actions, transitions, horizon: int | None, discount: float, **options):
    """Exact value of one deterministic joint controller: ``actions [agents, nodes]``,
    ``transitions [agents, nodes, obs]``; ``E[sum_{t<h} gamma^t r_t]`` from node 0 and
    ``s_0 ~ b0``. ``horizon=None`` with ``discount < 1``: the infinite discounted value, by
    value iteration until the error bound ``gamma/(1-gamma) max|V_k - V_{k-1}|`` is at most
    ``tol`` (so the result is within ``tol`` of the true value). ``options``: ``tol`` and
    ``max_iter`` of ``exact_values``."""
    batch = (np.asarray(actions)[None], np.asarray(transitions)[None])
    return float(exact_values(model, *batch, horizon, discount, **options)[0])


# --------------------------------------------------------------------------------------------
# Policy trees and brute force


def tree_num_nodes(num_obs: int, depth: int) -> int:
    """Nodes of a policy tree of ``depth`` levels: ``1 + Z + ... + Z^(depth-1)``."""
    return sum(num_obs**k for k in range(depth))


def _level_offset(num_obs: int, level: int) -> int:
    return tree_num_nodes(num_obs, level)


def policy_tree_transitions(num_obs: int, depth: int) -> np.ndarray:
    """Transitions ``[nodes, num_obs]`` of a policy tree as an FSC.

    Nodes are numbered level by level: the node of history ``(z_1, ..., z_k)`` is
    ``offset_k + sum_j z_j Z^(k-j)`` with ``offset_k = 1 + Z + ... + Z^(k-1)``; its child after
    ``z`` is that of ``(z_1, ..., z_k, z)``. Leaves (level ``depth-1``) loop to themselves (their
    successors are never used within the horizon).
    """
    if depth < 1:
        raise ValueError("depth must be at least 1")
    nodes = tree_num_nodes(num_obs, depth)
    out = np.empty((nodes, num_obs), dtype=np.int64)
    for k in range(depth):
        off = _level_offset(num_obs, k)
        local = np.arange(num_obs**k)
        if k == depth - 1:
            out[off + local] = (off + local)[:, None]
        else:
            child_off = _level_offset(num_obs, k + 1)
            out[off + local] = child_off + local[:, None] * num_obs + np.arange(num_obs)[None]
    return out


def _all_trees(num_actions: int, nodes: int) -> np.ndarray:
    """Every action assignment ``[A^nodes, nodes]`` of a tree (first node slowest)."""
    count = num_actions**nodes
    if count > MAX_BRUTE_ENTRIES:
        raise ValueError(f"{count} policy trees per agent: too many to enumerate")
    grid = np.unravel_index(np.arange(count), (num_actions,) * nodes)
    return np.stack(grid, axis=-1).astype(np.int64)


class Optimum(NamedTuple):
    """Best joint policy tree: its value and the tree as FSC arrays ``actions [agents, nodes]``,
    ``transitions [agents, nodes, obs]`` (padded to the largest agent; usable with
    :func:`exact_value` and the JAX rollouts)."""

    value: float
    actions: np.ndarray
    transitions: np.ndarray


def _pack(m: _Arrays, depth: int, trees: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    n = len(m.action_counts)
    nodes = [tree_num_nodes(z, depth) for z in m.obs_counts]
    N, Z = max(nodes), max(m.obs_counts)
    actions = np.zeros((n, N), dtype=np.int64)
    transitions = np.zeros((n, N, Z), dtype=np.int64)
    for i in range(n):
        actions[i, : nodes[i]] = trees[i]
        transitions[i, : nodes[i], : m.obs_counts[i]] = policy_tree_transitions(
            m.obs_counts[i], depth
        )
    return actions, transitions


def brute_force_optimum(
    model: Any,
    horizon: int,
    discount: float = 1.0,
    *,
    method: str = "best_response",
    max_policies: int = 20_000_000,
) -> Optimum:
    """Optimal value over all deterministic joint policy trees of depth ``horizon``.

    ``discount`` defaults to 1 (the undiscounted finite-horizon values of SPEC section 8).
    ``method="best_response"`` (default) enumerates the joint trees of agents ``0..n-2`` and
    computes the last agent's best response exactly and vectorised over that enumeration;
    ``method="exhaustive"`` evaluates every joint tree with :func:`exact_values`.
    ``max_policies`` bounds the size of the enumeration (``ValueError`` beyond it).
    """
    m = _arrays(model)
    h = int(horizon)
    if h < 1:
        raise ValueError("horizon must be at least 1")
    n = len(m.action_counts)
    nodes = [tree_num_nodes(z, h) for z in m.obs_counts]
    counts = [m.action_counts[i] ** nodes[i] for i in range(n)]
    if method == "exhaustive":
        total = int(np.prod(counts, dtype=object))
        if total > max_policies:
            raise ValueError(f"{total} joint policy trees exceed max_policies={max_policies}")
        return _exhaustive(m, h, discount, nodes)
    if method != "best_response":
        raise ValueError(f"unknown method {method!r}")
    others = int(np.prod(counts[:-1], dtype=object))
    if others > max_policies:
        raise ValueError(
            f"{others} joint trees of the other agents exceed max_policies={max_policies}"
        )
    return _best_response_search(m, h, discount)


def _exhaustive(m: _Arrays, h: int, discount: float, nodes: list[int]) -> Optimum:
    n = len(m.action_counts)
    trees = [_all_trees(m.action_counts[i], nodes[i]) for i in range(n)]
    N, Z = max(nodes), max(m.obs_counts)
    trans = np.zeros((n, N, Z), dtype=np.int64)
    for i in range(n):
        trans[i, : nodes[i], : m.obs_counts[i]] = policy_tree_transitions(m.obs_counts[i], h)
    sizes = [len(t) for t in trees]
    total = int(np.prod(sizes))
    chunk = 1 << 15
    best_val, best_idx = -np.inf, 0
    for lo in range(0, total, chunk):
        idx = np.arange(lo, min(total, lo + chunk))
        per_agent = np.unravel_index(idx, sizes)
        acts = np.zeros((len(idx), n, N), dtype=np.int64)
        for i in range(n):
            acts[:, i, : nodes[i]] = trees[i][per_agent[i]]
        vals = exact_values(m, acts, np.broadcast_to(trans, (len(idx),) + trans.shape), h, discount)
        k = int(np.argmax(vals))
        if vals[k] > best_val:
            best_val, best_idx = float(vals[k]), int(idx[k])
    per_agent = np.unravel_index(best_idx, sizes)
    actions, transitions = _pack(m, h, [trees[i][per_agent[i]] for i in range(n)])
    return Optimum(best_val, actions, transitions)


def _level(m: _Arrays, d: int, h: int, trees: list, p_of: tuple, P: int):
    """Level d of the others' joint trees: ``(lsizes, rew [P, S, L, A], trans)`` with the
    others' local joint nodes ``L = prod(lsizes)``, ``rew[p, s, l, a] = R(s, ja)`` and, below
    the last level, ``trans[a][p, l, s, t, jo] = T(t|s, ja) O(jo|ja, t)`` for the joint action
    ``ja`` of the others' nodes and the last agent's action ``a``."""
    n, S = len(m.action_counts), m.b0.shape[0]
    A_last, Z_last = m.action_counts[-1], m.obs_counts[-1]
    oth_A, oth_Z = m.action_counts[:-1], m.obs_counts[:-1]
    lsizes = tuple(z**d for z in oth_Z)
    L = int(np.prod(lsizes))
    ls = np.unravel_index(np.arange(L), lsizes) if n > 1 else ()
    oa = np.zeros((P, L), dtype=np.int64)  # the others' joint action at (p, l)
    stride = 1
    for i in reversed(range(n - 1)):
        node = _level_offset(oth_Z[i], d) + ls[i]
        oa += trees[i][p_of[i][:, None], node[None, :]] * stride
        stride *= oth_A[i]
    if P * L * S * A_last > MAX_BRUTE_ENTRIES:
        raise ValueError("problem too large for the brute-force search")
    ja_all = oa[:, :, None] * A_last + np.arange(A_last)  # [P, L, A]
    rew = m.rew[:, ja_all].transpose(1, 0, 2, 3)  # [P, S, L, A]
    if d == h - 1:
        return lsizes, rew, None
    if P * L * S * S * int(np.prod(oth_Z)) * Z_last * A_last > MAX_BRUTE_ENTRIES:
        raise ValueError("problem too large for the brute-force search")
    trans = []
    for a in range(A_last):
        ja = ja_all[:, :, a]
        Tg = m.trans[:, ja, :].transpose(1, 2, 0, 3)  # [P, L, S, S']
        Og = m.obs[ja]  # [P, L, S', JO]
        trans.append(Tg[..., None] * Og[:, :, None, :, :])
    return lsizes, rew, trans


class _Response(NamedTuple):
    """The last agent's best response to every joint tree ``p < P`` of the others, by
    recursion over its own histories (``levels``: ``_level`` of every depth)."""

    levels: list
    oth_Z: tuple
    Z_last: int
    A_last: int
    S: int
    P: int
    h: int
    gamma: float

    def children(self, d: int, nxt: np.ndarray) -> np.ndarray:
        """``nxt [P, S', L, JO]`` -> child alphas ``[Z_last, P, S', L']`` of level d+1."""
        k = len(self.oth_Z)
        x = nxt.reshape((self.P, self.S) + self.levels[d][0] + tuple(self.oth_Z) + (self.Z_last,))
        # interleave (l_i, z_i) so the child's local index is l_i * Z_i + z_i, agent-major
        perm = [len(x.shape) - 1, 0, 1]
        for i in range(k):
            perm += [2 + i, 2 + k + i]
        x = x.transpose(perm)
        return x.reshape((self.Z_last, self.P, self.S, int(np.prod(self.levels[d + 1][0]))))

    def value(self, d: int, alpha: np.ndarray, local: int, record: bool):
        """Best value ``[P]`` of the last agent from its node (level d, index ``local``) given
        the unnormalised distribution ``alpha [P, S, L]`` over (state, others' node); with
        ``record`` also its plan ``{(level, local): action}`` (for ``P = 1``)."""
        _, rew, trans = self.levels[d]
        imm = np.einsum("psl,psla->pa", alpha, rew)  # [P, A]
        if d == self.h - 1:
            if record:
                a = int(np.argmax(imm[0]))
                return imm[:, a], {(d, local): a}
            return imm.max(axis=1), None
        best, best_plan = None, None
        for a in range(self.A_last):
            kids = self.children(d, np.einsum("psl,plstj->ptlj", alpha, trans[a]))
            val = imm[:, a].copy()
            plan = {(d, local): a} if record else None
            for z in range(self.Z_last):
                v, sub = self.value(d + 1, kids[z], local * self.Z_last + z, record)
                val += self.gamma * v
                if record:
                    plan.update(sub)
            if best is None:
                best, best_plan = val, plan
            elif record:
                if val[0] > best[0]:
                    best, best_plan = val, plan
            else:
                best = np.maximum(best, val)
        return best, best_plan


def _best_response_search(m: _Arrays, h: int, discount: float) -> Optimum:
    n = len(m.action_counts)
    S = m.b0.shape[0]
    A_last, Z_last = m.action_counts[-1], m.obs_counts[-1]
    oth_A, oth_Z = m.action_counts[:-1], m.obs_counts[:-1]
    trees = [_all_trees(oth_A[i], tree_num_nodes(oth_Z[i], h)) for i in range(n - 1)]
    sizes = tuple(len(t) for t in trees)
    P = int(np.prod(sizes))  # joint trees of the other agents (1 when n == 1)
    p_of = np.unravel_index(np.arange(P), sizes) if n > 1 else ()
    levels = [_level(m, d, h, trees, p_of, P) for d in range(h)]
    search = _Response(levels, tuple(oth_Z), Z_last, A_last, S, P, h, float(discount))
    alpha0 = np.zeros((P, S, 1))
    alpha0[:, :, 0] = m.b0[None, :]
    values, _ = search.value(0, alpha0, 0, record=False)
    p_best = int(np.argmax(values))

    # Replay the best response to the best trees of the others, recording its actions.
    narrowed = [
        (
            lsizes,
            rew[p_best : p_best + 1],
            None if tr is None else [t[p_best : p_best + 1] for t in tr],
        )
        for lsizes, rew, tr in levels
    ]
    _, plan = search._replace(levels=narrowed, P=1).value(0, alpha0[:1], 0, record=True)
    last_tree = np.zeros(tree_num_nodes(Z_last, h), dtype=np.int64)
    for (d, local), a in plan.items():
        last_tree[_level_offset(Z_last, d) + local] = a
    per_agent = [trees[i][p_of[i][p_best]] for i in range(n - 1)]
    actions, transitions = _pack(m, h, per_agent + [last_tree])
    return Optimum(float(values[p_best]), actions, transitions)
