"""The search space of the default ``cognet-dice`` (``algorithms.cognet_weights``): the
distribution over joint neural controllers, one candidate's draws, and the tying of nodes and
agents. Shapes: ``Q`` nodes, ``F`` network inputs, ``H`` hidden units."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from cognet_jax.algorithms.cross_entropy import count_table, inject_entropy, smooth
from cognet_jax.controllers.base import sample_categorical


@struct.dataclass
class WeightDistribution:
    """Search distribution over joint neural controllers (``algorithms.cognet_weights``)."""

    action_probs: jax.Array  # [agents, Q, actions]
    w1_mean: jax.Array  # [agents, Q, F, H]
    w1_std: jax.Array  # [agents, Q, F, H]
    b1_mean: jax.Array  # [agents, Q, H]
    b1_std: jax.Array  # [agents, Q, H]
    unit_target_probs: jax.Array  # [agents, Q, H, Q]
    m_mean: jax.Array  # [agents, Q, H]
    m_std: jax.Array  # [agents, Q, H]
    default_probs: jax.Array  # [agents, Q, Q]
    bias_mean: jax.Array  # [agents, Q]
    bias_std: jax.Array  # [agents, Q]
    node_tie_probs: jax.Array  # [agents, 2]: (own networks, node 0's network in every node)
    agent_tie_probs: jax.Array  # [2]: (own controllers, agent 0's controller for every agent)
    #: [agents, 2]: (independent actions, distinct actions until every action has a node);
    #: None where not searched (``distinct_actions``)
    distinct_probs: jax.Array | None = None
    #: [] probability that a candidate redraws one hidden unit from the initial distribution
    #: (``redraw_unit``); None where the search has no such draws (``refine_redraw`` 0)
    redraw: jax.Array | None = None
    #: [agents, Q]: the node whose role each agent starts in (``started``); None where node 0
    #: always starts (``start_draw`` off)
    start_probs: jax.Array | None = None


@struct.dataclass
class WeightSample:
    """The draws of one candidate (leaves without the candidate axis)."""

    actions: jax.Array  # [agents, Q] int32
    w1: jax.Array  # [agents, Q, F, H]
    b1: jax.Array  # [agents, Q, H]
    unit_targets: jax.Array  # [agents, Q, H] int32
    m: jax.Array  # [agents, Q, H]
    default: jax.Array  # [agents, Q] int32
    bias: jax.Array  # [agents, Q]
    node_tie: jax.Array  # [agents] int32, 1: every node runs node 0's network
    agent_tie: jax.Array  # [] int32, 1: every agent runs agent 0's controller
    distinct: jax.Array | None = None  # [agents] int32, 1: actions drawn by ``distinct_draw``
    start: jax.Array | None = None  # [agents] int32: the node whose role starts (``started``)


#: the fields of a node's network (copied by node tying); agent tying copies every field
NETWORK_FIELDS = ("w1", "b1", "unit_targets", "m", "default", "bias")


def tie(sample: WeightSample) -> WeightSample:
    """Apply a sample's tie flags (leaves with or without a leading candidate axis): where
    ``node_tie`` is 1, every node of that agent gets node 0's network (a reactive controller:
    the next node depends on the observation only); where ``agent_tie`` is 1, every agent gets
    agent 0's whole controller (actions and networks). The Gaussians and categoricals are
    then refit to the weights the candidates ran, so a tied elite teaches every node.

    Written as gathers of a source index per node and per agent: a ``where`` between each
    array and a broadcast slice of it let XLA fuse the random draws that made the array into
    both reads and compute them again (benchmarks/NOTES.md, twelfth pass)."""
    lead = sample.node_tie.ndim - 1  # 1 with a candidate axis, else 0
    agents, q = sample.actions.shape[-2:]
    node_src = jnp.where(sample.node_tie[..., None] == 1, 0, jnp.arange(q))  # [..., agents, Q]
    agent_src = jnp.where(sample.agent_tie[..., None] == 1, 0, jnp.arange(agents))  # [..., agents]

    def pick(x, src, axis):
        index = src.reshape(src.shape + (1,) * (x.ndim - src.ndim))
        return jnp.take_along_axis(x, jnp.broadcast_to(index, x.shape), axis=axis)

    sample = sample.replace(
        **{f: pick(getattr(sample, f), node_src, lead + 1) for f in NETWORK_FIELDS}
    )
    fields = (*NETWORK_FIELDS, "actions", "node_tie")
    fields += ("distinct",) if sample.distinct is not None else ()
    return sample.replace(**{f: pick(getattr(sample, f), agent_src, lead) for f in fields})


def started(sample: WeightSample) -> WeightSample:
    """The controllers ``sample`` runs (leaves with or without a leading candidate axis):
    in each agent's, node 0 (where it starts) and node ``start[a]`` swap roles -- their
    actions, networks and every vote for them -- so an agent starts in the role of node
    ``start[a]``. Tied agents (``agent_tie``) then share one controller and may start in
    different roles. ``sample`` as it is without ``start``."""
    if sample.start is None:
        return sample
    lead = sample.start.ndim  # the node axis: after the agents'
    q = sample.actions.shape[-1]
    nodes, first = jnp.arange(q), sample.start[..., None]
    perm = jnp.where(nodes == 0, first, jnp.where(nodes == first, 0, nodes))  # [..., agents, Q]

    def along_nodes(x):  # x[..., perm[n], ...] at node n, by selects, not a gather: XLA's
        # CPU compile of that gather fused with standardised weights of one input feature ran
        # for over 20 minutes in sweeps of 4 or more runs (experiments/NOTES.md); selects copy
        # the same numbers
        index = perm.reshape(perm.shape + (1,) * (x.ndim - perm.ndim))
        out = jnp.zeros_like(x)
        for k in range(q):
            node = jax.lax.index_in_dim(x, k, axis=lead, keepdims=True)
            out = jnp.where(index == k, node, out)
        return out

    def renamed(votes):  # a vote for node t goes to where t now sits: perm is an involution
        flat = votes.reshape(votes.shape[:lead] + (-1,))  # [..., agents, Q x H]
        return jnp.take_along_axis(perm, flat, axis=-1).reshape(votes.shape)

    moved = {f: along_nodes(getattr(sample, f)) for f in (*NETWORK_FIELDS, "actions")}
    moved.update({f: renamed(moved[f]) for f in ("unit_targets", "default")})
    return sample.replace(**moved)


def gaussian_refit(mean, std, elite_draws, alpha):
    """``alpha * (elite mean, elite std) + (1 - alpha) * (mean, std)``; ``elite_draws [E, ...]``."""
    return (
        alpha * elite_draws.mean(0) + (1.0 - alpha) * mean,
        alpha * elite_draws.std(0) + (1.0 - alpha) * std,
    )


def sample_of(w1, b1, w2, b2, action_probs) -> WeightSample:
    """The draws that make a policy's arrays (the inverse of ``CognetWeights.to_policy``, with
    inputs not standardised): ``w1 [agents, Q, F, H]``, ``b1 [agents, Q, H]``, ``w2 [agents,
    Q, H, Q]`` (one vote per unit), ``b2 [agents, Q, Q]`` (one default vote), ``action_probs
    [agents, Q, actions]`` (one-hot). The tie flags say whether the policy is tied: every node
    of an agent runs node 0's network (``node_tie``), every agent runs agent 0's controller
    (``agent_tie``)."""
    targets = jnp.argmax(jnp.abs(w2), -1).astype(jnp.int32)
    default = jnp.argmax(jnp.abs(b2), -1).astype(jnp.int32)
    sample = WeightSample(
        actions=jnp.argmax(action_probs, -1).astype(jnp.int32),
        w1=w1,
        b1=b1,
        unit_targets=targets,
        m=jnp.take_along_axis(w2, targets[..., None], -1)[..., 0],
        default=default,
        bias=jnp.take_along_axis(b2, default[..., None], -1)[..., 0],
        node_tie=jnp.zeros(w1.shape[0], jnp.int32),
        agent_tie=jnp.int32(0),
    )

    def nodes_equal(x):
        """``[agents]``: whether every node's slice of ``x [agents, Q, ...]`` equals node 0's."""
        return jnp.all((x == x[:, :1]).reshape(x.shape[0], -1), axis=1)

    networks = [getattr(sample, f) for f in NETWORK_FIELDS]
    node_tied = jnp.all(jnp.stack([nodes_equal(x) for x in networks]), 0).astype(jnp.int32)
    agent_fields = [getattr(sample, f) for f in (*NETWORK_FIELDS, "actions")]
    agent_tied = jnp.all(jnp.stack([jnp.all(x == x[:1]) for x in agent_fields])).astype(jnp.int32)
    return sample.replace(node_tie=node_tied, agent_tie=agent_tied)


def refit(dist: WeightDistribution, elites: WeightSample, alpha, floors, agent_floor, support):
    """``dist`` refit to ``elites`` (leading ``[E]`` axis): categoricals by count MLE and
    Gaussians by the elites' mean and std, each smoothed with rate ``alpha``; then every
    categorical is mixed with the uniform one: ``floors = (actions, output-layer categories,
    node tie)``, ``agent_floor`` for the agent tie; ``support [agents, 1, actions]`` the actions
    each agent has."""
    action_floor, category_floor, node_floor = floors
    q = dist.default_probs.shape[-1]

    def categorical(old, draws, k, floor, allowed=None):
        counts = count_table(jnp.moveaxis(draws, 0, -1), k)
        return inject_entropy(smooth(old, counts, alpha), floor, allowed)

    def gaussian(name):
        mean, std = getattr(dist, f"{name}_mean"), getattr(dist, f"{name}_std")
        return gaussian_refit(mean, std, getattr(elites, name), alpha)

    (w1_mean, w1_std), (b1_mean, b1_std) = gaussian("w1"), gaussian("b1")
    (m_mean, m_std), (bias_mean, bias_std) = gaussian("m"), gaussian("bias")
    num_actions = dist.action_probs.shape[-1]
    return WeightDistribution(
        action_probs=categorical(
            dist.action_probs, elites.actions, num_actions, action_floor, support
        ),
        w1_mean=w1_mean,
        w1_std=w1_std,
        b1_mean=b1_mean,
        b1_std=b1_std,
        unit_target_probs=categorical(
            dist.unit_target_probs, elites.unit_targets, q, category_floor
        ),
        m_mean=m_mean,
        m_std=m_std,
        default_probs=categorical(dist.default_probs, elites.default, q, category_floor),
        bias_mean=bias_mean,
        bias_std=bias_std,
        node_tie_probs=categorical(dist.node_tie_probs, elites.node_tie, 2, node_floor),
        agent_tie_probs=categorical(dist.agent_tie_probs, elites.agent_tie, 2, agent_floor),
        distinct_probs=None
        if dist.distinct_probs is None
        else categorical(dist.distinct_probs, elites.distinct, 2, category_floor),
        redraw=dist.redraw,
        start_probs=None
        if dist.start_probs is None
        else categorical(dist.start_probs, elites.start, q, category_floor),
    )


def centered(
    sample: WeightSample,
    init: WeightDistribution,
    scale: float,
    support,
    tie_nodes: bool,
    tie_agents: bool,
    redraw: float = 0.0,
) -> WeightDistribution:
    """A distribution around one candidate's draws ``sample`` (the refine phase of
    ``cognet_weights``): Gaussian means at its weights and votes, spreads ``scale`` times those
    of the initial distribution ``init``; every categorical on the sample's choice mixed with
    ``scale`` of the uniform one (actions within ``support``); the tie flags too where tying is
    searched (``tie_nodes`` / ``tie_agents``), else ``init``'s; ``redraw`` the share of
    candidates that redraw one hidden unit from ``init`` (``redraw_unit``; kept as ``init``'s
    when it has none)."""
    rate = jnp.minimum(1.0, scale)

    def peaked(choice, k, allowed=None):
        return inject_entropy(jax.nn.one_hot(choice, k, dtype=jnp.float32), rate, allowed)

    q = init.default_probs.shape[-1]
    return WeightDistribution(
        action_probs=peaked(sample.actions, init.action_probs.shape[-1], support),
        w1_mean=sample.w1,
        w1_std=scale * init.w1_std,
        b1_mean=sample.b1,
        b1_std=scale * init.b1_std,
        unit_target_probs=peaked(sample.unit_targets, q),
        m_mean=sample.m,
        m_std=scale * init.m_std,
        default_probs=peaked(sample.default, q),
        bias_mean=sample.bias,
        bias_std=scale * init.bias_std,
        node_tie_probs=peaked(sample.node_tie, 2) if tie_nodes else init.node_tie_probs,
        agent_tie_probs=peaked(sample.agent_tie, 2) if tie_agents else init.agent_tie_probs,
        distinct_probs=None
        if init.distinct_probs is None
        else peaked(reproduces_distinct(sample.actions, support), 2),
        redraw=None if init.redraw is None else jnp.float32(redraw),
        start_probs=None
        if init.start_probs is None
        else peaked(
            jnp.zeros(sample.actions.shape[0], jnp.int32) if sample.start is None else sample.start,
            q,
        ),
    )


def redraw_unit(key: jax.Array, sample: WeightSample, init: WeightDistribution, rate):
    """``sample`` (leading ``[num]`` candidate axis, before ``tie``) where each candidate,
    with probability ``rate`` (``[]``), redraws one hidden unit -- its input weights, bias,
    target node and vote -- from the initial distribution ``init``: the unit of a uniform
    agent, node and index, in agent 0 where the candidate ties agents and in node 0 where it
    ties that agent's nodes (the network every node then runs).

    **[choice]** A converged controller leaves most of its units without a say (their vote
    never wins); around it, narrow Gaussians cannot add a region the controller lacks (the
    chase's "step back along x" on both ends of the bearing's range needs a unit past 2.4 rad
    voting for that node). A unit drawn from the broad initial distribution can, while the
    other candidates keep tuning the thresholds (experiments/NOTES.md)."""
    num, agents, q, f, h = sample.w1.shape
    ks = jax.random.split(key, 8)
    pick = jax.random.uniform(ks[0], (num,)) < rate
    agent = jnp.where(sample.agent_tie == 1, 0, jax.random.randint(ks[1], (num,), 0, agents))
    tied = jnp.take_along_axis(sample.node_tie, agent[:, None], 1)[:, 0] == 1
    node = jnp.where(tied, 0, jax.random.randint(ks[2], (num,), 0, q))
    unit = jax.random.randint(ks[3], (num,), 0, h)
    c = jnp.arange(num)

    def normal(k, mean, std, shape=()):
        return mean + std * jax.random.normal(k, (num,) + shape, jnp.float32)

    w1 = normal(ks[4], init.w1_mean[0, 0, :, 0], init.w1_std[0, 0, :, 0], (f,))
    b1 = normal(ks[5], init.b1_mean[0, 0, 0], init.b1_std[0, 0, 0])
    target_probs = jnp.broadcast_to(init.unit_target_probs[0, 0, 0], (num, q))
    target = sample_categorical(jax.random.uniform(ks[6], (num,)), target_probs)
    m = normal(ks[7], init.m_mean[0, 0, 0], init.m_std[0, 0, 0])

    unit_at = (c, agent, node, unit)  # one unit of each candidate ([num] indices)
    inputs_at = (c, agent, node, slice(None), unit)  # its input weights ([num, F])

    def put(x, at, value, chosen):
        return x.at[at].set(jnp.where(chosen, value, x[at]))

    return sample.replace(
        w1=put(sample.w1, inputs_at, w1, pick[:, None]),
        b1=put(sample.b1, unit_at, b1, pick),
        unit_targets=put(sample.unit_targets, unit_at, target, pick),
        m=put(sample.m, unit_at, m, pick),
    )


def reproduces_distinct(actions: jax.Array, support: jax.Array) -> jax.Array:
    """``[agents]`` int32: 1 where ``distinct_draw`` on categoricals peaked at ``actions
    [agents, Q]`` gives those actions again (no action repeats before every action has a
    node), so the refine phase draws the kept actions under the flag it centres on."""
    k = support.shape[-1]
    again = distinct_draw(None, jax.nn.one_hot(actions, k, dtype=jnp.float32), support)
    return jnp.all(again == actions, -1).astype(jnp.int32)


def distinct_draw(u: jax.Array | None, probs: jax.Array, support: jax.Array) -> jax.Array:
    """Actions drawn node after node, each from its node's categorical restricted to the
    actions no earlier node runs, until every action has a node; later nodes draw freely.
    ``u [..., agents, Q]`` uniforms in [0, 1), or ``None`` for the most likely actions (the
    mode); ``probs [..., agents, Q, actions]``; ``support [agents, 1, actions]`` the actions
    each agent has -> int32 ``[..., agents, Q]``. With Q >= actions every action is run by
    some node: a controller that must be able to do everything (move four ways and stay) is
    then one draw away, where independent draws give it once in 26 (5 nodes, 5 actions)."""
    if u is not None:  # one row of probabilities per candidate
        probs = jnp.broadcast_to(probs, u.shape + probs.shape[-1:])
    allowed = jnp.broadcast_to(support[..., 0, :], probs.shape[:-2] + probs.shape[-1:])

    def node(used, x):
        p_q, u_q = x  # [..., agents, actions], [..., agents] (or None)
        free = allowed & ~used
        mask = jnp.where(jnp.any(free, -1, keepdims=True), free, allowed)  # all once none is
        masked = p_q * mask  # left; uniform over them where the node gives them no mass
        p_q = jnp.where(jnp.sum(masked, -1, keepdims=True) > 0, masked, mask.astype(p_q.dtype))
        pick = (
            jnp.argmax(p_q, -1).astype(jnp.int32) if u_q is None else sample_categorical(u_q, p_q)
        )
        return used | jax.nn.one_hot(pick, probs.shape[-1], dtype=bool), pick

    xs = (jnp.moveaxis(probs, -2, 0), None if u is None else jnp.moveaxis(u, -1, 0))
    _, picks = jax.lax.scan(node, jnp.zeros(allowed.shape, bool), xs)
    return jnp.moveaxis(picks, 0, -1)


def draw_actions(key, probs: jax.Array, num: int, distinct, support: jax.Array) -> jax.Array:
    """``[num, agents, Q]`` int32 actions from the uniforms of ``key`` under ``probs [agents,
    Q, actions]``: one per node independently, and for the candidates whose flag ``distinct
    [num, agents]`` (or ``None``: none) is 1 by ``distinct_draw`` on the same uniforms."""
    u = jax.random.uniform(key, (num,) + probs.shape[:-1])
    actions = sample_categorical(u, probs)
    if distinct is None:
        return actions
    return jnp.where(distinct[..., None] == 1, distinct_draw(u, probs, support), actions)


def mode_of(dist: WeightDistribution, support: jax.Array, ties: bool) -> WeightSample:
    """The most likely controller of ``dist``: Gaussian means and the most likely categories
    (the actions distinct where the flag says so, ``distinct_draw``; tied where the tie flags
    say so and ``ties``); ``support [agents, 1, actions]`` the actions each agent has."""
    sample = WeightSample(
        actions=jnp.argmax(dist.action_probs, -1).astype(jnp.int32),
        w1=dist.w1_mean,
        b1=dist.b1_mean,
        unit_targets=jnp.argmax(dist.unit_target_probs, -1).astype(jnp.int32),
        m=dist.m_mean,
        default=jnp.argmax(dist.default_probs, -1).astype(jnp.int32),
        bias=dist.bias_mean,
        node_tie=jnp.argmax(dist.node_tie_probs, -1).astype(jnp.int32),
        agent_tie=jnp.argmax(dist.agent_tie_probs, -1).astype(jnp.int32),
    )
    if dist.distinct_probs is not None:
        flag = jnp.argmax(dist.distinct_probs, -1).astype(jnp.int32)
        chosen = distinct_draw(None, dist.action_probs, support)
        actions = jnp.where(flag[:, None] == 1, chosen, sample.actions)
        sample = sample.replace(actions=actions, distinct=flag)
    if dist.start_probs is not None:
        sample = sample.replace(start=jnp.argmax(dist.start_probs, -1).astype(jnp.int32))
    return tie(sample) if ties else sample


def fold_inputs(w1, b1, input_stats, whiten: bool):
    """``(w1, b1)`` of a first layer that reads the standardised features ``(x - mean) /
    scale`` (``input_stats = (mean, scale) [agents, F]``), or with ``whiten`` the whitened
    ``(x - mean) @ transform`` (``(mean, transform [agents, F, F])``), rewritten to read the
    raw ``x``: ``w1 [..., agents, Q, F, H]`` (a candidate axis or none), ``b1 [..., agents,
    Q, H]``."""
    if whiten:  # W1 -> transform @ W1
        input_mean, transform = input_stats
        w1 = jnp.einsum("afg,...aqgh->...aqfh", transform, w1)
        return w1, b1 - jnp.einsum("af,...aqfh->...aqh", input_mean, w1)
    input_mean, input_scale = input_stats
    lead = w1.ndim - 4
    scale = input_scale.reshape((1,) * lead + input_scale.shape[:1] + (1, -1, 1))
    shift = (input_mean / input_scale).reshape(scale.shape)
    return w1 / scale, b1 - jnp.sum(shift * w1, axis=-2)


def unfold_inputs(w1, b1, input_stats, whiten: bool):
    """The inverse of ``fold_inputs`` for one joint policy's first layer (``w1 [agents, Q, F,
    H]``, ``b1 [agents, Q, H]``)."""
    if whiten:  # W1 = transform^-1 @ raw W1
        input_mean, transform = input_stats
        b1 = b1 + jnp.einsum("af,aqfh->aqh", input_mean, w1)
        return jnp.einsum("afg,aqgh->aqfh", jnp.linalg.inv(transform), w1), b1
    input_mean, input_scale = input_stats
    w1 = w1 * input_scale[:, None, :, None]
    return w1, b1 + jnp.sum((input_mean / input_scale)[:, None, :, None] * w1, axis=-2)
