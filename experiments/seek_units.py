"""The README's user simulator (experiments/readme_seek.py) with its observation as a user might
bring it, to load with ``--import``: the reading in other units, ``(goal - position + noise) x
scale + offset``, and, with ``position`` or ``extras``, the vector ``[reading, position, z_1 ..
z_k]`` of the reading, the agent's own position on [0, 10] (a GPS reading a user would pass
along; off centre, and no use beside the distance) and ``extras`` features of pure noise
(``z ~ N(0, 1)``: sensors that tell nothing). The same problem as the README's every way -- a
hand-written controller's thresholds move with the units, it reads the distance only, and its
value stays -- so a search that copes with raw numbers and features it does not need should
reach the same value on every one. ``python experiments/offcentre.py`` sweeps the defaults on
it."""

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
    scale + offset``, beside its position and ``extras`` noise features when asked (module
    docstring); reward +1 per agent within 1 of the goal, else -0.1."""

    horizon: int = 20
    position: bool = False
    extras: int = 0
    num_agents: int = 2
    num_actions: int = 3
    action_counts: tuple = (3, 3)
    num_obs: None = None
    obs_range: tuple = (-10.0, 10.0)
    reset_noise: int = 3  # two positions and the goal

    @property
    def obs_shape(self) -> tuple:  # a scalar reading, or the vector of the module docstring
        features = 1 + int(self.position) + self.extras
        return (features,) if features > 1 else ()

    @property
    def step_noise(self) -> int:  # the reading's noise and the extras, per agent
        return 2 * (1 + self.extras)

    def reset(self, u, params):
        return 10.0 * u  # [x_0, x_1, goal]

    def step(self, u, state, actions, params):
        pos = jnp.clip(state[:2] + actions - 1.0, 0.0, 10.0)
        reward = jnp.sum(jnp.where(jnp.abs(pos - state[2]) < 1.0, 1.0, -0.1))
        distance = state[2] - pos + scaled_normal(params.noise, u[:2])
        reading = distance * params.scale + params.offset
        if self.obs_shape == ():
            return state.at[:2].set(pos), reading, reward
        columns = [reading[:, None]]
        if self.position:
            columns.append(pos[:, None])
        if self.extras:
            columns.append(scaled_normal(1.0, u[2:]).reshape(2, self.extras))
        return state.at[:2].set(pos), jnp.concatenate(columns, axis=-1), reward


@dataclasses.dataclass
class SeekUnitsSection:  # the [env] config section
    name: str = "seek-units"
    noise: float = 0.3
    scale: float = 1.0
    offset: float = 0.0
    position: bool = False
    extras: int = 0


def make(section, config):
    ends = sorted((-10.0 * section.scale + section.offset, 10.0 * section.scale + section.offset))
    params = SeekUnitsParams(noise=section.noise, scale=section.scale, offset=section.offset)
    if section.extras < 0:
        raise ValueError(f"env.extras must be >= 0, got {section.extras}")
    env = SeekUnits(position=section.position, extras=section.extras, obs_range=tuple(ends))
    return env, params


cognet_jax.register_env("seek-units", SeekUnitsSection, make)
