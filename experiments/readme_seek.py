"""The user simulator of the README ("Your own simulator": its classes and registration), to
load with ``--import``: two agents walk a line towards a hidden goal, each seeing its noisy
signed distance to it. It is not part of the package; experiments/suite.py judges the defaults
on it as on a simulator the project never tuned for, beside the controller a practitioner would
write (``hand_controller``, thresholds from ``HAND_GRID``)."""

import dataclasses

import jax.numpy as jnp
from flax import struct

import cognet_jax
from cognet_jax.envs.base import scaled_normal


@struct.dataclass
class SeekParams:
    noise: float = 0.3
    discount: float = 0.95


@dataclasses.dataclass(frozen=True)
class Seek:
    """Agents on [0, 10] move left / stay / right; each sees goal - position + noise."""

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
        obs = state[2] - pos + scaled_normal(params.noise, u)
        return state.at[:2].set(pos), obs, reward


@dataclasses.dataclass
class SeekSection:  # the [env] config section: every field a setting with its default
    name: str = "seek"
    noise: float = 0.3


cognet_jax.register_env("seek", SeekSection, lambda s, cfg: (Seek(), SeekParams(noise=s.noise)))


# the hand-written controller: node 0 takes the blind first step, nodes 1-3 move left, stay,
# right; the next node steps toward the goal when the reading is beyond the margin, else stays
HAND_GRID = {"margin": (0.25, 0.5, 0.75, 1.0, 1.5), "first": (0, 1, 2)}


def hand_controller(env, margin, first):
    from cognet_jax.controllers.rules import RuleController, rule_policy

    def rule(theta, nodes, obs):
        return jnp.where(obs > theta["margin"], 3, jnp.where(obs < -theta["margin"], 1, 2))

    return RuleController(2, 4, rule), rule_policy(2, [first, 0, 1, 2], {"margin": margin})
