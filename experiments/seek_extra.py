"""The README's user simulator (experiments/readme_seek.py) with more in its observation, to
load with ``--import``: each agent reads the vector ``[goal - position + noise, position,
z_1 .. z_k]``: the signed distance as before, its own position on [0, 10] (``position``: a GPS
reading a user would pass along; off centre, and no use beside the distance) and ``extras``
features of pure noise (``z ~ N(0, 1)``: sensors that tell nothing). The same problem as the
README's: the hand-written controller reads the first feature only and keeps its value, so a
search that copes with features it does not need should reach it. ``python
experiments/extra_features.py`` sweeps the defaults on it."""

import dataclasses

import jax.numpy as jnp
from flax import struct

import cognet_jax
from cognet_jax.envs.base import scaled_normal


@struct.dataclass
class SeekExtraParams:
    noise: float = 0.3
    discount: float = 0.95


@dataclasses.dataclass(frozen=True)
class SeekExtra:
    """Agents on [0, 10] move left / stay / right; reward +1 per agent within 1 of the goal,
    else -0.1; observation ``[agents, 1 + position + extras]`` (module docstring)."""

    horizon: int = 20
    position: bool = True
    extras: int = 0
    num_agents: int = 2
    num_actions: int = 3
    action_counts: tuple = (3, 3)
    num_obs: None = None
    obs_range: None = None
    reset_noise: int = 3  # two positions and the goal

    @property
    def features(self) -> int:
        return 1 + int(self.position) + self.extras

    @property
    def obs_shape(self) -> tuple:
        return (self.features,)

    @property
    def step_noise(self) -> int:  # the distance's noise and the extras, per agent
        return 2 * (1 + self.extras)

    def reset(self, u, params):
        return 10.0 * u  # [x_0, x_1, goal]

    def step(self, u, state, actions, params):
        pos = jnp.clip(state[:2] + actions - 1.0, 0.0, 10.0)
        reward = jnp.sum(jnp.where(jnp.abs(pos - state[2]) < 1.0, 1.0, -0.1))
        distance = state[2] - pos + scaled_normal(params.noise, u[:2])
        columns = [distance[:, None]]
        if self.position:
            columns.append(pos[:, None])
        if self.extras:
            columns.append(scaled_normal(1.0, u[2:]).reshape(2, self.extras))
        return state.at[:2].set(pos), jnp.concatenate(columns, axis=-1), reward


@dataclasses.dataclass
class SeekExtraSection:  # the [env] config section
    name: str = "seek-extra"
    noise: float = 0.3
    position: bool = True
    extras: int = 0


def make(section, config):
    env = SeekExtra(position=section.position, extras=section.extras)
    return env, SeekExtraParams(noise=section.noise)


cognet_jax.register_env("seek-extra", SeekExtraSection, make)
