"""Cooperative box pushing with noisy range sensors: a continuous-observation cousin of the
classic Dec-POMDP benchmark (Seuken and Zilberstein 2007), as pure JAX step functions.

A corridor ``[0, length]`` holds a heavy box at a uniform point and two agents at uniform points
of their own. Actions: ``0`` move left, ``1`` move right, ``2`` push (speed 1, Gaussian motion
noise ``N(0, motion_noise)``, clipped). A push counts when the agent is within ``reach`` of the
box. Joint reward on the pre-step state: both agents push within reach in the same step ->
``joint_reward`` (+20) and the box is delivered: it respawns at a uniform point (after the
moves); a push within reach alone -> ``lone_reward`` (-1: the box does not move); a push out
of reach -> ``miss_reward`` (-5) per agent; each move ``move_reward`` (-0.5). After moving,
agent i reads its range sensor: ``box - p_i + N(0, obs_noise)``, a signed scalar.

Defaults: h 100, gamma 0.9, ``obs_noise`` 1.0. Only a joint push pays, so the agents must
arrive and push together. Hand-written controller (``hand_controller``): push when the reading
is within ``margin``, else move toward it.
"""

from __future__ import annotations

import dataclasses
import typing

import jax
import jax.numpy as jnp
from flax import struct

from cognet_jax.config import require_discount, require_nonnegative, require_positive
from cognet_jax.controllers.rules import RuleController, rule_policy
from cognet_jax.envs.base import (
    ContinuousObservations,
    scaled_normal,
    sum_last,
)
from cognet_jax.registry import register_fields_env

LEFT, RIGHT, PUSH = 0, 1, 2
ACTION_NAMES = ("left", "right", "push")


@struct.dataclass
class BoxPushParams:
    obs_noise: jax.Array | float = 1.0
    motion_noise: jax.Array | float = 0.0
    reach: jax.Array | float = 1.0
    joint_reward: jax.Array | float = 20.0
    lone_reward: jax.Array | float = -1.0
    miss_reward: jax.Array | float = -5.0
    move_reward: jax.Array | float = -0.5
    discount: jax.Array | float = 0.9


@struct.dataclass
class BoxPushState:
    agents: jax.Array  # [2] float32
    box: jax.Array  # [] float32


@dataclasses.dataclass(frozen=True)
class BoxPush(ContinuousObservations):
    horizon: int = 100
    length: float = 10.0
    num_agents: typing.ClassVar[int] = 2
    num_actions: typing.ClassVar[int] = 3
    action_names: typing.ClassVar[tuple[str, ...]] = ACTION_NAMES
    obs_shape: typing.ClassVar[tuple[int, ...]] = ()
    reset_noise: typing.ClassVar[int] = 3
    step_noise: typing.ClassVar[int] = 5  # motion (2), the box's respawn, range noise (2)

    @property
    def obs_range(self) -> tuple[float, float]:
        return (-self.length, self.length)

    def default_params(self) -> BoxPushParams:
        return BoxPushParams()

    def reset(self, u, params: BoxPushParams) -> BoxPushState:
        return BoxPushState(agents=u[:2] * self.length, box=u[2] * self.length)

    def step(self, u, state: BoxPushState, actions, params: BoxPushParams):
        """``u [5]``. Returns ``(state', obs [2], reward [])``."""
        pushing = actions == PUSH
        in_reach = jnp.abs(state.agents - state.box) <= params.reach
        delivered = jnp.all(pushing & in_reach)
        each = jnp.where(
            pushing,
            jnp.where(in_reach, params.lone_reward, params.miss_reward),
            params.move_reward,
        )
        reward = jnp.where(delivered, params.joint_reward, sum_last(each))
        move = jnp.where(actions == LEFT, -1.0, jnp.where(actions == RIGHT, 1.0, 0.0))
        moved = state.agents + move + scaled_normal(params.motion_noise, u[:2])
        agents = jnp.clip(moved, 0.0, self.length)
        box = jnp.where(delivered, u[2] * self.length, state.box)
        obs = box - agents + scaled_normal(params.obs_noise, u[3:])
        return BoxPushState(agents, box), obs.astype(jnp.float32), reward


# ---------------------------------------------------------------------------------------------
# the hand-written controller
# ---------------------------------------------------------------------------------------------
HAND_GRID = {"margin": (0.5, 0.75, 1.0, 1.5, 2.0)}


def hand_controller(env: BoxPush, margin: float):
    """``(controller, policy)``: three nodes, node k acts k (node 0 moves left: the blind first
    step); the next node pushes when ``|reading| <= margin``, else moves toward the box."""

    def rule(theta, nodes, obs):
        toward = jnp.where(obs > 0, RIGHT, LEFT)
        return jnp.where(jnp.abs(obs) <= theta["margin"], PUSH, toward)

    return RuleController(2, 3, rule), rule_policy(2, range(3), {"margin": margin})


# ---------------------------------------------------------------------------------------------
# configuration
# ---------------------------------------------------------------------------------------------
@dataclasses.dataclass
class BoxPushSection:
    """``[env]`` of cooperative box pushing with range sensors (module docstring)."""

    name: str = "box-push"
    horizon: int = 100
    discount: float = 0.9
    obs_noise: float = 1.0
    motion_noise: float = 0.0
    reach: float = 1.0
    joint_reward: float = 20.0
    lone_reward: float = -1.0
    miss_reward: float = -5.0
    move_reward: float = -0.5

    def check(self, config) -> None:
        require_positive(self, "env", "horizon")
        require_discount(self.discount, "env.discount")
        require_nonnegative(self, "env", "obs_noise", "motion_noise", "reach")


#: ``build_from_section(section, config) -> (env, params)``: the registered builder
build_from_section = register_fields_env("box-push", BoxPushSection, BoxPush, BoxPushParams).build
