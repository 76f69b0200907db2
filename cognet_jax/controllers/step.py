"""``controller_step``: run a learned controller inside your own JAX simulation.

A learned joint controller is a policy pytree (``NeuralPolicy``, ``DeterministicTabularPolicy``,
``TabularDistribution`` or ``DeterministicRegionPolicy``); ``controller_step`` needs nothing
else -- the controller kind and its static facts (agents, nodes, hidden units) are read from
the policy's array shapes, so it is a pure function of arrays that jits and vmaps.

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
        "NeuralPolicy, DeterministicTabularPolicy, TabularDistribution or "
        "DeterministicRegionPolicy)"
    )


def controller_step(policy, node: jax.Array, observation, key: jax.Array):
    """One time step of a learned joint controller: observe, move, act.

    Args:
      policy: a policy pytree (see module docstring), e.g. ``state.best_policy`` of a search.
      node: ``[agents]`` int32, the node every agent is in (``zeros`` at the start).
      observation: every agent's new observation -- ``[agents, *obs_shape]`` float32 for
        continuous (neural, region) controllers, ``[agents]`` int32 indices for tabular ones --
        or ``None`` before the first action (the nodes are then kept).
      key: a PRNG key; stochastic controllers (neural, ``TabularDistribution``) draw from it,
        deterministic ones ignore it.

    Returns:
      ``(action [agents] int32, next_node [agents] int32)``: ``next_node ~ g(. | node, obs)``
      and ``action ~ pi(. | next_node)``.
    """
    node = jnp.asarray(node, jnp.int32)
    agents = node.shape[0]
    k_move, k_act = jax.random.split(key)
    u_move = jax.random.uniform(k_move, (agents,))
    u_act = jax.random.uniform(k_act, (agents,))
    if isinstance(policy, TabularDistribution):
        from cognet_jax.controllers.base import sample_categorical

        idx = jnp.arange(agents)
        if observation is not None:
            probs = policy.transition_probs[idx, node, jnp.asarray(observation, jnp.int32)]
            node = sample_categorical(u_move, probs)
        return sample_categorical(u_act, policy.action_probs[idx, node]), node
    controller = controller_for(policy)
    if observation is not None:
        obs = jnp.asarray(observation)
        if isinstance(policy, NeuralPolicy):
            obs = obs.reshape(agents, -1).astype(jnp.float32)
        node = controller.next_node(u_move, policy, node, obs)
    return controller.act(u_act, policy, node), node
