"""Hand-written controllers: a Moore FSC whose next node is a rule of the observation.

What a practitioner writes in ten minutes for a new simulator: a few nodes, each with a fixed
action, and a rule that picks the next node from the current one and the observation, with a
few thresholds tuned by a grid search (``baselines.tune``). Every simulator of the suite
ships one (``hand_controller`` in its module), the yardstick the searches must beat.

``RuleController(num_agents, num_nodes, rule)``: ``rule(theta, nodes [agents], obs [agents,
*obs_shape]) -> next nodes [agents]`` (int32), a pure JAX function; ``RulePolicy`` holds the
node actions ``[agents, nodes]`` and the thresholds ``theta`` (a pytree). All agents start in
node 0 (SPEC section 1), so node 0's action is the blind first move.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import jax
import jax.numpy as jnp
from flax import struct


@struct.dataclass
class RulePolicy:
    actions: jax.Array  # [agents, nodes] int32
    theta: dict  # the rule's thresholds (scalars or per-agent arrays)


@dataclasses.dataclass(frozen=True)
class RuleController:
    """A deterministic FSC driven by ``rule`` (see the module docstring)."""

    num_agents: int
    num_nodes: int
    rule: Callable

    def act(self, u, policy: RulePolicy, nodes):
        return policy.actions[jnp.arange(self.num_agents), nodes]

    def next_node(self, u, policy: RulePolicy, nodes, obs):
        nxt = self.rule(policy.theta, nodes, obs)
        return jnp.clip(nxt, 0, self.num_nodes - 1).astype(jnp.int32)


def rule_policy(num_agents: int, node_actions, theta: dict) -> RulePolicy:
    """The same ``node_actions [nodes]`` for every agent, thresholds ``theta`` as float32."""
    actions = jnp.tile(jnp.asarray(node_actions, jnp.int32)[None], (num_agents, 1))
    return RulePolicy(actions, {k: jnp.float32(v) for k, v in theta.items()})
