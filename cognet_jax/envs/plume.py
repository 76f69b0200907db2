"""Plume source search on a grid: two agents read a small noisy image patch of a concentration
field, as pure JAX step functions.

A ``size x size`` grid of cells holds a concentration ``exp(-|c - s|^2 / (2 spread^2))`` around
a source cell ``s`` drawn uniformly at reset (the field is unknown to the agents). Each agent
starts on a uniform cell. Actions: ``0`` stay, ``1`` x+1, ``2`` x-1, ``3`` y+1, ``4`` y-1
(``envs.base.MOVES5``), clipped to the grid. Reward on the pre-step state: ``+1`` per agent on
the source cell. After moving, agent i observes the ``3 x 3`` patch of concentrations around
its cell (rows x-1..x+1, columns y-1..y+1, flattened row-major; cells outside the grid read 0)
plus ``N(0, obs_noise)`` per pixel: ``obs [agents, 9]``.

Defaults: 10 x 10 grid, spread 2, h 20, gamma 1, ``obs_noise`` 0.05. Hand-written controller
(``hand_controller``): step to the brightest of the four neighbours when it is brighter than
the centre by more than ``margin``, else stay.
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

#: ``(dx, dy)`` of the patch's pixels, row-major
PATCH_OFFSETS = np.array([(dx, dy) for dx in (-1, 0, 1) for dy in (-1, 0, 1)], np.int32)
#: the patch pixel of each move's target cell (stay: the centre)
MOVE_PIXEL = (4, 7, 1, 5, 3)


@struct.dataclass
class PlumeParams:
    obs_noise: jax.Array | float = 0.05
    spread: jax.Array | float = 2.0
    discount: jax.Array | float = 1.0


@struct.dataclass
class PlumeState:
    agents: jax.Array  # [agents, 2] int32 cells
    source: jax.Array  # [2] int32 cell


@dataclasses.dataclass(frozen=True)
class Plume(ContinuousObservations):
    horizon: int = 20
    size: int = 10
    num_agents: typing.ClassVar[int] = 2
    num_actions: typing.ClassVar[int] = 5
    action_names: typing.ClassVar[tuple[str, ...]] = MOVE5_NAMES
    obs_shape: typing.ClassVar[tuple[int, ...]] = (9,)
    obs_range: typing.ClassVar[None] = None
    reset_noise: typing.ClassVar[int] = 6
    step_noise: typing.ClassVar[int] = 18  # 9 pixels per agent

    def default_params(self) -> PlumeParams:
        return PlumeParams()

    def _cells(self, u) -> jax.Array:
        return jnp.minimum((u * self.size).astype(jnp.int32), self.size - 1)

    def reset(self, u, params: PlumeParams) -> PlumeState:
        cells = self._cells(u).reshape(3, 2)
        return PlumeState(agents=cells[:2], source=cells[2])

    def patches(self, agents, source, params: PlumeParams) -> jax.Array:
        """Clean patches ``[agents, 9]`` of the agents at ``agents [agents, 2]``."""
        cells = agents[:, None, :] + jnp.asarray(PATCH_OFFSETS)  # [agents, 9, 2]
        inside = jnp.all((cells >= 0) & (cells < self.size), axis=-1)
        d2 = jnp.sum((cells - source).astype(jnp.float32) ** 2, axis=-1)
        return jnp.where(inside, jnp.exp(-d2 / (2.0 * params.spread**2)), 0.0)

    def step(self, u, state: PlumeState, actions, params: PlumeParams):
        """``u [18]``. Returns ``(state', obs [2, 9], reward [])``."""
        on_source = jnp.all(state.agents == state.source, axis=-1)
        reward = sum_last(on_source.astype(jnp.float32))
        moves = jnp.asarray(MOVES5, jnp.int32)[actions]
        agents = jnp.clip(state.agents + moves, 0, self.size - 1)
        clean = self.patches(agents, state.source, params)
        obs = clean + scaled_normal(params.obs_noise, u).reshape(clean.shape)
        return PlumeState(agents, state.source), obs, reward


def upper_bound(env: Plume) -> float:
    """Exact upper bound on any controller's value with ``gamma = 1`` (plain numpy): an agent
    moves one cell per step, so from Manhattan distance ``d`` it is on the source at most at
    steps ``d .. h - 1``; averaged over every start and source cell, summed over agents."""
    n = env.size
    cells = np.stack(np.meshgrid(np.arange(n), np.arange(n), indexing="ij"), -1).reshape(-1, 2)
    d = np.abs(cells[:, None, :] - cells[None, :, :]).sum(-1)  # [start, source]
    return float(env.num_agents * np.maximum(env.horizon - d, 0).mean())


# ---------------------------------------------------------------------------------------------
# the hand-written controller
# ---------------------------------------------------------------------------------------------
HAND_GRID = {"margin": (-0.02, 0.0, 0.02, 0.05, 0.1)}


def hand_controller(env: Plume, margin: float):
    """``(controller, policy)``: five nodes, node k acts ``MOVES5[k]`` (node 0 stays: the blind
    first step); the next node is the move to the brightest of the four neighbour pixels when
    it beats the centre pixel by more than ``margin``, else stay."""

    def rule(theta, nodes, obs):
        neighbours = obs[:, jnp.asarray(MOVE_PIXEL[1:])]  # [agents, 4]
        best = jnp.argmax(neighbours, axis=-1)
        gain = jnp.max(neighbours, axis=-1) - obs[:, 4]
        return jnp.where(gain > theta["margin"], best + 1, 0)

    return RuleController(2, 5, rule), rule_policy(2, range(5), {"margin": margin})


# ---------------------------------------------------------------------------------------------
# configuration
# ---------------------------------------------------------------------------------------------
@dataclasses.dataclass
class PlumeSection:
    """``[env]`` of the plume source search (module docstring)."""

    name: str = "plume"
    horizon: int = 20
    size: int = 10
    discount: float = 1.0
    obs_noise: float = 0.05
    spread: float = 2.0

    def check(self, config) -> None:
        require_positive(self, "env", "horizon", "size")
        require(2 <= self.size <= 1000, "env.size", f"must be in 2 .. 1000, got {self.size}")
        require_discount(self.discount, "env.discount")
        require_nonnegative(self, "env", "obs_noise")
        require(self.spread > 0, "env.spread", f"must be > 0, got {self.spread}")


#: ``build_from_section(section, config) -> (env, params)``: the registered builder
build_from_section = register_fields_env("plume", PlumeSection, Plume, PlumeParams).build
