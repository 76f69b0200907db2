"""Bearing-only chase of a moving target: two agents, noisy bearings, as pure JAX step
functions.

The arena is ``[0, size]^2``. A target starts at a uniform point with a uniform heading and
moves ``target_speed`` per step, its heading turning by ``N(0, heading_noise)`` each step and
reflecting off the walls. Each agent starts at a uniform point. Actions: ``0`` stay, ``1`` x+1,
``2`` x-1, ``3`` y+1, ``4`` y-1 (``envs.base.MOVES5``), clipped to the arena. Reward on the
pre-step state: ``+1`` per agent within ``radius`` of the target, and ``pincer_bonus`` more
when both are. After moving, agent i observes only the bearing to the target,
``atan2(dy, dx) + N(0, bearing_noise)`` wrapped to ``(-pi, pi]``: a scalar, no range.

Defaults: h 50, gamma 0.9, ``bearing_noise`` 0.3 rad, target speed 0.5. Hand-written
controller (``hand_controller``): step along x when ``|cos(bearing)| >= split``, else along y,
toward the target.
"""

from __future__ import annotations

import dataclasses
import math
import typing

import jax
import jax.numpy as jnp
from flax import struct

from cognet_jax.config import require, require_discount, require_nonnegative, require_positive
from cognet_jax.controllers.rules import RuleController, rule_policy
from cognet_jax.envs.base import (
    MOVE5_NAMES,
    MOVES5,
    ContinuousObservations,
    scaled_normal,
)
from cognet_jax.registry import register_fields_env


@struct.dataclass
class ChaseParams:
    bearing_noise: jax.Array | float = 0.3
    heading_noise: jax.Array | float = 0.3
    target_speed: jax.Array | float = 0.5
    radius: jax.Array | float = 1.5
    pincer_bonus: jax.Array | float = 1.0
    discount: jax.Array | float = 0.9


@struct.dataclass
class ChaseState:
    agents: jax.Array  # [2, 2] float32
    target: jax.Array  # [2] float32
    heading: jax.Array  # [] float32, radians


def reflect(position: jax.Array, velocity: jax.Array, size: float):
    """``(position, velocity)`` after a move bounced off the walls of ``[0, size]^2``."""
    low, high = position < 0.0, position > size
    position = jnp.where(low, -position, jnp.where(high, 2.0 * size - position, position))
    velocity = jnp.where(low | high, -velocity, velocity)
    return jnp.clip(position, 0.0, size), velocity


def wrap_angle(angle: jax.Array) -> jax.Array:
    """``angle`` wrapped to ``(-pi, pi]``."""
    return math.pi - jnp.mod(math.pi - angle, 2.0 * math.pi)


@dataclasses.dataclass(frozen=True)
class BearingChase(ContinuousObservations):
    horizon: int = 50
    size: float = 10.0
    num_agents: typing.ClassVar[int] = 2
    num_actions: typing.ClassVar[int] = 5
    action_names: typing.ClassVar[tuple[str, ...]] = MOVE5_NAMES
    obs_shape: typing.ClassVar[tuple[int, ...]] = ()
    obs_range: typing.ClassVar[tuple[float, float]] = (-math.pi, math.pi)
    reset_noise: typing.ClassVar[int] = 7  # agents (4), target (2), heading (1)
    step_noise: typing.ClassVar[int] = 3  # heading turn, two bearings

    def default_params(self) -> ChaseParams:
        return ChaseParams()

    def reset(self, u, params: ChaseParams) -> ChaseState:
        return ChaseState(
            agents=u[:4].reshape(2, 2) * self.size,
            target=u[4:6] * self.size,
            heading=(u[6] * 2.0 - 1.0) * math.pi,
        )

    def step(self, u, state: ChaseState, actions, params: ChaseParams):
        """``u [3]``. Returns ``(state', obs [2] bearings, reward [])``."""
        dist = jnp.sqrt(jnp.sum((state.agents - state.target) ** 2, axis=-1))
        near = dist <= params.radius
        reward = near[0].astype(jnp.float32) + near[1] + params.pincer_bonus * (near[0] & near[1])
        agents = jnp.clip(state.agents + jnp.asarray(MOVES5)[actions], 0.0, self.size)
        heading = state.heading + scaled_normal(params.heading_noise, u[:1])[0]
        velocity = params.target_speed * jnp.stack([jnp.cos(heading), jnp.sin(heading)])
        target, velocity = reflect(state.target + velocity, velocity, self.size)
        heading = jnp.arctan2(velocity[1], velocity[0])
        offset = target - agents
        bearing = jnp.arctan2(offset[:, 1], offset[:, 0])
        obs = wrap_angle(bearing + scaled_normal(params.bearing_noise, u[1:]))
        return ChaseState(agents, target, heading), obs.astype(jnp.float32), reward


# ---------------------------------------------------------------------------------------------
# the hand-written controller
# ---------------------------------------------------------------------------------------------
HAND_GRID = {"split": (0.5, 0.6, 0.7071, 0.8, 0.9)}


def hand_controller(env: BearingChase, split: float):
    """``(controller, policy)``: five nodes, node k acts ``MOVES5[k]`` (node 0 stays: the blind
    first step); the next node steps toward the bearing: along x (``1`` / ``2`` by the sign of
    its cosine) when ``|cos| >= split``, else along y (``3`` / ``4``)."""

    def rule(theta, nodes, obs):
        c, s = jnp.cos(obs), jnp.sin(obs)
        along_x = jnp.where(c > 0, 1, 2)
        along_y = jnp.where(s > 0, 3, 4)
        return jnp.where(jnp.abs(c) >= theta["split"], along_x, along_y)

    return RuleController(2, 5, rule), rule_policy(2, range(5), {"split": split})


# ---------------------------------------------------------------------------------------------
# configuration
# ---------------------------------------------------------------------------------------------
@dataclasses.dataclass
class BearingChaseSection:
    """``[env]`` of the bearing-only chase (module docstring)."""

    name: str = "bearing-chase"
    horizon: int = 50
    discount: float = 0.9
    bearing_noise: float = 0.3
    heading_noise: float = 0.3
    target_speed: float = 0.5
    radius: float = 1.5
    pincer_bonus: float = 1.0

    def check(self, config) -> None:
        require_positive(self, "env", "horizon")
        require_discount(self.discount, "env.discount")
        require_nonnegative(self, "env", "bearing_noise", "heading_noise", "radius")
        require(
            0.0 <= self.target_speed <= 5.0,
            "env.target_speed",
            f"must be in [0, 5] (half the arena per step), got {self.target_speed}",
        )


#: ``build_from_section(section, config) -> (env, params)``: the registered builder
build_from_section = register_fields_env(
    "bearing-chase", BearingChaseSection, BearingChase, ChaseParams
).build
