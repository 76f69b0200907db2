"""Region FSCs for scalar continuous observations (COG-DICE, SPEC section 4).

Node q of agent i cuts the observation axis with sorted division points
``points[i, q, :]`` (``N_t - 1`` of them) into ``N_t`` regions; the region of ``z`` is the
number of points strictly below ``z``, so region r is ``(p_{r-1}, p_r]``. A deterministic region
controller has ``actions [agents, nodes]``, ``points [agents, nodes, N_t - 1]`` and
``transitions [agents, nodes, N_t]`` (next node per region).
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct


@struct.dataclass
class DeterministicRegionPolicy:
    actions: jax.Array  # [agents, nodes] int32
    points: jax.Array  # [agents, nodes, regions - 1] float32, sorted
    transitions: jax.Array  # [agents, nodes, regions] int32


def region_of(points: jax.Array, z: jax.Array) -> jax.Array:
    """Number of ``points [..., P]`` strictly below ``z [...]`` (int32 ``[...]``)."""
    return jnp.sum(points < z[..., None], axis=-1).astype(jnp.int32)


@dataclasses.dataclass(frozen=True)
class RegionController:
    num_agents: int
    num_nodes: int
    num_regions: int

    def act(self, u, policy: DeterministicRegionPolicy, nodes):
        return policy.actions[jnp.arange(self.num_agents), nodes]

    def next_node(self, u, policy: DeterministicRegionPolicy, nodes, obs):
        agents = jnp.arange(self.num_agents)
        region = region_of(policy.points[agents, nodes], obs)
        return policy.transitions[agents, nodes, region]


def reactive_tagging_policy(
    num_agents: int = 2,
) -> tuple[RegionController, DeterministicRegionPolicy]:
    """The reactive 3-node tagging controller of SPEC section 8: node 0 moves left, node 1 tags,
    node 2 moves right; from every node the next node is chosen by the region of the
    observation ``z = e - p``: ``(-inf, -1]`` -> node 0 (left), ``(-1, 1]`` -> node 1 (tag),
    ``(1, inf)`` -> node 2 (right)."""
    ctrl = RegionController(num_agents=num_agents, num_nodes=3, num_regions=3)
    policy = DeterministicRegionPolicy(
        actions=jnp.tile(jnp.array([1, 0, 2], jnp.int32), (num_agents, 1)),
        points=jnp.tile(jnp.array([-1.0, 1.0], jnp.float32), (num_agents, 3, 1)),
        transitions=jnp.tile(jnp.array([0, 1, 2], jnp.int32), (num_agents, 3, 1)),
    )
    return ctrl, policy


def region_graph_edges(points, transitions) -> list[tuple[int, int, list[tuple[float, float]]]]:
    """Edges of one agent's deterministic region controller, for ``plots.plot_controller_graphs``.

    ``points [nodes, regions - 1]`` sorted, ``transitions [nodes, regions]`` (plain numpy or JAX
    arrays). Returns ``(src, dst, [(lo, hi), ...])`` sorted by ``(src, dst)``: the observation
    intervals ``(lo, hi]`` (``-inf`` / ``inf`` at the ends) leading from ``src`` to ``dst``,
    adjacent regions with the same ``dst`` merged, empty regions (equal points) left out -- the
    same format as ``plots.controller_graph_edges`` but with the exact division points.
    """
    pts = np.asarray(points, dtype=float)
    trans = np.asarray(transitions)
    edges = []
    for src in range(trans.shape[0]):
        bounds = [-math.inf, *pts[src].tolist(), math.inf]
        by_dst: dict[int, list[tuple[float, float]]] = {}
        for r, dst in enumerate(trans[src].tolist()):
            lo, hi = bounds[r], bounds[r + 1]
            if not lo < hi:
                continue
            intervals = by_dst.setdefault(int(dst), [])
            if intervals and intervals[-1][1] == lo:
                intervals[-1] = (intervals[-1][0], hi)
            else:
                intervals.append((lo, hi))
        edges.extend((src, dst, by_dst[dst]) for dst in sorted(by_dst))
    return edges
