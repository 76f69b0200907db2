"""The README's user simulator (experiments/readme_seek.py) with its reading in other units, to
load with ``--import``: ``obs = (goal - position + noise) x scale + offset``. The same problem
as the README's for every scale and offset -- a hand-written controller's thresholds move with
the units and its value stays -- so a search that reads raw numbers should reach the same value
on every one. ``python experiments/offcentre.py`` sweeps the defaults on it."""

import dataclasses

import jax.numpy as jnp
from flax import struct

import cognet_jax
from cognet_jax.envs.base import scaled_normal


@struct.dataclass
class SeekUnitsParams:
    noise: float = 0.3
    scale: float = 1.0
    offset: float = 0.0
    discount: float = 0.95


@dataclasses.dataclass(frozen=True)
class SeekUnits:
    """Agents on [0, 10] move left / stay / right; each reads ``(goal - position + noise) x
    scale + offset``; reward +1 per agent within 1 of the goal, else -0.1."""

    horizon: int = 20
    num_agents: int = 2
    num_actions: int = 3
    action_counts: tuple = (3, 3)
    obs_shape: tuple = ()
    num_obs: None = None
    obs_range: tuple = (-10.0, 10.0)
    reset_noise: int = 3  # two positions and the goal
    step_noise: int = 2  # one observation noise per agent

    def reset(self, u, params):
        return 10.0 * u  # [x_0, x_1, goal]

    def step(self, u, state, actions, params):
        pos = jnp.clip(state[:2] + actions - 1.0, 0.0, 10.0)
        reward = jnp.sum(jnp.where(jnp.abs(pos - state[2]) < 1.0, 1.0, -0.1))
        distance = state[2] - pos + scaled_normal(params.noise, u)
        return state.at[:2].set(pos), distance * params.scale + params.offset, reward


@dataclasses.dataclass
class SeekUnitsSection:  # the [env] config section
    name: str = "seek-units"
    noise: float = 0.3
    scale: float = 1.0
    offset: float = 0.0


def make(section, config):
    ends = sorted((-10.0 * section.scale + section.offset, 10.0 * section.scale + section.offset))
    params = SeekUnitsParams(noise=section.noise, scale=section.scale, offset=section.offset)
    return SeekUnits(obs_range=tuple(ends)), params


cognet_jax.register_env("seek-units", SeekUnitsSection, make)
