"""The search space of the default ``cognet-dice`` (``algorithms.cognet_weights``): the
distribution over joint neural controllers, one candidate's draws, and the tying of nodes and
agents. Shapes: ``Q`` nodes, ``F`` network inputs, ``H`` hidden units."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct


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
    return sample.replace(**{f: pick(getattr(sample, f), agent_src, lead) for f in fields})


def gaussian_refit(mean, std, elite_draws, alpha):
    """``alpha * (elite mean, elite std) + (1 - alpha) * (mean, std)``; ``elite_draws [E, ...]``."""
    return (
        alpha * elite_draws.mean(0) + (1.0 - alpha) * mean,
        alpha * elite_draws.std(0) + (1.0 - alpha) * std,
    )
