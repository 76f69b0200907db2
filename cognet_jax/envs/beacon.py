"""Beacon search on a plane: three agents, noisy 2-D offsets to a static beacon, as pure JAX
step functions.

The arena is ``[0, size]^2``. A beacon sits at a uniform point; every agent starts at a uniform
point of its own. Actions (all agents): ``0`` stay, ``1`` x+1, ``2`` x-1, ``3`` y+1, ``4`` y-1
(``envs.base.MOVES5``), plus Gaussian motion noise ``N(0, motion_noise)`` per coordinate,
clipped to the arena. Reward, summed over agents, on the pre-step state: ``+1`` for each agent
within ``radius`` of the beacon. After moving, agent i observes the 2-D offset ``beacon - p_i
+ N(0, obs_noise)`` per coordinate: ``obs [agents, 2]``.

Defaults: 3 agents, h 30, gamma 0.95, ``obs_noise`` 0.5. The agents need no coordination;
the problem tests vector observations and a third agent. Hand-written controller
(``hand_controller``): stay when the offset's larger coordinate is within ``margin``, else
step along it.
"""

from __future__ import annotations

import dataclasses
import typing

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from cognet_jax.config import require, require_discount, require_nonnegative, require_positive
from cognet_jax.controllers.rules import RuleController, rule_policy
from cognet_jax.envs.base import (
    MOVE5_NAMES,
    MOVES5,
    ContinuousObservations,
    scaled_normal,
    sum_last,
)
from cognet_jax.registry import register_fields_env


@struct.dataclass
class BeaconParams:
    obs_noise: jax.Array | float = 0.5
    motion_noise: jax.Array | float = 0.0
    radius: jax.Array | float = 1.0
    discount: jax.Array | float = 0.95


@struct.dataclass
class BeaconState:
    agents: jax.Array  # [agents, 2] float32
    beacon: jax.Array  # [2] float32


@dataclasses.dataclass(frozen=True)
class Beacon(ContinuousObservations):
    horizon: int = 30
    num_agents: int = 3
    size: float = 10.0
    num_actions: typing.ClassVar[int] = 5
    action_names: typing.ClassVar[tuple[str, ...]] = MOVE5_NAMES
    obs_shape: typing.ClassVar[tuple[int, ...]] = (2,)
    obs_range: typing.ClassVar[None] = None

    @property
    def reset_noise(self) -> int:
        return 2 * self.num_agents + 2

    @property
    def step_noise(self) -> int:
        return 4 * self.num_agents  # motion, then observation noise, 2 coordinates each

    def default_params(self) -> BeaconParams:
        return BeaconParams()

    def reset(self, u, params: BeaconParams) -> BeaconState:
        points = u.reshape(self.num_agents + 1, 2) * self.size
        return BeaconState(agents=points[:-1], beacon=points[-1])

    def step(self, u, state: BeaconState, actions, params: BeaconParams):
        """``u [4 agents]``. Returns ``(state', obs [agents, 2], reward [])``."""
        n = self.num_agents
        dist = jnp.sqrt(jnp.sum((state.agents - state.beacon) ** 2, axis=-1))
        reward = sum_last((dist <= params.radius).astype(jnp.float32))
        noise = scaled_normal(params.motion_noise, u[: 2 * n]).reshape(n, 2)
        moved = state.agents + jnp.asarray(MOVES5)[actions] + noise
        agents = jnp.clip(moved, 0.0, self.size)
        obs_noise = scaled_normal(params.obs_noise, u[2 * n :]).reshape(n, 2)
        obs = state.beacon - agents + obs_noise
        return BeaconState(agents, state.beacon), obs, reward


def upper_bound(env: Beacon, params: BeaconParams, samples: int = 200_000, seed: int = 0):
    """An upper bound on any controller's value without motion noise (plain numpy, Monte Carlo
    over starts; returns ``(mean, standard error)``): an agent moves at most 1 per step, so it
    is inside the radius no earlier than step ``ceil(distance - radius)``, and at best at every
    step from then on."""
    rng = np.random.default_rng(seed)
    d = np.linalg.norm(
        rng.uniform(0, env.size, (samples, env.num_agents, 2))
        - rng.uniform(0, env.size, (samples, 1, 2)),
        axis=-1,
    )
    first = np.ceil(np.maximum(d - float(params.radius), 0.0))  # [samples, agents]
    gamma = float(params.discount)
    steps = np.arange(env.horizon)
    per_step = gamma**steps  # [h]
    tail = np.cumsum(per_step[::-1])[::-1]  # sum_{t >= k} gamma^t, k < h
    value = np.where(first < env.horizon, tail[np.minimum(first, env.horizon - 1).astype(int)], 0)
    total = value.sum(-1)
    return float(total.mean()), float(total.std() / np.sqrt(samples))


# ---------------------------------------------------------------------------------------------
# the hand-written controller
# ---------------------------------------------------------------------------------------------
#: (wide enough that the tuned point is inside it with and without observation noise)
HAND_GRID = {"margin": (0.0, 0.1, 0.25, 0.5, 0.75, 1.0, 1.5)}


def move_toward(offset: jax.Array, margin) -> jax.Array:
    """The ``MOVES5`` action toward a 2-D ``offset [..., 2]``: stay when both coordinates are
    within ``margin``, else a step along the larger one."""
    dx, dy = offset[..., 0], offset[..., 1]
    along_x = jnp.where(dx > 0, 1, 2)
    along_y = jnp.where(dy > 0, 3, 4)
    step = jnp.where(jnp.abs(dx) >= jnp.abs(dy), along_x, along_y)
    return jnp.where(jnp.maximum(jnp.abs(dx), jnp.abs(dy)) <= margin, 0, step)


def hand_controller(env: Beacon, margin: float):
    """``(controller, policy)``: five nodes, node k acts ``MOVES5[k]`` (node 0 stays: the blind
    first step); the next node is ``move_toward(obs, margin)``."""
    controller = RuleController(
        env.num_agents, 5, lambda theta, nodes, obs: move_toward(obs, theta["margin"])
    )
    return controller, rule_policy(env.num_agents, range(5), {"margin": margin})


# ---------------------------------------------------------------------------------------------
# configuration
# ---------------------------------------------------------------------------------------------
@dataclasses.dataclass
class BeaconSection:
    """``[env]`` of the beacon search (module docstring)."""

    name: str = "beacon"
    horizon: int = 30
    num_agents: int = 3
    discount: float = 0.95
    obs_noise: float = 0.5
    motion_noise: float = 0.0
    radius: float = 1.0

    def check(self, config) -> None:
        require_positive(self, "env", "horizon", "num_agents")
        require(self.num_agents <= 16, "env.num_agents", f"at most 16, got {self.num_agents}")
        require_discount(self.discount, "env.discount")
        require_nonnegative(self, "env", "obs_noise", "motion_noise", "radius")


#: ``build_from_section(section, config) -> (env, params)``: the registered builder
build_from_section = register_fields_env("beacon", BeaconSection, Beacon, BeaconParams).build
