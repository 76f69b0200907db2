"""1D moving-source tagging problem (SPEC section 7.1), as pure JAX step functions.

A line ``[0, length]`` holds one evader and ``num_agents`` taggers, all with speed 1. Tagger
actions: ``0`` tag, ``1`` move left, ``2`` move right. One step:

1. reward on the pre-step state, summed over taggers: a tag with ``|p_i - e| <= tag_radius``
   gives ``tag_reward`` (+50), a tag otherwise ``miss_reward`` (-20), a move ``move_reward`` (-1);
2. taggers move -1/0/+1 plus Gaussian motion noise ``N(0, motion_noise)`` (on every action),
   clipped to the line;
3. the evader moves one unit away from the taggers: with ``d = sum_i (p_i' - e)`` it moves +1 if
   ``d < 0``, -1 if ``d > 0``, stays if ``d == 0``; clipped;
4. if ``respawn`` is on and any tagger tagged successfully, every position is redrawn uniformly;
5. each tagger observes ``z_i = e' - p_i' + N(0, obs_noise)`` (signed, unnormalised).

``obs_division > 0`` discretises observations (COG-DICE paper): round to an integer, then
truncate toward zero to a multiple of ``obs_division``; a division below 1 (e.g. 0.5) rounds to a
multiple of the division instead. The discretisation is static because it changes which
controllers apply.

``obs_index = True`` (with ``obs_division > 0``; what G-DICE's tabular controllers need) makes
``step`` return the *index* of the discretised observation instead of its value:
``obs [agents]`` int32 in ``0 .. num_obs - 1``, index k standing for the value
``observation_values[k] = (k - K) * obs_division`` with ``K = floor(length / obs_division)``, so
``num_obs = 2 K + 1`` (d = 0.5 / 1 / 2 / 4 on length 10: 41 / 21 / 11 / 5 observations).
Noise-free observations always lie in ``[-length, length]``; **[choice]** with observation noise
a value beyond the range is clipped to the first / last index.

Two standard settings (``SETTINGS``): ``thesis`` (h 3, gamma 1, no respawn) and
``cogdice-paper`` (h 150, gamma 0.9, respawn).
"""

from __future__ import annotations

import dataclasses
import math
import typing
from typing import Literal

import jax
import jax.numpy as jnp
from flax import struct

from cognet_jax.config import require, require_discount, require_nonnegative, require_positive
from cognet_jax.envs.base import scaled_normal, sum_last
from cognet_jax.registry import algorithm_entry, register_env


@struct.dataclass
class TaggingParams:
    """Tunable numbers of the tagging problem (a pytree: vmap or sweep over any leaf)."""

    motion_noise: jax.Array | float = 0.0
    obs_noise: jax.Array | float = 0.0
    respawn: jax.Array | bool = False
    discount: jax.Array | float = 1.0
    tag_reward: jax.Array | float = 50.0
    miss_reward: jax.Array | float = -20.0
    move_reward: jax.Array | float = -1.0
    tag_radius: jax.Array | float = 1.0


@struct.dataclass
class TaggingState:
    taggers: jax.Array  # [agents] float32 positions
    evader: jax.Array  # [] float32 position


#: Standard settings: horizon and default params.
SETTINGS = {
    "thesis": dict(horizon=3, discount=1.0, respawn=False),
    "cogdice-paper": dict(horizon=150, discount=0.9, respawn=True),
}

TAG, LEFT, RIGHT = 0, 1, 2
ACTION_NAMES = ("tag", "left", "right")


@dataclasses.dataclass(frozen=True)
class Tagging:
    """Static description of the tagging problem (see module docstring)."""

    horizon: int = 3
    num_agents: int = 2
    length: float = 10.0
    obs_division: float = 0.0
    obs_index: bool = False

    #: the same for every tagging problem: three actions, a scalar observation
    num_actions: typing.ClassVar[int] = 3
    action_names: typing.ClassVar[tuple[str, ...]] = ACTION_NAMES
    obs_shape: typing.ClassVar[tuple[int, ...]] = ()

    def __post_init__(self):
        if self.obs_index and self.obs_division <= 0:
            raise ValueError("obs_index needs obs_division > 0")

    @property
    def action_counts(self) -> tuple[int, ...]:
        return (self.num_actions,) * self.num_agents

    @property
    def num_obs(self) -> int | None:
        """Observation indices (``obs_index``), or ``None`` for a continuous observation."""
        return 2 * self._half_count + 1 if self.obs_index else None

    @property
    def _half_count(self) -> int:
        """K: the largest k with k * obs_division <= length (small tolerance for rounding)."""
        return int(math.floor(self.length / self.obs_division + 1e-9))

    @property
    def observation_values(self) -> tuple[float, ...] | None:
        """Value of each observation index (``obs_index`` only, else ``None``)."""
        if not self.obs_index:
            return None
        k = self._half_count
        return tuple((i - k) * self.obs_division for i in range(2 * k + 1))

    @property
    def obs_range(self) -> tuple[float, float] | None:
        """Range of the scalar observation; ``None`` for index observations."""
        return None if self.obs_index else (-self.length, self.length)

    @property
    def reset_noise(self) -> int:
        return self.num_agents + 1

    @property
    def step_noise(self) -> int:
        """Motion noise (n), observation noise (n), respawn positions (n + 1)."""
        return 3 * self.num_agents + 1

    def default_params(self) -> TaggingParams:
        return TaggingParams()

    def reset(self, u: jax.Array, params: TaggingParams) -> TaggingState:
        """``u [agents + 1]``: uniform positions of the taggers, then the evader."""
        pos = u * self.length
        return TaggingState(taggers=pos[:-1], evader=pos[-1])

    def step(
        self, u: jax.Array, state: TaggingState, actions: jax.Array, params: TaggingParams
    ) -> tuple[TaggingState, jax.Array, jax.Array]:
        """One step; ``u [3 agents + 1]`` = motion-noise, observation-noise and respawn
        uniforms. Returns ``(next_state, obs [agents] float32, joint reward [])``."""
        n = self.num_agents
        u_motion, u_obs, u_respawn = u[:n], u[n : 2 * n], u[2 * n :]
        p, e = state.taggers, state.evader
        tagging = actions == TAG
        hit = tagging & (jnp.abs(p - e) <= params.tag_radius)
        reward = sum_last(
            jnp.where(
                tagging, jnp.where(hit, params.tag_reward, params.miss_reward), params.move_reward
            )
        )
        move = jnp.where(actions == LEFT, -1.0, jnp.where(actions == RIGHT, 1.0, 0.0))
        noise = scaled_normal(params.motion_noise, u_motion)
        p_next = jnp.clip(p + move + noise, 0.0, self.length)
        d = sum_last(p_next - e)
        e_next = jnp.clip(e - jnp.sign(d), 0.0, self.length)
        respawned = self.reset(u_respawn, params)
        do_respawn = jnp.logical_and(params.respawn, jnp.any(hit))
        p_next = jnp.where(do_respawn, respawned.taggers, p_next)
        e_next = jnp.where(do_respawn, respawned.evader, e_next)
        obs = e_next - p_next + scaled_normal(params.obs_noise, u_obs)
        obs = discretise(obs, self.obs_division)
        if self.obs_index:
            obs = observation_index(obs, self.obs_division, self._half_count)
        return TaggingState(taggers=p_next, evader=e_next), obs, reward


def discretise(obs: jax.Array, division: float) -> jax.Array:
    """COG-DICE paper discretisation (static ``division``; 0 leaves ``obs`` unchanged)."""
    if division <= 0:
        return obs
    if division < 1:
        return jnp.round(obs / division) * division
    return jnp.trunc(jnp.round(obs) / division) * division


def observation_index(obs: jax.Array, division: float, half_count: int) -> jax.Array:
    """Index ``round(obs / division) + half_count`` of a discretised observation, clipped to
    ``0 .. 2 half_count`` (int32, same shape as ``obs``)."""
    k = jnp.round(obs / division).astype(jnp.int32) + half_count
    return jnp.clip(k, 0, 2 * half_count)


def make_tagging(
    setting: str = "thesis",
    horizon: int | None = None,
    obs_division: float = 0.0,
    obs_index: bool = False,
    **overrides,
) -> tuple[Tagging, TaggingParams]:
    """Build the env and its params for a named setting; ``overrides`` set params fields;
    ``obs_index`` returns discretised observations as indices (see the module docstring)."""
    if setting not in SETTINGS:
        raise ValueError(f"unknown tagging setting {setting!r}; choose from {sorted(SETTINGS)}")
    s = SETTINGS[setting]
    env = Tagging(horizon=horizon or s["horizon"], obs_division=obs_division, obs_index=obs_index)
    params = TaggingParams(discount=s["discount"], respawn=s["respawn"])
    params = params.replace(**overrides)
    return env, params


# ---------------------------------------------------------------------------------------------
# configuration: the [env] section and the registration (cognet_jax.registry)
# ---------------------------------------------------------------------------------------------
@dataclasses.dataclass
class TaggingSection:
    """``[env]`` of 1D tagging (SPEC 7.1). ``horizon``/``discount``/``respawn`` default to the
    setting's."""

    name: str = "tagging"
    setting: Literal["thesis", "cogdice-paper"] = "thesis"
    horizon: int | None = None
    discount: float | None = None
    respawn: bool | None = None
    motion_noise: float = 0.0
    obs_noise: float = 0.0
    obs_division: float = 0.0

    def check(self, config) -> None:
        require_positive(self, "env", "horizon")
        require_discount(self.discount, "env.discount")
        require_nonnegative(self, "env", "motion_noise", "obs_noise", "obs_division")
        require(
            self.obs_division > 0 or not algorithm_entry(config.experiment.algorithm).discrete,
            "env.obs_division",
            f"{config.experiment.algorithm} needs discrete observations: give the division "
            "(> 0) that cuts the signed distance into intervals",
        )


def build_from_section(section: TaggingSection, config) -> tuple[Tagging, TaggingParams]:
    """Env and params of a ``[env]`` section; algorithms that need discrete observations
    (G-DICE's tabular controllers) read the discretised observation as an index."""
    overrides = dict(motion_noise=section.motion_noise, obs_noise=section.obs_noise)
    if section.discount is not None:
        overrides["discount"] = section.discount
    if section.respawn is not None:
        overrides["respawn"] = section.respawn
    discrete = algorithm_entry(config.experiment.algorithm).discrete
    return make_tagging(
        section.setting,
        horizon=section.horizon,
        obs_division=section.obs_division,
        obs_index=discrete and section.obs_division > 0,
        **overrides,
    )


register_env(
    "tagging",
    TaggingSection,
    build_from_section,
    dynamic=("motion_noise", "obs_noise", "discount", "respawn"),
    # SPEC section 8
    references={
        "thesis": {"reactive 3-node controller": 20.76, "random actions": -23.68},
        "cogdice-paper": {"reactive 3-node controller": 108.0, "COG-DICE (paper)": 101.8},
    },
    reference_field="setting",
    overwrite=False,  # a user's own "tagging" registered first stays
)
