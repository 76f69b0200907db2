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
``sweeps`` sweeps, when no move improves, or when the next sweep would go past the budget of
exact evaluations (``Polish``). What is maximised: the exact expected return of
the joint controller over the horizon (:meth:`cognet_jax.algorithms.gdice.GDice.exact_values`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from cognet_jax.algorithms.cross_entropy import select_tree
from cognet_jax.controllers.tabular import DeterministicTabularPolicy, TabularController

#: relative improvement a move must bring (exact values are float32)
RELATIVE_TOLERANCE = 1e-5
#: largest budget and step cost counted (exact evaluations; int32 sums stay exact)
BUDGET_CAP = 1 << 30


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


@struct.dataclass
class PolishState:
    """Where a polish is (``Polish``): the policy and its exact value, the value it started
    from, moves applied (in all and since the last best-response round), whether the current
    phase of sweeps still improves, best responses applied, rounds done, whether the last round
    applied one, and the exact evaluations spent (``budget``)."""

    policy: DeterministicTabularPolicy
    value: jax.Array
    before: jax.Array
    moves_applied: jax.Array
    phase_moves: jax.Array
    sweeping: jax.Array
    responses_applied: jax.Array
    rounds: jax.Array
    answered: jax.Array
    spent: jax.Array


@dataclasses.dataclass(frozen=True)
class Polish:
    """The exact polish as steps (a state machine over ``PolishState``), so a driver can show
    progress and stop between them, and ``run`` (a ``while_loop`` of the same steps) is the
    pure version ``make_train`` compiles.

    A step is one sweep (every move of ``moves [M, 5]`` valued exactly, the best applied when it
    improves) while the phase improves, at most ``sweeps`` moves per phase; then, with
    ``rounds > 0``, one round of best responses (``respond(policy, value) -> (policy, value,
    applied)``), which opens a new phase; rounds stop after ``rounds`` or after one that applies
    nothing. What is spent is counted in exact evaluations of one controller: ``M`` a sweep,
    ``round_cost`` a round; a step that would take ``spent`` past ``budget`` is not started.
    ``move_values(policy, moves [M, 5])`` gives the exact value ``[M]`` of ``policy`` with each
    move applied (:func:`values_by_evaluation`, or for a layered controller the one-layer
    update of :func:`cognet_jax.exact_jax.layered_move_values`)."""

    moves: np.ndarray
    sweeps: int
    rounds: int
    budget: int
    round_cost: int

    def start(self, policy, value: jax.Array) -> PolishState:
        zero = jnp.int32(0)
        return PolishState(
            policy=policy,
            value=value,
            before=value,
            moves_applied=zero,
            phase_moves=zero,
            sweeping=jnp.bool_(self.sweeps > 0),
            responses_applied=zero,
            rounds=zero,
            answered=jnp.bool_(True),
            spent=jnp.int32(1),
        )

    def _affords(self, s: PolishState, cost: int) -> jax.Array:
        # budget and costs are clamped to 2**30 (``polish_budget``), so the int32 sum is exact
        return s.spent + min(cost, BUDGET_CAP) <= min(self.budget, BUDGET_CAP)

    def can_sweep(self, s: PolishState) -> jax.Array:
        return s.sweeping & (s.phase_moves < self.sweeps) & self._affords(s, len(self.moves))

    def can_respond(self, s: PolishState) -> jax.Array:
        more = (s.rounds < self.rounds) & s.answered & self._affords(s, self.round_cost)
        return ~self.can_sweep(s) & more

    def done(self, s: PolishState) -> jax.Array:
        return ~(self.can_sweep(s) | self.can_respond(s))

    def sweep(self, s: PolishState, move_values: Callable) -> PolishState:
        moves = jnp.asarray(self.moves)
        values = move_values(s.policy, moves)
        best = jnp.argmax(values)
        better = improves(values[best], s.value)
        return s.replace(
            policy=select_tree(better, apply_move(s.policy, moves[best]), s.policy),
            value=jnp.where(better, values[best], s.value),
            moves_applied=s.moves_applied + better,
            phase_moves=s.phase_moves + better,
            sweeping=better,
            spent=s.spent + len(self.moves),
        )

    def respond(self, s: PolishState, respond: Callable) -> PolishState:
        policy, value, applied = respond(s.policy, s.value)
        return s.replace(
            policy=policy,
            value=value,
            phase_moves=jnp.int32(0),
            sweeping=jnp.bool_(self.sweeps > 0),
            responses_applied=s.responses_applied + applied,
            rounds=s.rounds + 1,
            answered=applied > 0,
            spent=s.spent + self.round_cost,
        )

    def advance(self, s: PolishState, move_values: Callable, respond: Callable) -> PolishState:
        """One step: a sweep if the phase goes on, else a round if one is due, else nothing."""
        return jax.lax.cond(
            self.can_sweep(s),
            lambda s: self.sweep(s, move_values),
            lambda s: jax.lax.cond(
                self.can_respond(s), lambda s: self.respond(s, respond), lambda s: s, s
            ),
            s,
        )

    def run(self, s: PolishState, move_values: Callable, respond: Callable) -> PolishState:
        """Every step until ``done`` (pure, jit-able)."""
        return jax.lax.while_loop(
            lambda s: ~self.done(s), lambda s: self.advance(s, move_values, respond), s
        )


def values_by_evaluation(exact_values: Callable, batch: int = 256) -> Callable:
    """``move_values(policy, moves) -> [M]`` that applies each move (:func:`apply_move`) and
    values the changed controller with ``exact_values`` (policies with a leading ``[C]`` axis
    to ``[C]``), ``batch`` moves at a time."""

    def move_values(policy, moves):
        def value_of(move):
            changed = apply_move(policy, move)
            return exact_values(jax.tree.map(lambda x: x[None], changed))[0]

        return jax.lax.map(value_of, moves, batch_size=batch)

    return move_values


def improves(new: jax.Array, value: jax.Array) -> jax.Array:
    """Whether ``new`` beats ``value`` by more than ``RELATIVE_TOLERANCE`` (float32 values)."""
    return new > value + RELATIVE_TOLERANCE * jnp.maximum(1.0, jnp.abs(value))
