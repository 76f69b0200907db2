"""``controller_step``: run a learned controller inside your own JAX simulation.

A learned joint controller is a policy pytree (``NeuralPolicy``, ``EncodedPolicy``,
``DeterministicTabularPolicy``, ``TabularDistribution`` or ``DeterministicRegionPolicy``);
``controller_step`` needs nothing else -- the controller kind and its static facts (agents,
nodes, hidden units) are read from the policy's array shapes, so it is a pure function of arrays
that jits and vmaps. An encoded COGNet-DICE search's networks read a VAE encoding of the raw
observation: ``portable_policy(algorithm, policy)`` bundles the encoder with the policy
(``EncodedPolicy``), and ``controller_step`` then takes the raw observation. Observations whose
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


def controller_for(policy):
    """The controller kind (static facts) matching a policy pytree, from its shapes."""
    if isinstance(policy, NeuralPolicy):
        agents, nodes, actions = policy.action_probs.shape
        dense0 = policy.net_params["params"]["Dense_0"]["kernel"]  # [agents, nodes, in, hidden]
        return NeuralController(
            num_agents=agents,
            num_nodes=nodes,
            num_actions=actions,
            obs_shape=(dense0.shape[2],),
            hidden=dense0.shape[3],
        )
    if isinstance(policy, DeterministicTabularPolicy):
        agents, nodes, num_obs = policy.transitions.shape
        return TabularController(num_agents=agents, num_nodes=nodes, num_actions=0, num_obs=num_obs)
    if isinstance(policy, DeterministicRegionPolicy):
        agents, nodes, regions = policy.transitions.shape
        return RegionController(num_agents=agents, num_nodes=nodes, num_regions=regions)
    if isinstance(policy, TabularDistribution):
        return None  # sampled directly below
    raise TypeError(
        f"controller_step: unsupported policy type {type(policy).__name__} (expected "
        "NeuralPolicy, EncodedPolicy, DeterministicTabularPolicy, TabularDistribution or "
        "DeterministicRegionPolicy)"
    )


def _policy_agents(policy) -> int:
    if isinstance(policy, EncodedPolicy):
        return _policy_agents(policy.policy)
    if isinstance(policy, NeuralPolicy | TabularDistribution):
        return policy.action_probs.shape[0]
    return policy.transitions.shape[0]


def _per_agent_size(policy) -> tuple[int, str]:
    """Numbers per agent the policy reads from one observation, and what they are."""
    if isinstance(policy, EncodedPolicy):
        return policy.raw_features, "raw observation values (the VAE encoder's input)"
    if isinstance(policy, NeuralPolicy):
        size = policy.net_params["params"]["Dense_0"]["kernel"].shape[2]
        return size, "network inputs"
    if isinstance(policy, DeterministicRegionPolicy):
        return 1, "scalar observation"
    return 1, "observation index"


def _checked_observation(policy, observation, agents: int) -> jax.Array:
    """``observation`` as ``[agents, per-agent size]`` (scalar kinds: ``[agents]``), or a
    ``ValueError`` naming both shapes."""
    obs = jnp.asarray(observation)
    size, what = _per_agent_size(policy)
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
    if isinstance(policy, NeuralPolicy | EncodedPolicy):
        return obs.reshape(agents, size).astype(jnp.float32)
    return obs.reshape(agents)


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
    if isinstance(policy, TabularDistribution):
        idx = jnp.arange(agents)
        if observation is not None:
            obs = _checked_observation(policy, observation, agents).astype(jnp.int32)
            probs = policy.transition_probs[idx, node, obs]
            node = sample_categorical(u_move, probs)
        return sample_categorical(u_act, policy.action_probs[idx, node]), node
    if observation is not None:
        obs = _checked_observation(policy, observation, agents)
        if isinstance(policy, EncodedPolicy):
            obs = policy.features(obs)  # [agents, latent], what the search's networks read
        node = controller.next_node(u_move, inner, node, obs)
    return controller.act(u_act, inner, node), node
