"""Shared pieces of finite-state controllers (Moore FSCs, SPEC section 1).

A controller *kind* is a frozen dataclass of static facts (agents, nodes, actions) with two pure
functions over a *policy* pytree, used by the rollout engine once per time step:

* ``act(u, policy, nodes) -> actions``: ``u`` is ``[agents]`` uniform(0, 1) numbers, ``nodes`` the
  current node of every agent ``[agents]``; returns ``[agents]`` int32 actions.
* ``next_node(u, policy, nodes, obs) -> nodes``: the next node of every agent given its
  observation ``obs[agents, *obs_shape]``.

Sampling uses one uniform number per draw (inverse CDF) instead of a key, so the rollout engine
draws all random numbers of a rollout in two block calls. Deterministic controllers ignore ``u``.
All agents start in node 0.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

import jax
import jax.numpy as jnp

from cognet_jax.envs.base import categorical_from_uniform


def sample_categorical(u: jax.Array, probs: jax.Array) -> jax.Array:
    """Inverse-CDF draw: ``u[...]`` uniform in [0, 1), ``probs[..., K]`` -> int32 ``[...]``.

    Returns the smallest k with ``u * sum(probs) < cumsum(probs)[k]``; exact for probabilities
    that do not sum exactly to one, and never picks a zero-probability category.
    """
    return categorical_from_uniform(u, probs)


def uniform_distribution(shape: tuple[int, ...], counts: tuple[int, ...] | None = None):
    """Uniform probabilities of ``shape [agents, ..., K]``; with per-agent ``counts`` the
    categories ``k >= counts[agent]`` get probability 0 (agents with fewer actions).

    One small program per ``(shape, counts)`` (a ``jit`` with both static), not a handful of
    single operations where it runs eagerly; inside a program it is inlined."""
    return _uniform_probs(tuple(shape), None if counts is None else tuple(counts))


@functools.partial(jax.jit, static_argnums=(0, 1))
def _uniform_probs(shape: tuple[int, ...], counts: tuple[int, ...] | None) -> jax.Array:
    k = shape[-1]
    if counts is None:
        return jnp.full(shape, 1.0 / k, jnp.float32)
    mask = jnp.arange(k)[None, :] < jnp.asarray(counts)[:, None]  # [agents, K]
    mask = mask.reshape((shape[0],) + (1,) * (len(shape) - 2) + (k,))
    probs = jnp.broadcast_to(mask, shape).astype(jnp.float32)
    return probs / probs.sum(-1, keepdims=True)


def action_support(env) -> jax.Array:
    """Which actions each agent has, ``[agents, 1, actions]`` bool (broadcasts over nodes):
    agents with fewer actions than ``env.num_actions`` have ``k >= env.action_counts[agent]``
    masked out (e.g. for the uniform part of an entropy injection)."""
    counts = jnp.asarray(env.action_counts)
    return (jnp.arange(env.num_actions)[None, :] < counts[:, None])[:, None, :]


@dataclasses.dataclass(frozen=True)
class GuardedNodes:
    """The honest evaluation's controller: ``controller`` whose ``act`` gives action ``-1``
    in a node outside ``0 .. num_nodes - 1`` (a plug-in's ``next_node`` led there; JAX would
    clamp the gather silently), which ``envs.base.GuardedSteps`` turns into a NaN return;
    in every other node the same actions to the bit."""

    controller: Any

    def __getattr__(self, name):
        if name == "controller" or name.startswith("__"):  # (copy and pickle)
            raise AttributeError(name)
        return getattr(self.controller, name)

    def act(self, u, policy, nodes):
        n = self.controller.num_nodes
        actions = self.controller.act(u, policy, jnp.clip(nodes, 0, n - 1))
        inside = (nodes >= 0) & (nodes < n)
        return jnp.where(inside, actions, -1).astype(actions.dtype)

    def next_node(self, u, policy, nodes, obs):
        return self.controller.next_node(u, policy, nodes, obs)


def guarded_nodes(controller):
    """``controller`` for the honest evaluation: wrapped in ``GuardedNodes`` where it declares
    ``num_nodes`` and runs the rollouts-first layout; the built-in written-out networks
    (``agents_major``, which hold node and action packed in one number) pass as they are:
    their nodes come from an argmax over ``num_nodes`` logits."""
    if getattr(controller, "agents_major", False) or not hasattr(controller, "num_nodes"):
        return controller
    return GuardedNodes(controller)
