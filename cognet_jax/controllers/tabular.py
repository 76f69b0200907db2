"""Tabular FSCs for discrete observations (G-DICE, SPEC section 3).

* ``TabularDistribution``: the search distribution -- ``action_probs [agents, nodes, actions]``
  and ``transition_probs [agents, nodes, obs, nodes]`` (``phi[q, z, q']``).
* ``DeterministicTabularPolicy``: one sampled controller -- ``actions [agents, nodes]`` and
  ``transitions [agents, nodes, obs]`` (int32). This is what G-DICE evaluates.

**[option]** ``layers=L`` (a *time-layered* controller for a finite horizon of L steps): the
``num_nodes`` nodes form L layers of ``num_nodes // L`` nodes; node q of layer t acts at time t
and moves only to nodes of layer t + 1 (the last layer to itself). The transition distribution
is zero outside the next layer (``transition_support``), so sampling, count MLE and smoothing
keep every controller layered. Layered controllers are policy graphs of bounded width: node
reuse across time steps is ruled out, which is what a finite-horizon optimum needs anyway, and
every node's distribution learns what to do at one depth only.

**[option]** ``shared=True`` (identical agents): every sample is one controller drawn from agent
0's rows and given to every agent, so the joint controllers searched are the symmetric ones.
The distribution keeps its ``[agents, ...]`` shape; because every elite's table is the same for
all agents, count MLE, smoothing and entropy injection keep the agents' rows equal.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
from flax import struct

from cognet_jax.controllers.base import sample_categorical, uniform_distribution


@struct.dataclass
class TabularDistribution:
    action_probs: jax.Array  # [agents, nodes, actions]
    transition_probs: jax.Array  # [agents, nodes, obs, nodes]


@struct.dataclass
class DeterministicTabularPolicy:
    actions: jax.Array  # [agents, nodes] int32
    transitions: jax.Array  # [agents, nodes, obs] int32


@dataclasses.dataclass(frozen=True)
class TabularController:
    """Deterministic Moore FSC over discrete observations (static shapes only)."""

    num_agents: int
    num_nodes: int
    num_actions: int
    num_obs: int
    action_counts: tuple[int, ...] | None = None
    obs_counts: tuple[int, ...] | None = None
    shared: bool = False
    #: 0: a free FSC; L > 0: L time layers of ``num_nodes // L`` nodes (see module docstring)
    layers: int = 0

    def __post_init__(self):
        if self.layers and self.num_nodes % self.layers:
            raise ValueError(f"{self.num_nodes} nodes do not split into {self.layers} layers")

    @property
    def layer_width(self) -> int:
        """Nodes per layer (all nodes for a free FSC)."""
        return self.num_nodes // self.layers if self.layers else self.num_nodes

    def _layers_of_nodes(self) -> tuple[jax.Array, jax.Array]:
        """``(layer, target)`` ``[nodes]`` int32 of a layered controller: each node's layer and
        the layer it moves to, ``min(layer + 1, L - 1)``."""
        layer = jnp.arange(self.num_nodes, dtype=jnp.int32) // self.layer_width
        return layer, jnp.minimum(layer + 1, self.layers - 1)

    def transition_support(self) -> jax.Array | None:
        """Allowed next nodes ``[nodes, 1, nodes]`` bool of a layered controller (``None`` for
        a free FSC): node q of layer t may move to layer ``min(t + 1, L - 1)`` only."""
        if not self.layers:
            return None
        layer, target = self._layers_of_nodes()
        return (layer[None, :] == target[:, None])[:, None, :]

    @functools.partial(jax.jit, static_argnums=0)
    def init_distribution(self) -> TabularDistribution:
        """Uniform rows (a layered controller's over the next layer only). This and ``sample``
        are ``jit``s with the controller static: one program each where they run eagerly (a
        search's initial state built outside a program), inlined inside one."""
        a, n = self.num_agents, self.num_nodes
        trans = uniform_distribution((a, n, self.num_obs, n))
        support = self.transition_support()
        if support is not None:
            trans = support.astype(jnp.float32) / support.sum(-1, keepdims=True)
            trans = jnp.broadcast_to(trans, (a, n, self.num_obs, n))
        return TabularDistribution(
            action_probs=uniform_distribution((a, n, self.num_actions), self.action_counts),
            transition_probs=trans,
        )

    @functools.partial(jax.jit, static_argnums=0)
    def sample(self, key: jax.Array, dist: TabularDistribution) -> DeterministicTabularPolicy:
        """Draw one deterministic joint controller from the search distribution (with
        ``shared``: one controller from agent 0's rows, the same for every agent)."""
        if self.shared:
            one = self._sample_rows(key, dist.action_probs[:1], dist.transition_probs[:1])
            return jax.tree.map(
                lambda x: jnp.broadcast_to(x, (self.num_agents,) + x.shape[1:]), one
            )
        return self._sample_rows(key, dist.action_probs, dist.transition_probs)

    def _sample_rows(self, key, action_probs, transition_probs) -> DeterministicTabularPolicy:
        k_a, k_t = jax.random.split(key)
        u_a = jax.random.uniform(k_a, action_probs.shape[:-1])
        u_t = jax.random.uniform(k_t, transition_probs.shape[:-1])
        return DeterministicTabularPolicy(
            actions=sample_categorical(u_a, action_probs),
            transitions=self._sample_next_nodes(u_t, transition_probs),
        )

    def _sample_next_nodes(self, u: jax.Array, transition_probs: jax.Array) -> jax.Array:
        """Next nodes ``[agents, nodes, obs]`` drawn by inverse CDF from ``transition_probs
        [agents, nodes, obs, nodes]`` with the uniforms ``u [agents, nodes, obs]``. A layered
        controller's rows are zero outside the next layer (``transition_support``), so only
        that layer's ``layer_width`` entries are read: the same draw (the zeros before the
        window add nothing to the cumulative sum) at ``layers`` times less work, which at h 10
        is most of an iteration's sampling."""
        if not self.layers:
            return sample_categorical(u, transition_probs)
        # index arrays as jnp ops, not numpy constants: a size refused while the initial
        # state is traced must not be built in host memory first. Node ids are int32: more
        # nodes raise OverflowError here (memory.trace_checked makes it a one-line error)
        jnp.asarray(self.num_nodes - 1, jnp.int32)
        layers, w = self.layers, self.layer_width
        agents, obs = transition_probs.shape[0], transition_probs.shape[2]
        _, target = self._layers_of_nodes()  # [nodes]
        blocks = transition_probs.reshape(agents, layers, w, obs, layers, w)
        # [agents, layers, w, obs, w]: each layer's rows over its next layer's nodes
        window = jnp.moveaxis(blocks[:, jnp.arange(layers), :, :, target[::w], :], 0, 1)
        local = sample_categorical(u, window.reshape(agents, self.num_nodes, obs, w))
        return local + (target * w)[None, :, None]  # + the first node of the next layer

    def act(self, u, policy: DeterministicTabularPolicy, nodes):
        return policy.actions[jnp.arange(self.num_agents), nodes]

    def next_node(self, u, policy: DeterministicTabularPolicy, nodes, obs):
        return policy.transitions[jnp.arange(self.num_agents), nodes, obs]
