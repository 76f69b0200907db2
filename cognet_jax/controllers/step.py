"""``controller_step``: run a learned controller inside your own JAX simulation.

A learned joint controller is a policy pytree (``NeuralPolicy``, ``EncodedPolicy``,
``DeterministicTabularPolicy``, ``TabularDistribution`` or ``DeterministicRegionPolicy``);
``controller_step`` needs nothing else -- the controller kind and its static facts (agents,
nodes, hidden units) are read from the policy's array shapes, so it is a pure function of arrays
that jits and vmaps. A plug-in algorithm's own policy type joins them with
``register_policy_type`` (its controller, agents and observation size from the policy). An
encoded COGNet-DICE search's networks read a VAE encoding of the raw observation:
``portable_policy(algorithm, policy)`` bundles the encoder with the policy (``EncodedPolicy``),
and ``controller_step`` then takes the raw observation. Observations whose
shape does not match what the policy reads are refused (``ValueError``, at trace time).

Order within one time step, from the agents' side (SPEC section 1, Moore controllers): every
agent sits in a node q, receives its observation z, moves to ``q' ~ g(. | q, z)`` and plays
``a ~ pi(. | q')``. All agents start in node 0 and the first action comes before any
observation: pass ``observation=None`` on the first call (the node is then kept). A user loop::

    action, node = controller_step(policy, jnp.zeros(agents, jnp.int32), None, key_0)
    for t in 1, 2, ...:   # (a lax.scan in practice)
        sim_state, obs = your_sim(sim_state, action)
        action, node = controller_step(policy, node, obs, key_t)

This is the same process as :func:`cognet_jax.rollout.rollouts` (there a time step's random
block draws ``a_t`` at ``q_t`` and then ``q_{t+1}`` from ``z_{t+1}``; here the node move comes
first and the action second, so the same draws are grouped differently).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import jax
import jax.numpy as jnp

from cognet_jax.controllers.base import sample_categorical
from cognet_jax.controllers.encoded import EncodedPolicy
from cognet_jax.controllers.neural import NeuralController, NeuralPolicy
from cognet_jax.controllers.regions import DeterministicRegionPolicy, RegionController
from cognet_jax.controllers.tabular import (
    DeterministicTabularPolicy,
    TabularController,
    TabularDistribution,
)


@dataclasses.dataclass(frozen=True)
class PolicyType:
    """How ``controller_step`` runs one kind of policy pytree: ``controller(policy)`` gives an
    object with ``act(u [agents], policy, nodes [agents]) -> actions [agents]`` and
    ``next_node(u [agents], policy, nodes [agents], obs) -> nodes [agents]`` (the protocol of
    every controller in ``cognet_jax.controllers``); ``agents(policy)`` the number of agents;
    ``reads(policy)`` ``(numbers per agent, what they are, dtype)`` of one observation."""

    controller: Callable
    agents: Callable
    reads: Callable


_POLICY_TYPES: dict[type, PolicyType] = {}


def register_policy_type(
    cls: type, controller: Callable, agents: Callable, reads: Callable | None = None
) -> None:
    """Let ``controller_step`` run policies of ``cls`` (a plug-in algorithm's own policy type;
    ``PolicyType`` gives the three functions). ``reads`` defaults to one float per agent."""
    default = lambda policy: (1, "observation value", jnp.float32)  # noqa: E731
    _POLICY_TYPES[cls] = PolicyType(controller, agents, reads or default)


def policy_type(policy) -> PolicyType:
    """The registered ``PolicyType`` of a policy pytree, or ``TypeError``."""
    for cls in type(policy).__mro__:
        if cls in _POLICY_TYPES:
            return _POLICY_TYPES[cls]
    names = ", ".join(sorted(c.__name__ for c in _POLICY_TYPES))
    raise TypeError(
        f"controller_step: unsupported policy type {type(policy).__name__} (expected one of "
        f"{names}, or a type given to register_policy_type)"
    )


def controller_for(policy):
    """The controller (static facts) matching a policy pytree, from its shapes."""
    return policy_type(policy).controller(policy)


def _neural_controller(policy: NeuralPolicy) -> NeuralController:
    agents, nodes, actions = policy.action_probs.shape
    dense0 = policy.net_params["params"]["Dense_0"]["kernel"]  # [agents, nodes, in, hidden]
    return NeuralController(
        num_agents=agents,
        num_nodes=nodes,
        num_actions=actions,
        obs_shape=(dense0.shape[2],),
        hidden=dense0.shape[3],
    )


@dataclasses.dataclass(frozen=True)
class _SampledTabular:
    """A ``TabularDistribution`` run as it is: nodes and actions drawn from its tables."""

    num_agents: int

    def act(self, u, policy: TabularDistribution, nodes):
        return sample_categorical(u, policy.action_probs[jnp.arange(self.num_agents), nodes])

    def next_node(self, u, policy: TabularDistribution, nodes, obs):
        idx = jnp.arange(self.num_agents)
        return sample_categorical(u, policy.transition_probs[idx, nodes, obs])


def _tabular_controller(policy: DeterministicTabularPolicy) -> TabularController:
    agents, nodes, num_obs = policy.transitions.shape
    return TabularController(num_agents=agents, num_nodes=nodes, num_actions=0, num_obs=num_obs)


def _region_controller(policy: DeterministicRegionPolicy) -> RegionController:
    agents, nodes, regions = policy.transitions.shape
    return RegionController(num_agents=agents, num_nodes=nodes, num_regions=regions)


def _network_inputs(policy: NeuralPolicy):
    size = policy.net_params["params"]["Dense_0"]["kernel"].shape[2]
    return size, "network inputs", jnp.float32


def _index(policy):
    return 1, "observation index", jnp.int32


register_policy_type(
    NeuralPolicy, _neural_controller, lambda p: p.action_probs.shape[0], _network_inputs
)
register_policy_type(
    DeterministicTabularPolicy, _tabular_controller, lambda p: p.transitions.shape[0], _index
)
register_policy_type(
    TabularDistribution,
    lambda p: _SampledTabular(p.action_probs.shape[0]),
    lambda p: p.action_probs.shape[0],
    _index,
)
register_policy_type(
    DeterministicRegionPolicy,
    _region_controller,
    lambda p: p.transitions.shape[0],
    lambda p: (1, "scalar observation", jnp.float32),
)


def _policy_agents(policy) -> int:
    if isinstance(policy, EncodedPolicy):
        return _policy_agents(policy.policy)
    return policy_type(policy).agents(policy)


def _per_agent_size(policy):
    """Numbers per agent the policy reads from one observation, what they are, their dtype."""
    if isinstance(policy, EncodedPolicy):
        return policy.raw_features, "raw observation values (the VAE encoder's input)", jnp.float32
    return policy_type(policy).reads(policy)


def _checked_observation(policy, observation, agents: int) -> jax.Array:
    """``observation`` as ``[agents, per-agent size]`` (one number each: ``[agents]``) in the
    dtype the policy reads, or a ``ValueError`` naming both shapes."""
    obs = jnp.asarray(observation)
    size, what, dtype = _per_agent_size(policy)
    if obs.ndim == 0 or obs.shape[0] != agents or obs.size != agents * size:
        hint = ""
        if isinstance(policy, NeuralPolicy) and obs.size == agents * 16 and size != 16:
            hint = (
                "; a policy of an encoded search reads the VAE encoding: pass "
                "portable_policy(algorithm, policy)"
            )
        raise ValueError(
            f"controller_step: observation of shape {tuple(obs.shape)}, but this policy has "
            f"{agents} agents reading {size} {what} each (expected shape ({agents}, {size}) "
            f"or ({agents},) for one number){hint}"
        )
    shape = (
        (agents, size)
        if size > 1 or isinstance(policy, NeuralPolicy | EncodedPolicy)
        else (agents,)
    )
    return obs.reshape(shape).astype(dtype)


def controller_step(policy, node: jax.Array, observation, key: jax.Array):
    """One time step of a learned joint controller: observe, move, act.

    Args:
      policy: a policy pytree (see module docstring), e.g. ``state.best_policy`` of a search.
      node: ``[agents]`` int32, the node every agent is in (``zeros`` at the start).
      observation: every agent's new observation -- ``[agents, *obs_shape]`` float32 for
        continuous (neural, region) controllers (the raw observation for an ``EncodedPolicy``),
        ``[agents]`` int32 indices for tabular ones -- or ``None`` before the first action (the
        nodes are then kept). A shape that does not match the policy raises ``ValueError``.
      key: a PRNG key; stochastic controllers (neural, ``TabularDistribution``) draw from it,
        deterministic ones ignore it.

    Returns:
      ``(action [agents] int32, next_node [agents] int32)``: ``next_node ~ g(. | node, obs)``
      and ``action ~ pi(. | next_node)``.
    """
    inner = policy.policy if isinstance(policy, EncodedPolicy) else policy
    controller = controller_for(inner)  # TypeError for anything but a policy
    node = jnp.asarray(node, jnp.int32)
    agents = node.shape[0] if node.ndim == 1 else -1
    if agents != _policy_agents(policy):
        raise ValueError(
            f"controller_step: node of shape {tuple(node.shape)}, but this policy has "
            f"{_policy_agents(policy)} agents (expected shape ({_policy_agents(policy)},))"
        )
    k_move, k_act = jax.random.split(key)
    u_move = jax.random.uniform(k_move, (agents,))
    u_act = jax.random.uniform(k_act, (agents,))
    if observation is not None:
        obs = _checked_observation(policy, observation, agents)
        if isinstance(policy, EncodedPolicy):
            obs = policy.features(obs)  # [agents, latent], what the search's networks read
        node = controller.next_node(u_move, inner, node, obs)
    return controller.act(u_act, inner, node), node
