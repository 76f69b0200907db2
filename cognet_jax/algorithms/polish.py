"""Exact local search ("polish") of a deterministic tabular controller, after a G-DICE search.

A cross-entropy search ends near an optimum but often a few table entries away from it (the
"before polish" column of experiments/README.md, problems outside ../shared). When every
controller's value can be computed exactly (a tabular model), a steepest-ascent search over
single-entry changes finishes that job cheaply.

Moves (all static, listed once by :func:`neighbour_moves` as rows ``(kind, agent, node, obs,
value)``; ``agent = -1`` changes every agent's entry at once, for identical agents):

* ``kind 0``: the action of ``node`` becomes ``value`` (``value < action_counts[agent]``);
* ``kind 1``: the next node after ``(node, obs)`` becomes ``value`` -- for a time-layered
  controller only nodes of the next layer, and no move from the last layer (never used within
  the horizon).

One sweep evaluates every move exactly and applies the best one if it beats the current value
by more than ``1e-5 * max(1, |value|)`` (exact values are float32); the search stops after
``sweeps`` sweeps or when no move improves. What is maximised: the exact expected return of
the joint controller over the horizon (:meth:`cognet_jax.algorithms.gdice.GDice.exact_values`).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from cognet_jax.algorithms.cross_entropy import select_tree
from cognet_jax.controllers.tabular import DeterministicTabularPolicy, TabularController

#: relative improvement a move must bring (exact values are float32)
RELATIVE_TOLERANCE = 1e-5


def neighbour_moves(
    controller: TabularController,
    action_counts,
    obs_counts,
    joint_moves: bool,
) -> np.ndarray:
    """Every single-entry change of a controller, ``[moves, 5]`` int32 rows ``(kind, agent,
    node, obs, value)``; with ``joint_moves`` also each change made by every agent at once
    (``agent = -1``; only meaningful for agents with the same action and observation counts)."""
    n = controller.num_nodes
    width = controller.layer_width if controller.layers else n
    agents = list(range(controller.num_agents)) + ([-1] if joint_moves else [])
    rows = []
    for agent in agents:
        a_count = int(action_counts[max(agent, 0)])
        o_count = int(obs_counts[max(agent, 0)])
        for node in range(n):
            rows += [(0, agent, node, 0, a) for a in range(a_count)]
            if controller.layers:
                layer = node // width
                if layer == controller.layers - 1:
                    continue
                targets = range((layer + 1) * width, (layer + 2) * width)
            else:
                targets = range(n)
            rows += [(1, agent, node, o, t) for o in range(o_count) for t in targets]
    return np.asarray(rows, np.int32)


def count_moves(controller: TabularController, action_counts, obs_counts, joint_moves: bool):
    """The number of rows ``neighbour_moves`` lists, without listing them (a controller of
    millions of nodes would take minutes to list)."""
    n = controller.num_nodes
    if controller.layers:  # no moves out of the last layer; a next layer of width targets
        width = controller.layer_width
        moving, targets = n - width, width
    else:
        moving, targets = n, n
    agents = list(range(controller.num_agents)) + ([-1] if joint_moves else [])
    total = 0
    for agent in agents:
        a_count, o_count = int(action_counts[max(agent, 0)]), int(obs_counts[max(agent, 0)])
        total += n * a_count + moving * o_count * targets
    return total


def apply_move(policy: DeterministicTabularPolicy, move: jax.Array) -> DeterministicTabularPolicy:
    """``policy`` with one move ``(kind, agent, node, obs, value)`` applied."""
    kind, agent, node, obs, value = move[0], move[1], move[2], move[3], move[4]
    agents, nodes, num_obs = policy.transitions.shape
    rows = (agent < 0) | (jnp.arange(agents) == agent)  # [agents]
    at_node = jnp.arange(nodes) == node  # [nodes]
    act_mask = (kind == 0) & rows[:, None] & at_node[None, :]
    tr_mask = (
        (kind == 1)
        & rows[:, None, None]
        & at_node[None, :, None]
        & (jnp.arange(num_obs) == obs)[None, None, :]
    )
    return DeterministicTabularPolicy(
        actions=jnp.where(act_mask, value, policy.actions).astype(policy.actions.dtype),
        transitions=jnp.where(tr_mask, value, policy.transitions).astype(policy.transitions.dtype),
    )


def polish(
    exact_values: Callable,
    policy: DeterministicTabularPolicy,
    moves: np.ndarray,
    sweeps: int,
    batch: int = 256,
) -> tuple[DeterministicTabularPolicy, jax.Array, jax.Array]:
    """Steepest ascent from ``policy`` over ``moves`` (``[moves, 5]``), at most ``sweeps``
    moves applied. ``exact_values`` maps policies with a leading ``[C]`` axis to their exact
    values ``[C]``. Returns ``(policy, value, moves applied)``; jit-able."""
    moves = jnp.asarray(moves)

    def value_of(p):
        return exact_values(jax.tree.map(lambda x: x[None], p))[0]

    def sweep(carry):
        p, value, applied, _ = carry
        values = jax.lax.map(lambda m: value_of(apply_move(p, m)), moves, batch_size=batch)
        best = jnp.argmax(values)
        better = values[best] > value + RELATIVE_TOLERANCE * jnp.maximum(1.0, jnp.abs(value))
        p = select_tree(better, apply_move(p, moves[best]), p)
        return p, jnp.where(better, values[best], value), applied + better, better

    def keep_going(carry):
        _, _, applied, improved = carry
        return improved & (applied < sweeps)

    start = (policy, value_of(policy), jnp.int32(0), jnp.bool_(sweeps > 0))
    policy, value, applied, _ = jax.lax.while_loop(keep_going, sweep, start)
    return policy, value, applied
