"""Local search ("polish") of a kept neural controller by paired rollouts, after a
``cognet-dice`` search (the default's ``finish``; ``algorithms.cognet_weights``).

Why: a cross-entropy search over weights moves every threshold of a candidate at once, so the
last few hundredths of one threshold -- what a practitioner's grid search over a hand-written
controller's thresholds tunes -- are lost in the noise of the others' moves. On the bearing
chase the kept policies of two seeds of eight were 0.12 and 0.23 below what one or two
threshold shifts of a few hundredths of the observation's spread gave them
(experiments/NOTES.md). Moves of one entry at a time, valued under common random numbers
(a move changes only the rollouts whose trajectories it touches), show those.

Moves (static rows ``(kind, agent, node, unit, arg)`` of :func:`move_table`; ``Q`` nodes,
``H`` hidden units):

* ``SHIFT``: hidden unit ``unit`` of ``(agent, node)`` moves its threshold by
  ``SHIFTS[arg]`` standard deviations of the input features along its weights (the bias
  changes by that times ``|w * scale|``, ``scale [agents, F]`` the features' spread);
* ``TARGET``: the unit votes for node ``(k + 1 + arg) % Q`` instead of its node ``k`` (the
  vote's strength kept);
* ``ACTION``: the node's action becomes ``(a + 1 + arg) % actions`` (a move to an action the
  agent lacks leaves the policy as it is);
* ``DEFAULT``: the node's default vote goes to ``(d + 1 + arg) % Q`` instead of ``d``;
* ``AXIS`` (``polish_axes``, with at most ``AXIS_MAX_FEATURES`` input features): the node's
  weakest unit (smallest vote times spread along its weights) becomes a threshold on one
  feature, the rule a practitioner writes by hand: ``arg`` picks the feature ``f``, a side
  ``s = +-1``, a level ``AXIS_LEVELS[l]`` and a target node ``t``; the unit reads ``relu(g s
  (x_f - c_f - level scale_f) / scale_f)`` (``c``, ``scale``: the features' mean and spread;
  ``g`` a slope steep enough to outvote the node's other units ``AXIS_SHARPNESS`` spreads
  past the threshold, ``_axis_unit``) and votes for ``t`` with the node's strongest vote.
  SHIFT moves of later sweeps tune its threshold. Why: a region the search never covered
  (on the chase, one end of the bearing's range for half of the seeds) is a joint change of
  a unit's direction, bias and target that one-entry moves cannot make (experiments/NOTES.md);
* ``START`` (``polish_axes``, any number of features): node 0, where every controller starts,
  and node ``1 + arg`` swap roles (their actions, networks and every vote for them) in agent
  ``agent``'s controller, or, with ``node`` 1, in every agent's: the same controller started
  elsewhere. Why: the start node acts blind and is also a target of the others' votes, so
  which role starts is a joint choice of every weight the search cannot make one entry at a
  time (beacon: the kept policies started by stepping, the hand-written rule by staying;
  +0.1).

* ``COUNTER`` (``polish_axes`` and ``polish_counter``, inputs of at most
  ``AXIS_MAX_FEATURES`` features): every agent's controller becomes a counter of the
  evidence on one feature (``_counter``): its nodes hold a tally that steps up past
  ``+margin`` standard deviations of the feature and down past ``-margin``, the agent's
  node-0 action played while ``|tally| < depth``, one end action at ``+depth`` and another
  at ``-depth``, then the tally starts again; ``arg`` picks the feature, the margin
  (``COUNTER_LEVELS``), the depth (up to ``(Q - 1) // 2``) and the two end actions. Why:
  where acting pays only after several concordant observations (a door opened after hearing
  the tiger on one side a few times more than on the other), the controllers that keep
  gathering are a plateau -- their transitions change no return until an action is placed at
  the end of a chain -- and no move of one entry leaves it: on noisy Dec-Tiger the kept
  policies listened for ever (-19.6) where a counter of depth 3 gives about -17.9
  (experiments/NOTES.md). **[choice]** The COUNTER moves are valued in one sweep of their
  own, before the polish's sweeps and on a key of its own, beyond ``polish_share``: listed
  in every sweep they made each sweep dearer, so fewer fit in the share (beacon without
  noise: one sweep where two fitted, a START move lost), and the sweeps after draw what they
  drew without them. The SHIFT and ACTION moves of those sweeps tune the counter.

SHIFT, TARGET and AXIS change every copy of the unit at once: a tied controller (``node_tie``,
``agent_tie``: the same network in every node or agent) runs copies with equal weights, and
changing one copy alone would untie it.

One sweep (:func:`sweep`): every move's mean return on ``rollouts`` rollouts of one key, the
current policy's on the same rollouts; the ``CONFIRM_TOP`` moves with the largest gains are
tried again against the current policy on ``CONFIRM_FACTOR`` times as many rollouts of a
second key, and the one that wins there by most is applied if it wins by ``CONFIRM_Z``
standard errors of the paired difference (so a move picked for a lucky draw among hundreds is
not kept on that draw). **[choice]** The polish runs every sweep its share of the budget
allows, also after a sweep that applied nothing (the next sweep's rollouts are fresh): on box
pushing that gave four more seeds of eight a move than stopping there (experiments/NOTES.md).
**[choice]** Past its share it goes on while each sweep applies a move, up to ``polish_extend``
times the share: a policy that still gains at every sweep (the chase seed whose kept policy
missed a region: one move per sweep for seven sweeps) is not cut off, and one that has
settled costs no more.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from cognet_jax.controllers.base import action_support
from cognet_jax.controllers.neural import NeuralPolicy
from cognet_jax.rollout import evaluate_candidates, many_returns

SHIFT, TARGET, ACTION, DEFAULT, AXIS, START, COUNTER = 0, 1, 2, 3, 4, 5, 6
#: threshold shifts, in standard deviations of the input features along a unit's weights
SHIFTS = (-0.3, -0.1, -0.03, -0.01, 0.01, 0.03, 0.1, 0.3)
#: thresholds of AXIS moves, in standard deviations of the feature from its mean
AXIS_LEVELS = (-1.5, -1.0, -0.5, 0.0, 0.5, 1.0, 1.5)
#: standard deviations past an AXIS threshold where its unit outvotes the node's others
AXIS_SHARPNESS = 0.05
#: AXIS moves only on inputs of at most this many features: on an image patch a threshold on
#: one pixel is not what a hand-written rule reads, and the moves would grow with the pixels
AXIS_MAX_FEATURES = 4
#: margins of COUNTER moves, in standard deviations of the feature past its mean
COUNTER_LEVELS = (0.0, 0.25, 0.5, 0.75, 1.0, 1.25, 1.5)
#: logit of a COUNTER node's default (stay, or back to node 0 after an end): the controller
#: samples its next node from the softmax of its logits, so 30 leaves the others e^-30
COUNTER_STAY = 30.0
#: slope of a COUNTER unit, per standard deviation of its feature, and its vote: twice the
#: stay logit 1 / (2 COUNTER_SLOPE) standard deviations past its margin
COUNTER_SLOPE = 40.0
#: moves of a sweep tried again on the confirming rollouts (its best by the picking ones)
CONFIRM_TOP = 4
#: the confirming rollouts, as a multiple of the picking ones (``best_rollouts``): the picking
#: evaluates hundreds of moves, the confirming a few, so a finer test costs little
CONFIRM_FACTOR = 10
#: standard errors of the paired difference by which a move must win on the confirming
#: rollouts: of ``CONFIRM_TOP`` moves that change nothing one is kept in about 40 sweeps
CONFIRM_Z = 2.5
#: the stream of the polish's key: the search's init key folded with it
POLISH_STREAM = 0x706F6C69
#: the stream of the COUNTER moves' sweep: the polish's key folded with it
COUNTER_STREAM = 0x636F756E
#: most sweeps of a polish (each applies at most one move)
POLISH_MAX_SWEEPS = 20


def axis_moves(features: int, nodes: int) -> int:
    """AXIS moves per node: features x sides x levels x targets (0 above
    ``AXIS_MAX_FEATURES``)."""
    if features > AXIS_MAX_FEATURES:
        return 0
    return features * 2 * len(AXIS_LEVELS) * nodes


def counter_depths(nodes: int, hidden: int) -> int:
    """Depths of COUNTER moves a controller holds: a counter of depth ``c`` takes ``2 c + 1``
    nodes and two hidden units per node."""
    return (nodes - 1) // 2 if hidden >= 2 else 0


def counter_moves(features: int, nodes: int, hidden: int, actions: int) -> int:
    """COUNTER moves: features x margins x depths x the two end actions (0 above
    ``AXIS_MAX_FEATURES``)."""
    if features > AXIS_MAX_FEATURES:
        return 0
    return features * len(COUNTER_LEVELS) * counter_depths(nodes, hidden) * actions * actions


def counter_table(features: int, nodes: int, hidden: int, actions: int) -> np.ndarray:
    """The COUNTER moves, ``[moves, 5]`` int32 rows (``counter_moves`` of them): valued in a
    sweep of their own before the polish's (``PolishFinish.finish_start``)."""
    count = counter_moves(features, nodes, hidden, actions)
    return np.asarray([(COUNTER, 0, 0, 0, i) for i in range(count)], np.int32).reshape(-1, 5)


def move_table(agents: int, nodes: int, hidden: int, actions: int, features: int = 0) -> np.ndarray:
    """Every move of a sweep, ``[moves, 5]`` int32 rows ``(kind, agent, node, unit, arg)``;
    ``features`` > 0 adds the AXIS moves of that many input features (``axis_moves``) and the
    START moves (the COUNTER moves are ``counter_table``'s)."""
    rows = []
    for a in range(agents):
        for n in range(nodes):
            for h in range(hidden):
                rows += [(SHIFT, a, n, h, i) for i in range(len(SHIFTS))]
                rows += [(TARGET, a, n, h, i) for i in range(nodes - 1)]
            rows += [(ACTION, a, n, 0, i) for i in range(actions - 1)]
            rows += [(DEFAULT, a, n, 0, i) for i in range(nodes - 1)]
            rows += [(AXIS, a, n, 0, i) for i in range(axis_moves(features, nodes))]
        if features:
            rows += [(START, a, 0, 0, i) for i in range(nodes - 1)]
    if features:
        rows += [(START, 0, 1, 0, i) for i in range(nodes - 1)]
    return np.asarray(rows, np.int32).reshape(-1, 5)


def _layers(policy: NeuralPolicy):
    p = policy.net_params["params"]
    return (
        p["Dense_0"]["kernel"],
        p["Dense_0"]["bias"],
        p["Dense_1"]["kernel"],
        p["Dense_1"]["bias"],
    )


def _with(policy: NeuralPolicy, w1, b1, w2, b2, actions) -> NeuralPolicy:
    params = {"Dense_0": {"kernel": w1, "bias": b1}, "Dense_1": {"kernel": w2, "bias": b2}}
    return policy.replace(action_probs=actions, net_params={"params": params})


def _shifted(index: int, size: int, arg) -> jax.Array:
    """``(index + 1 + arg) % size``: every other category than ``index`` as ``arg`` runs."""
    return (index + 1 + arg) % size


def _axis_unit(w1, b1, w2, b2, a, n, arg, scale, center):
    """``(h, column [F], bias [], votes [Q])``: the AXIS move ``arg`` of node ``(a, n)``
    (module docstring) -- which unit it rewrites and that unit's new weights. The unit's slope
    makes its vote, ``AXIS_SHARPNESS`` standard deviations past the threshold, twice a bound
    on any other logit of the node over features within 3 standard deviations of their mean:
    the region past the threshold is the target's, as in a hand-written rule (relu units add
    up, so a unit of the others' slope would lose to their sum)."""
    q, f_count = w2.shape[-1], w1.shape[-2]
    target, rest = arg % q, arg // q
    level, rest = rest % len(AXIS_LEVELS), rest // len(AXIS_LEVELS)
    side, feature = jnp.where(rest % 2 == 0, 1.0, -1.0), rest // 2
    spreads = jnp.sqrt(jnp.sum((w1[a, n] * scale[a][:, None]) ** 2, axis=0))  # [H]
    strength = jnp.max(jnp.abs(w2[a, n]), axis=-1)  # [H]
    h = jnp.argmin(spreads * strength)
    reach = jnp.abs(w1[a, n]).T @ (jnp.abs(center[a]) + 3.0 * scale[a]) + jnp.abs(b1[a, n])
    bound = jnp.sum(reach * strength) + jnp.max(jnp.abs(b2[a, n]))
    vote = jnp.maximum(jnp.max(strength), 1.0)
    slope = 2.0 * bound / (AXIS_SHARPNESS * vote) + 1.0  # per standard deviation
    s_f = scale[a, feature]
    threshold = center[a, feature] + jnp.asarray(AXIS_LEVELS, jnp.float32)[level] * s_f
    column = jax.nn.one_hot(feature, f_count, dtype=w1.dtype) * side * slope / s_f
    bias = -side * slope * threshold / s_f
    return h, column, bias, vote * jax.nn.one_hot(target, q, dtype=w2.dtype)


def _counter(leaves, arg, scale, center, support):
    """The COUNTER move ``arg`` (module docstring): ``leaves`` ``(w1, b1, w2, b2, actions)``
    rewritten, in every agent's controller, as a counter of the evidence on one feature.
    Node 0 holds the tally 0, node ``2t - 1`` the tally ``t > 0``, node ``2t`` the tally
    ``-t``; while ``|t| < c`` the node plays the agent's node-0 action, its unit 0 votes up a
    tally past ``+margin`` standard deviations of the feature, its unit 1 down one past
    ``-margin``, its default stays. At ``+c`` node ``2c - 1`` plays one action, at ``-c`` node
    ``2c`` the other, and the next node is 0: the tally starts again. Nodes past ``2c`` are
    left unreached."""
    w1, b1, w2, b2, actions = leaves
    agents, q, f_count, hidden = w1.shape
    na = actions.shape[-1]
    lo, rest = arg % na, arg // na
    hi, rest = rest % na, rest // na
    depths = max(counter_depths(q, hidden), 1)
    depth, rest = 1 + rest % depths, rest // depths
    level, feature = rest % len(COUNTER_LEVELS), rest // len(COUNTER_LEVELS)
    margin = jnp.asarray(COUNTER_LEVELS, jnp.float32)[level]
    nodes = jnp.arange(q)
    tally = jnp.where(nodes % 2 == 1, (nodes + 1) // 2, -(nodes // 2))

    def node_of(t):  # the node of tally t; the ends at +-depth
        inner = jnp.where(t > 0, 2 * t - 1, -2 * t)
        return jnp.where(t >= depth, 2 * depth - 1, jnp.where(t <= -depth, 2 * depth, inner))

    counting = nodes < 2 * depth - 1  # [Q]
    s_f = scale[:, feature]  # [A]
    c_f = center[:, feature]
    slope = COUNTER_SLOPE / s_f  # [A]
    column = jax.nn.one_hot(feature, f_count, dtype=w1.dtype)  # [F]
    signs = jnp.asarray([1.0, -1.0], w1.dtype)  # unit 0 up, unit 1 down
    units = jnp.arange(hidden) < 2
    unit_sign = jnp.where(units, jnp.pad(signs, (0, hidden - 2)), 0.0)  # [H]
    new_w1 = column[None, None, :, None] * (slope[:, None, None, None] * unit_sign)
    new_w1 = jnp.where(counting[None, :, None, None], new_w1, 0.0)  # [A, Q, F, H]
    new_b1 = (  # relu(slope (s (x_f - c_f) - margin s_f)): unit 0 s = +1, unit 1 s = -1
        -slope[:, None, None] * (unit_sign * c_f[:, None, None] + margin * s_f[:, None, None])
    )
    new_b1 = jnp.where(counting[None, :, None] & units, new_b1, 0.0)  # [A, Q, H]
    up = jax.nn.one_hot(node_of(tally + 1), q, dtype=w2.dtype)  # [Q, Q]
    down = jax.nn.one_hot(node_of(tally - 1), q, dtype=w2.dtype)
    rows = jnp.zeros((q, hidden, q), w2.dtype).at[:, 0].set(up).at[:, 1].set(down)
    rows = 2.0 * COUNTER_STAY * rows
    new_w2 = jnp.broadcast_to(jnp.where(counting[:, None, None], rows, 0.0), w2.shape)
    stay = jnp.where(counting[:, None], jnp.eye(q, dtype=b2.dtype), jax.nn.one_hot(0, q))
    new_b2 = jnp.broadcast_to(COUNTER_STAY * stay, b2.shape)
    middle = jnp.argmax(actions[:, 0], axis=-1)  # [A]
    agents_ax = jnp.arange(agents)
    end_hi = jnp.where(support[agents_ax, hi], hi, middle)
    end_lo = jnp.where(support[agents_ax, lo], lo, middle)
    played = jnp.where(
        nodes == 2 * depth - 1,
        end_hi[:, None],
        jnp.where(nodes == 2 * depth, end_lo[:, None], middle[:, None]),
    )  # [A, Q]
    new_actions = jax.nn.one_hot(played, na, dtype=actions.dtype)
    return new_w1, new_b1, new_w2, new_b2, new_actions


def apply_move(
    policy: NeuralPolicy,
    move: jax.Array,
    scale: jax.Array,
    support: jax.Array,
    center: jax.Array | None = None,
):
    """``policy`` changed by one move (``move [5]`` int32, module docstring); ``scale [agents,
    F]``, ``center [agents, F]``: the input features' spread and mean (``center`` needed by
    AXIS moves only); ``support [agents, actions]`` bool: the agents' actions.
    Leaves: ``w1 [agents, Q, F, H]``, ``b1 [agents, Q, H]``, ``w2 [agents, Q, H, Q]``, ``b2
    [agents, Q, Q]``, ``action_probs [agents, Q, actions]`` (one-hot)."""
    w1, b1, w2, b2 = _layers(policy)
    actions = policy.action_probs
    kind, a, n, h, arg = move[0], move[1], move[2], move[3], move[4]
    q, na = b2.shape[-1], actions.shape[-1]
    if center is not None:  # AXIS: its unit is the node's weakest, found here
        axis_h, axis_column, axis_bias, axis_votes = _axis_unit(
            w1, b1, w2, b2, a, n, arg, scale, center
        )
        h = jnp.where(kind == AXIS, axis_h, h)
    # the unit's copies: equal input weights and bias in every (agent, node)
    column = w1[a, n, :, h]
    copies = jnp.all(w1[:, :, :, h] == column, -1) & (b1[:, :, h] == b1[a, n, h])  # [A, Q]
    unit = jax.nn.one_hot(h, w1.shape[-1], dtype=bool)  # [H]
    # SHIFT
    norm = jnp.sqrt(jnp.sum((column * scale[a]) ** 2))
    step = jnp.asarray(SHIFTS, jnp.float32)[jnp.clip(arg, 0, len(SHIFTS) - 1)] * norm
    b1_new = jnp.where(copies[..., None] & unit, b1 + step, b1)
    # TARGET: the vote's strength to another node
    votes = w2[a, n, h]  # [Q]
    target = jnp.argmax(jnp.abs(votes))
    row = votes[target] * jax.nn.one_hot(_shifted(target, q, arg), q, dtype=w2.dtype)
    w2_new = jnp.where((copies[..., None] & unit)[..., None], row, w2)
    # ACTION of (a, n), to an action the agent has
    current = jnp.argmax(actions[a, n])
    new_action = _shifted(current, na, arg)
    one_hot = jax.nn.one_hot(new_action, na, dtype=actions.dtype)
    actions_new = actions.at[a, n].set(jnp.where(support[a, new_action], one_hot, actions[a, n]))
    # DEFAULT vote of (a, n) to another node
    default = jnp.argmax(jnp.abs(b2[a, n]))
    b2_new = b2.at[a, n].set(b2[a, n, default] * jax.nn.one_hot(_shifted(default, q, arg), q))
    pick = lambda k, new, old: jnp.where(kind == k, new, old)  # noqa: E731
    b1_new, w2_new = pick(SHIFT, b1_new, b1), pick(TARGET, w2_new, w2)
    b2_new, actions_new = pick(DEFAULT, b2_new, b2), pick(ACTION, actions_new, actions)
    if center is not None:  # AXIS: every copy of the unit rewritten
        at = copies[..., None] & unit  # [A, Q, H]
        w1 = pick(AXIS, jnp.where(at[:, :, None, :], axis_column[:, None], w1), w1)
        b1_new = pick(AXIS, jnp.where(at, axis_bias, b1), b1_new)
        w2_new = pick(AXIS, jnp.where(at[..., None], axis_votes, w2), w2_new)
        started = _started(arg, a, n, (w1, b1, w2, b2, actions))
        w1, b1_new, w2_new, b2_new, actions_new = (
            pick(START, new, old)
            for new, old in zip(started, (w1, b1_new, w2_new, b2_new, actions_new))
        )
        if counter_depths(q, w1.shape[-1]):
            counted = _counter((w1, b1, w2, b2, actions), arg, scale, center, support)
            w1, b1_new, w2_new, b2_new, actions_new = (
                pick(COUNTER, new, old)
                for new, old in zip(counted, (w1, b1_new, w2_new, b2_new, actions_new))
            )
    return _with(policy, w1, b1_new, w2_new, b2_new, actions_new)


def _started(arg, agent, every, leaves):
    """The START move (module docstring): ``leaves`` ``(w1, b1, w2, b2, actions)`` with nodes
    0 and ``1 + arg`` swapped in agent ``agent``'s controller, or every agent's when
    ``every`` is 1."""
    q = leaves[1].shape[1]
    other = 1 + arg
    nodes = jnp.arange(q)
    perm = jnp.where(nodes == 0, other, jnp.where(nodes == other, 0, nodes))
    agents = jnp.arange(leaves[0].shape[0])
    chosen = (every == 1) | (agents == agent)  # [A]
    # the node axis of each leaf, and the axis of the nodes its votes go to (w2, b2)
    axes = ((1,), (1,), (1, 3), (1, 2), (1,))
    out = []
    for leaf, leaf_axes in zip(leaves, axes):
        swapped = leaf
        for axis in leaf_axes:
            swapped = jnp.take(swapped, perm, axis=axis)
        mask = chosen.reshape((-1,) + (1,) * (leaf.ndim - 1))
        out.append(jnp.where(mask, swapped, leaf))
    return out


def polish_seed(init_key: jax.Array) -> jax.Array:
    """``[2]`` uint32: bits of the init key's ``POLISH_STREAM`` (a search state keeps these,
    not a typed key, so checkpoints can hold it)."""
    return jax.random.bits(jax.random.fold_in(init_key, POLISH_STREAM), (2,), jnp.uint32)


def polish_key(seed: jax.Array) -> jax.Array:
    """The polish's key from ``polish_seed``'s bits (JAX's default generator, whatever
    ``run.prng_impl`` the search draws with: the bits come from the search's own key)."""
    return jax.random.fold_in(jax.random.fold_in(jax.random.key(0), seed[0]), seed[1])


@struct.dataclass
class PolishWork:
    """The polish in progress: the ``policy`` so far, the ``key`` of the next sweep, sweeps
    run, moves applied, the summed gain of the applied moves on their confirming rollouts and
    whether the last sweep applied one (``moved``; ``[]`` each)."""

    policy: NeuralPolicy
    key: jax.Array
    sweeps: jax.Array
    applied: jax.Array
    gain: jax.Array
    moved: jax.Array
    #: ``[]`` bool: a COUNTER move was applied (by the sweep of them before the others)
    counted: jax.Array | None = None

    @classmethod
    def start(cls, policy: NeuralPolicy, key: jax.Array) -> PolishWork:
        zero = jnp.int32(0)
        return cls(policy, key, zero, zero, jnp.float32(0.0), jnp.bool_(False), jnp.bool_(False))


def sweep(
    work: PolishWork, moves: jax.Array, values, paired, scale, support, center=None
) -> PolishWork:
    """One sweep (module docstring). ``values(key, policies) -> [P]``: mean returns of stacked
    policies on the same rollouts of ``key`` (common random numbers); ``paired(key, policy,
    others) -> (gains [K], stderrs [K])``: each of the stacked ``others``' mean return minus
    ``policy``'s on the same rollouts of ``key``, and the standard errors of those paired
    differences; ``center``: the features' mean (AXIS moves)."""
    k_pick, k_check, k_next = jax.random.split(work.key, 3)
    policy = work.policy
    changed = jax.vmap(lambda m: apply_move(policy, m, scale, support, center))(moves)
    stack = jax.tree.map(lambda p, c: jnp.concatenate([p[None], c]), policy, changed)
    means = values(k_pick, stack)
    gains = jnp.where(jnp.isnan(means[1:]), -jnp.inf, means[1:] - means[0])
    top_gains, top = jax.lax.top_k(gains, min(CONFIRM_TOP, moves.shape[0]))
    chosen = jax.tree.map(lambda c: c[top], changed)
    gain, stderr = paired(k_check, policy, chosen)
    wins = (top_gains > 0) & (gain > 0) & (gain > CONFIRM_Z * stderr)
    best = jnp.argmax(jnp.where(wins, gain, -jnp.inf))
    confirmed = wins[best]
    return PolishWork(
        policy=jax.tree.map(lambda c, p: jnp.where(confirmed, c[best], p), chosen, policy),
        key=k_next,
        sweeps=work.sweeps + 1,
        applied=work.applied + confirmed,
        gain=work.gain + jnp.where(confirmed, gain[best], 0.0),
        moved=confirmed,
        counted=work.counted,
    )


class PolishFinish:
    """The polish as a search's ``finish`` (``algorithms.engine``; mixed into
    ``cognet_weights.CognetWeights``): ``polish_sweeps`` sweeps, and more while each applies a
    move, up to ``polish_sweep_cap``; each values every move on ``best_rollouts`` rollouts.
    Reads the search's ``settings`` (``polish_share``, ``polish_axes``, ``polish_extend``,
    ``best_rollouts``, ``iterations``, ``nodes``, ``hidden``), ``env``, ``controller``,
    ``memory``, ``feature_scale``, ``feature_mean`` and ``rollouts_per_iteration``; its
    state's ``best_policy`` and ``polish_seed``."""

    @functools.cached_property
    def polish_moves(self) -> np.ndarray:
        """``[moves, 5]``: the moves of one sweep (``move_table``, listed once per search: the
        records of a sweep's runs read its length)."""
        s, c = self.settings, self.controller
        features = c.in_features if s.polish_axes else 0
        return move_table(c.num_agents, s.nodes, s.hidden, self.env.num_actions, features)

    @functools.cached_property
    def polish_counters(self) -> np.ndarray:
        """``[moves, 5]``: the COUNTER moves (``counter_table``; none without ``polish_axes``
        and ``polish_counter``)."""
        s, c = self.settings, self.controller
        features = c.in_features if s.polish_axes and s.polish_counter else 0
        return counter_table(features, s.nodes, s.hidden, self.env.num_actions)

    @property
    def counter_sweep_rollouts(self) -> int:
        """Rollouts of the sweep of COUNTER moves (0 without them): on top of the share,
        once, as a sweep of those moves alone."""
        moves = len(self.polish_counters)
        if not moves:
            return 0
        return (moves + 1 + CONFIRM_FACTOR * (CONFIRM_TOP + 1)) * self.settings.best_rollouts

    @property
    def polish_sweeps(self) -> int:
        """Sweeps the polish runs: ``polish_share`` of the search's rollouts over the
        rollouts of one sweep (every move and the policy, the confirming ones), at most
        ``POLISH_MAX_SWEEPS``; 0: no polish."""
        return self._sweeps_of(self.settings.polish_share)

    @property
    def polish_sweep_cap(self) -> int:
        """Sweeps the polish may run while each applies a move: those of ``polish_extend``
        times its share (at least ``polish_sweeps``)."""
        s = self.settings
        return max(self._sweeps_of(s.polish_share * s.polish_extend), self.polish_sweeps)

    def _sweeps_of(self, share: float) -> int:
        s = self.settings
        if s.polish_share <= 0:
            return 0
        total = share * s.iterations * self.rollouts_per_iteration
        return int(min(total // self.polish_sweep_rollouts, POLISH_MAX_SWEEPS))

    @property
    def polish_sweep_rollouts(self) -> int:
        """Rollouts one sweep simulates: every move and the policy on ``best_rollouts``, the
        confirming ones and the policy on ``CONFIRM_FACTOR`` times as many."""
        moves = len(self.polish_moves)
        return (moves + 1 + CONFIRM_FACTOR * (CONFIRM_TOP + 1)) * self.settings.best_rollouts

    def _polish_parts(self, params):
        n = self.settings.best_rollouts
        n_check = CONFIRM_FACTOR * n

        def values(key, policies):
            return evaluate_candidates(
                self.env, self.controller, key, n, params.env, policies, memory=self.memory
            )

        def paired(key, policy, others):  # 10,000 rollouts at a time: bounded memory
            def run(p):
                return many_returns(self.env, self.controller, key, params.env, p, n_check)

            diff = jax.vmap(run)(others) - run(policy)  # [K, n_check]
            return diff.mean(-1), diff.std(-1) / jnp.sqrt(jnp.float32(n_check))

        agents, features = self.controller.num_agents, self.controller.in_features
        scale = self.feature_scale
        if scale is None:
            scale = jnp.ones((agents, features), jnp.float32)
        support = action_support(self.env)[:, 0, :]
        center = None
        if self.settings.polish_axes:
            center = self.feature_mean
            if center is None:
                center = jnp.zeros((agents, features), jnp.float32)
            center = jnp.asarray(center, jnp.float32)
        return values, paired, jnp.asarray(scale, jnp.float32), support, center

    def finish_start(self, state, params):
        """The polish of the kept policy (``None`` without sweeps), after the sweep of its
        COUNTER moves: a sweep of their own, on a key of its own (the polish's sweeps draw
        what they drew without them), that counts in none of the polish's sweeps."""
        if self.polish_sweeps == 0 or state.polish_seed is None:
            return None
        work = PolishWork.start(state.best_policy, polish_key(state.polish_seed))
        if not len(self.polish_counters):
            return work
        values, paired, scale, support, center = self._polish_parts(params)
        own = work.replace(key=jax.random.fold_in(work.key, COUNTER_STREAM))
        swept = sweep(
            own, jnp.asarray(self.polish_counters), values, paired, scale, support, center
        )
        return swept.replace(
            key=work.key, sweeps=work.sweeps, moved=work.moved, counted=swept.moved
        )

    def finish_advance(self, work: PolishWork, params) -> PolishWork:
        values, paired, scale, support, center = self._polish_parts(params)
        moves = jnp.asarray(self.polish_moves)
        done = self.finish_done(work)
        swept = sweep(work, moves, values, paired, scale, support, center)
        return jax.tree.map(lambda old, new: jnp.where(done, old, new), work, swept)

    def finish_done(self, work: PolishWork) -> jax.Array:
        """Its share spent and the last sweep applied nothing, or ``polish_sweep_cap``."""
        spent = (work.sweeps >= self.polish_sweeps) & ~work.moved
        return spent | (work.sweeps >= self.polish_sweep_cap)

    def finish_end(self, state, work: PolishWork):
        """``(state, work)``: the polished policy kept."""
        return state.replace(best_policy=work.policy), work

    def finish_record(self, info, seconds: float) -> dict | None:
        """results.json ``finish``: sweeps run, moves applied, their summed gain on the
        confirming rollouts (a paired estimate, not the honest value), moves per sweep."""
        if info is None:
            return None
        record = {
            "sweeps": int(info.sweeps),
            "moves_applied": int(info.applied),
            "confirmed_gain": float(info.gain),
            "moves_per_sweep": len(self.polish_moves),
            "rollouts_per_move": self.settings.best_rollouts,
            "rollouts": int(info.sweeps) * self.polish_sweep_rollouts + self.counter_sweep_rollouts,
            "seconds": seconds,
        }
        if len(self.polish_counters):
            record["counter_moves"] = len(self.polish_counters)
            record["counter_applied"] = bool(info.counted)
        return record

    def finish_status(self, work) -> dict:
        """The polish's progress: sweeps run and moves applied (the largest over runs)."""
        sweeps, applied = (np.max(np.asarray(getattr(work, f))) for f in ("sweeps", "applied"))
        return {"sweeps": int(sweeps), "moves": int(applied)}

    def finish_line(self, record: dict) -> str | None:
        counter = ""
        if "counter_moves" in record:
            counter = f" after {record['counter_moves']} COUNTER moves"
            counter += " (one applied)" if record["counter_applied"] else " (none applied)"
        return (
            f"polish: {record['moves_applied']} moves in {record['sweeps']} sweeps of "
            f"{record['moves_per_sweep']}{counter} (paired gain "
            f"{record['confirmed_gain']:+.4g}, {record['seconds']:.1f} s)"
        )
