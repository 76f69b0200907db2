"""COGNet-DICE controllers (SPEC section 5): a categorical action distribution per node and one
small MLP per (agent, node) mapping an observation to logits over next nodes.

The MLPs are a single Flax module whose parameters are *stacked*: every leaf has leading axes
``[agents, nodes, ...]``; members are initialised independently (vmap over split keys) and never
share weights. Transitions are sampled from the softmax, in training and in evaluation.

Initialisation follows PyTorch's ``nn.Linear`` default used by the thesis code: weights and biases
uniform in ``+-1/sqrt(fan_in)``.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable

import flax.linen as nn
import jax
import jax.numpy as jnp
from flax import struct

from cognet_jax.controllers.base import sample_categorical, uniform_distribution
from cognet_jax.envs.base import UNROLLED_CATEGORIES, categorical_from_columns
from cognet_jax.errors import SimulatorError

#: Node nets with at most this many inputs and hidden units are evaluated as unrolled scalar
#: arithmetic in rollouts (``NeuralController.one_net_logits``); larger ones use ``dot``.
#: Written out, small networks run a search iteration several times faster than with ``dot``
#: (benchmarks/NOTES.md, "Written-out networks up to 12 inputs"); 12 keeps the heatmap's
#: committed rows, made with ``dot``, bit for bit.
UNROLL_MAX_IN = 12
UNROLL_MAX_HIDDEN = 32
#: Small node nets of controllers with at least this many nodes are applied in one fused loop
#: (``NeuralController.unrolled_agent_logits``); fewer nodes use a ``lax.scan`` over the nodes.
#: Both forms serve the per-rollout engine: controllers that are not ``agents_major``.
UNROLL_MIN_NODES = 4
#: Controllers with small written-out networks, at most this many nodes, and at most this many
#: ``where``s to pick a rollout's member weights run in the rollout engine's rollouts-last
#: layout and draw from the current node's network alone (``NeuralController.agents_major``,
#: ``selected_member_logits``). Beyond these limits the picks cost more than the other forms
#: spare (benchmarks/NOTES.md, "Ninth pass").
AGENTS_MAJOR_MAX_NODES = 6
AGENTS_MAJOR_MAX_WHERES = 600
#: Agents-major controllers with at most this many picks ask the rollout engine for 16-bit
#: nodes (``narrow_nodes``): faster up to this many picks, slower beyond
#: (benchmarks/NOTES.md, "Eleventh pass").
NARROW_NODES_MAX_WHERES = 330


def _torch_uniform(fan_in: int):
    bound = 1.0 / math.sqrt(fan_in)

    def init(key, shape, dtype=jnp.float32):
        return jax.random.uniform(key, shape, dtype, -bound, bound)

    return init


class NodeNet(nn.Module):
    """obs ``[*obs_shape]`` -> hidden (ReLU) -> ``out`` logits. One member of the stack."""

    in_features: int
    hidden: int
    out: int

    @nn.compact
    def __call__(self, obs: jax.Array) -> jax.Array:
        x = obs.reshape(-1).astype(jnp.float32)
        x = nn.Dense(
            self.hidden,
            kernel_init=_torch_uniform(self.in_features),
            bias_init=_torch_uniform(self.in_features),
        )(x)
        x = nn.relu(x)
        return nn.Dense(
            self.out, kernel_init=_torch_uniform(self.hidden), bias_init=_torch_uniform(self.hidden)
        )(x)


@struct.dataclass
class NeuralPolicy:
    """A stochastic joint COGNet-DICE controller.

    ``action_probs [agents, nodes, actions]``; ``net_params``: Flax params, leaves
    ``[agents, nodes, ...]``.
    """

    action_probs: jax.Array
    net_params: dict


@dataclasses.dataclass(frozen=True)
class NeuralController:
    """Static shape facts of a neural FSC; ``act`` / ``next_node`` are the rollout hooks, and
    ``agent_act`` / ``agent_next_node`` their per-agent forms (the engine's rollouts-last
    layout, ``agents_major``).

    ``obs_shape`` is the shape the node networks read. ``features`` (optional) maps the
    environment's observation ``[agents, *raw]`` to that input ``[agents, *obs_shape]`` before
    the networks (e.g. a VAE encoder, ``cognet_jax.observations``); ``None`` is the identity.
    """

    num_agents: int
    num_nodes: int
    num_actions: int
    obs_shape: tuple[int, ...] = ()
    hidden: int = 10
    action_counts: tuple[int, ...] | None = None
    features: Callable[[jax.Array], jax.Array] | None = None

    @property
    def in_features(self) -> int:
        return math.prod(self.obs_shape)

    @property
    def net(self) -> NodeNet:
        return NodeNet(in_features=self.in_features, hidden=self.hidden, out=self.num_nodes)

    @functools.partial(jax.jit, static_argnums=0)
    def init_net_params(self, key: jax.Array) -> dict:
        """Independent members for every (agent, node): leaves ``[agents, nodes, ...]``.
        A ``jit`` (the controller static): one program, not Flax's initialisers op by op."""
        a, n = self.num_agents, self.num_nodes
        keys = jax.random.split(key, a * n)
        dummy = jnp.zeros(self.obs_shape, jnp.float32)
        params = jax.vmap(lambda k: self.net.init(k, dummy))(keys)
        return jax.tree.map(lambda p: p.reshape((a, n) + p.shape[1:]), params)

    def init(self, key: jax.Array) -> NeuralPolicy:
        probs = uniform_distribution(
            (self.num_agents, self.num_nodes, self.num_actions), self.action_counts
        )
        return NeuralPolicy(action_probs=probs, net_params=self.init_net_params(key))

    @property
    def unrolled(self) -> bool:
        """Whether ``one_net_logits`` writes the MLP out as scalar multiply-adds (small nets)."""
        return self.in_features <= UNROLL_MAX_IN and self.hidden <= UNROLL_MAX_HIDDEN

    def one_net_logits(self, member_params: dict, obs: jax.Array) -> jax.Array:
        """Logits ``[nodes]`` of one member for one observation ``[*obs_shape]``.

        Small nets (``unrolled``) are written out as ``hidden * (in + 1)`` scalar multiply-adds
        instead of two ``dot``s: under ``vmap`` over rollouts XLA then fuses the whole net into
        one loop over the rollouts, where a ``dot`` with 1-10 inputs and 3-6 outputs runs at a
        few GFLOP/s and writes the ``[rollouts, hidden]`` activations to memory
        (benchmarks/NOTES.md). Same function as
        ``self.net.apply`` (the Flax module, used for training), up to float rounding."""
        if not self.unrolled:
            return self.net.apply(member_params, obs)
        self.check_inputs(obs)
        return _written_out_mlp(member_params["params"], obs)

    def check_inputs(self, obs: jax.Array) -> None:
        """Refuse an observation with another number of inputs than the networks read (a
        simulator whose observations change shape between steps: ``SimulatorError``)."""
        if math.prod(obs.shape) != self.in_features:
            raise SimulatorError(
                f"the simulator's observation has shape {tuple(obs.shape)} per agent at a step "
                f"where the node networks read {self.in_features} inputs (its obs_shape "
                f"{self.obs_shape}): a step must return the same shapes every time"
            )

    def node_logits(self, net_params: dict, nodes: jax.Array, obs: jax.Array) -> jax.Array:
        """Logits ``[agents, nodes]`` of each agent's current-node network on its observation
        (``agent_node_logits`` for every agent)."""
        return jax.vmap(self.agent_node_logits)(net_params, nodes, obs)

    def agent_node_logits(self, members: dict, node: jax.Array, obs: jax.Array) -> jax.Array:
        """Logits ``[nodes]`` of one agent's current-node network: ``members`` the agent's
        networks (leaves ``[nodes, ...]``), ``node`` its current node (int scalar), ``obs`` its
        network input ``[*obs_shape]``.

        Every member is applied and its logits kept where the agent is in that node (``where``),
        instead of gathering each rollout's member weights: under ``vmap`` over rollouts each
        member is then one fused loop (or one batched matmul) over all rollouts and no
        per-rollout copy of the weights is made (benchmarks/NOTES.md: the gather is slower).

        Two forms of the same arithmetic, the same numbers bit for bit with XLA's default CPU
        emitters (tests/test_neural.py):
        ``lax.scan`` over the nodes (``scan_agent_logits``), whose carry is written to memory
        after each member, or the members written out one after the other
        (``unrolled_agent_logits``), which XLA computes in one fused loop and writes once. The
        second is used for small (``unrolled``) networks with at least
        ``UNROLL_MIN_NODES`` nodes. With fewer nodes XLA fuses the written-out networks into the
        softmax and draw that read the logits, and computes them again for each read, so the
        scan's
        stores are the cheaper way there (benchmarks/NOTES.md, "Fifth pass")."""
        if self.unrolled and self.num_nodes >= UNROLL_MIN_NODES:
            return self.unrolled_agent_logits(members, node, obs)
        return self.scan_agent_logits(members, node, obs)

    def scan_agent_logits(self, members: dict, node: jax.Array, obs: jax.Array) -> jax.Array:
        """``agent_node_logits`` as a ``lax.scan`` over the nodes (carry ``[nodes]``)."""

        def keep_if_current(out, node_and_member):
            n, member = node_and_member
            return jnp.where(node == n, self.one_net_logits(member, obs), out), None

        init = jnp.zeros(self.num_nodes, jnp.float32)
        out, _ = jax.lax.scan(keep_if_current, init, (jnp.arange(self.num_nodes), members))
        return out

    def selected_member_logits(self, members: dict, node: jax.Array, obs: jax.Array) -> tuple:
        """``agent_node_logits`` as ``nodes`` scalars, computed by the current node's member
        alone: each of its weights is picked from the ``[nodes]`` members by a ``where`` chain
        over the nodes, then the written-out network runs on them. Under ``vmap`` over
        rollouts (the rollouts-last layout, ``agents_major``) each output is an array of its
        own whose minor axis is the rollouts, and XLA fuses the picks, the network, the softmax
        and the draw into one loop over the rollouts: one network per rollout instead of one
        per member and rollout, and no logit written to memory (benchmarks/NOTES.md, "Ninth
        pass").
        The same operations on the same numbers as every member's network kept where the
        agent is in that node (``scan_agent_logits``): the same logits bit for bit."""
        self.check_inputs(obs)
        return _selected_member_outputs(members["params"], node, obs)

    def unrolled_agent_logits(self, members: dict, node: jax.Array, obs: jax.Array) -> jax.Array:
        """``agent_node_logits`` with the members written out in a Python loop, each member's
        logits one ``[nodes]`` vector (the same operations in the same order as
        ``scan_agent_logits``)."""
        out = jnp.zeros(self.num_nodes, jnp.float32)
        for n in range(self.num_nodes):
            member = jax.tree.map(lambda p, n=n: p[n], members)
            out = jnp.where(node == n, self.one_net_logits(member, obs), out)
        return out

    def scan_node_logits(self, net_params: dict, nodes: jax.Array, obs: jax.Array) -> jax.Array:
        """``node_logits`` with the scan form for every agent."""
        return jax.vmap(self.scan_agent_logits)(net_params, nodes, obs)

    def unrolled_node_logits(self, net_params: dict, nodes: jax.Array, obs: jax.Array) -> jax.Array:
        """``node_logits`` with the written-out form for every agent."""
        return jax.vmap(self.unrolled_agent_logits)(net_params, nodes, obs)

    def all_node_logits(self, net_params: dict, obs: jax.Array) -> jax.Array:
        """Logits ``[agents, nodes, next_nodes]`` of every member on its agent's ``obs``."""
        return jax.vmap(jax.vmap(self.one_net_logits, (0, None)), (0, 0))(net_params, obs)

    def act(self, u, policy: NeuralPolicy, nodes):
        probs = rows_at(policy.action_probs, nodes)
        return sample_categorical(u, probs)

    def node_inputs(self, obs: jax.Array) -> jax.Array:
        """The networks' inputs ``[agents, *obs_shape]`` from raw observations ``[agents, *raw]``
        (``features``, or the observations themselves)."""
        return obs if self.features is None else self.features(obs)

    def next_node(self, u, policy: NeuralPolicy, nodes, obs):
        """Next nodes ``[agents]`` from the raw observations ``obs [agents, *raw]``."""
        return jax.vmap(self.agent_next_node)(u, policy, nodes, self.node_inputs(obs))

    @property
    def agents_major(self) -> bool:
        """Whether the rollout engine should lay its arrays out with the rollouts last and
        call the per-agent functions (``agent_act``, ``agent_next_node``; ``rollout._Steps``):
        for written-out (``unrolled``) networks, whose elementwise arithmetic gives the same
        numbers in any layout, with at most ``AGENTS_MAJOR_MAX_NODES`` nodes and
        ``AGENTS_MAJOR_MAX_WHERES`` picks of member weights (``selected_member_logits``), and no
        ``features`` (an encoder's matrix products might round differently in another
        layout)."""
        return (
            self.unrolled
            and self.num_nodes <= AGENTS_MAJOR_MAX_NODES
            and self.picks <= AGENTS_MAJOR_MAX_WHERES
            and self.features is None
        )

    @property
    def picks(self) -> int:
        """The ``where``s that pick one rollout's member weights: ``(nodes - 1) x`` the
        weights of one member network."""
        weights = self.hidden * (self.in_features + 1) + self.num_nodes * (self.hidden + 1)
        return (self.num_nodes - 1) * weights

    @property
    def narrow_nodes(self) -> bool:
        """Whether the rollout engine should hold the nodes as 16-bit integers where it can
        (``rollout._TimeLoop``): the kernel that draws the next nodes then writes 16-bit
        numbers, and LLVM vectorises it 16 rollouts at a time instead of 8 (two 256-bit
        registers per float), which pays while the picks' registers fit: agents-major
        controllers with at most ``NARROW_NODES_MAX_WHERES`` picks. The same numbers."""
        return self.agents_major and self.picks <= NARROW_NODES_MAX_WHERES

    def agent_act(self, u, policy: NeuralPolicy, node):
        """One agent's action (int32 scalar) from its slice of ``policy`` (``action_probs
        [nodes, actions]``) at ``node``: ``act`` for one agent, the probabilities of the current
        node as one scalar per action (``categorical_from_columns``; a ``where`` chain over the
        nodes as ``rows_at``)."""
        table = policy.action_probs
        columns = [pick(node, table[:, k]) for k in range(table.shape[1])]
        if len(columns) > UNROLLED_CATEGORIES:  # the draw of ``categorical_from_uniform``
            return sample_categorical(u, jnp.stack(columns))
        return categorical_from_columns(u, columns)

    def agent_next_node(self, u, policy: NeuralPolicy, node, inputs):
        """One agent's next node (int32 scalar): ``u`` uniform scalar, ``policy`` that agent's
        slice (leaves ``[nodes, ...]``), ``node`` its current node, ``inputs`` its network input
        ``[*obs_shape]`` (``node_inputs``). Agents-major controllers draw from one array per
        logit (``selected_member_logits``, ``softmax_columns``, ``categorical_from_columns``),
        the others from the ``[nodes]`` logits: the same numbers."""
        if self.agents_major:
            logits = self.selected_member_logits(policy.net_params, node, inputs)
            return categorical_from_columns(u, softmax_columns(logits))
        weights = softmax_weights(self.agent_node_logits(policy.net_params, node, inputs))
        return sample_categorical(u, weights)


@jax.jit
def _written_out_mlp(p: dict, obs: jax.Array) -> jax.Array:
    """``NodeNet`` (``Dense_0``, relu, ``Dense_1``) on one observation, as scalar multiply-adds
    (``NeuralController.one_net_logits``): logits ``[nodes]`` from ``obs`` (``in`` numbers),
    each hidden unit added to all logits at once (``_selected_member_outputs`` computes the
    same numbers as one scalar per logit).

    Jitted, so its ``hidden * (in + 1)`` traced operations are traced once per shape and the
    trace reused: a rollout applies it in the scan's body and in its last step, for every
    rollout engine of an iteration, and every program of a process (``envs.base.
    normal_from_uniform``, the same change). XLA inlines it: the same numbers bit for bit."""
    w1, b1, w2, b2, x = _operands(p, obs)
    out = b2
    for j in range(w1.shape[1]):
        out = out + jnp.maximum(_hidden_unit(w1, b1, x, j), 0.0) * w2[j]
    return out


def _operands(p: dict, obs: jax.Array) -> tuple[jax.Array, ...]:
    """``NodeNet``'s weights and input: ``w1 [in, hidden]``, ``b1 [hidden]``, ``w2 [hidden,
    nodes]``, ``b2 [nodes]`` and ``x [in]`` (float32)."""
    w1, b1 = p["Dense_0"]["kernel"], p["Dense_0"]["bias"]
    w2, b2 = p["Dense_1"]["kernel"], p["Dense_1"]["bias"]
    return w1, b1, w2, b2, obs.reshape(-1).astype(jnp.float32)


def _hidden_unit(w1: jax.Array, b1: jax.Array, x: jax.Array, j: int) -> jax.Array:
    """Pre-activation of hidden unit ``j``: ``b1[j] + x[0] w1[0, j] + x[1] w1[1, j] + ...``."""
    pre = b1[j]
    for i in range(w1.shape[0]):
        pre = pre + x[i] * w1[i, j]
    return pre


@jax.jit
def _selected_member_outputs(p: dict, node: jax.Array, obs: jax.Array) -> tuple[jax.Array, ...]:
    """The current node's ``NodeNet`` (``Dense_0``, relu, ``Dense_1``) on one observation, as
    scalar multiply-adds (``NeuralController.selected_member_logits``): ``p`` the members'
    params (leaves ``[nodes, ...]``), ``node`` the current node (int scalar), ``obs`` the input
    (``in`` numbers); the ``nodes`` logits, one scalar each. Each weight is ``pick``ed from the
    members; logit k is ``b2[k] + relu(h_0) w2[0, k] + relu(h_1) w2[1, k] + ...`` summed in
    that order, as ``_written_out_mlp`` sums it.

    Jitted, so its traced operations are traced once per shape and the trace reused: a rollout
    applies it in the scan's body and in its last step, for every rollout engine of an
    iteration, and every program of a process (``envs.base.normal_from_uniform``). XLA
    inlines it."""
    w1, b1, w2, b2, x = _operands(p, obs)

    def weight(a: jax.Array, *index: int) -> jax.Array:
        return pick(node, a[(slice(None), *index)])

    outs = [weight(b2, k) for k in range(w2.shape[2])]
    for j in range(w1.shape[2]):
        pre = weight(b1, j)
        for i in range(w1.shape[1]):
            pre = pre + x[i] * weight(w1, i, j)
        hidden = jnp.maximum(pre, 0.0)
        outs = [out + hidden * weight(w2, j, k) for k, out in enumerate(outs)]
    return tuple(outs)


def pick(node: jax.Array, values: jax.Array) -> jax.Array:
    """``values[node]`` of ``values [nodes, ...]`` as a chain of ``where``s over the nodes: under
    ``vmap`` over rollouts a select XLA fuses into the loop that reads it, where a gather would
    be a kernel of its own writing each rollout's value to memory."""
    out = values[0]
    for q in range(1, values.shape[0]):
        out = jnp.where(node == q, values[q], out)
    return out


def rows_at(table: jax.Array, nodes: jax.Array) -> jax.Array:
    """``table[a, nodes[a]]`` for every agent a: ``table [agents, nodes, K]`` -> ``[agents, K]``.

    With few nodes each agent's row is ``pick``ed (a chain of ``where`` over the nodes, which
    XLA fuses into the draw that uses it); a gather of each rollout's row is a kernel of its own
    and writes the rows to memory."""
    if table.shape[1] > UNROLLED_CATEGORIES:
        return table[jnp.arange(table.shape[0]), nodes]
    return jax.vmap(pick)(nodes, table)


def softmax_columns(logits) -> list[jax.Array]:
    """``softmax_weights`` of logits given as K arrays (one per category): the K weights as K
    arrays, the same operations on every element."""
    top = logits[0]
    for column in logits[1:]:
        top = jnp.maximum(top, column)
    return [jnp.exp(column - top) for column in logits]


def softmax_weights(logits: jax.Array) -> jax.Array:
    """``exp(logits - max(logits))`` over the last axis: the softmax without its division, which
    the inverse-CDF draw does not need (it scales ``u`` by the sum). With few categories the
    maximum is written out over the K slices, so XLA fuses it with the draw; a ``reduce`` over
    an axis of 3-6 is a kernel of its own on CPU (benchmarks/NOTES.md)."""
    k = logits.shape[-1]
    if k > UNROLLED_CATEGORIES:
        return jnp.exp(logits - jnp.max(logits, axis=-1, keepdims=True))
    top = logits[..., 0]
    for i in range(1, k):
        top = jnp.maximum(top, logits[..., i])
    return jnp.exp(logits - top[..., None])
