"""Tagging simulator (SPEC section 7.1) in plain Python floats and in batched torch tensors.

Both versions mirror ``cognet_jax.envs.tagging.Tagging`` exactly: given the same uniform(0, 1)
numbers they return the same next state, observations and reward.

* ``reset``: ``u [agents + 1]`` -> tagger positions ``u[:n] * length``, evader ``u[n] * length``.
* ``step``: ``u [3 agents + 1]`` laid out as ``[motion noise (n), observation noise (n),
  respawn positions (n + 1)]``; normal draws by the inverse CDF of the uniforms clipped to
  ``[1e-7, 1 - 1e-7]``.

One step: (1) joint reward on the pre-step state (tag within ``tag_radius`` +50, tag otherwise -20,
move -1, summed over taggers); (2) taggers move -1 / 0 / +1 plus ``motion_noise * N(0, 1)``,
clipped to ``[0, length]``; (3) the evader moves one unit away: ``d = sum_i (p_i' - e)``, ``e' =
clip(e - sign(d))``; (4) with ``respawn`` and any successful tag, all positions are redrawn from the
respawn uniforms; (5) ``z_i = e' - p_i' + obs_noise * N(0, 1)``, optionally discretised.

``step_scalar`` / ``reset_scalar`` work on Python lists and floats (double precision), for the
loop reference; ``step_batched`` / ``reset_batched`` work on float32 tensors with a leading batch
axis, for the vectorised reference.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from statistics import NormalDist

import torch

TAG, LEFT, RIGHT = 0, 1, 2
_EPS = 1e-7
_STD_NORMAL = NormalDist()

#: Standard settings, as in ``cognet_jax.envs.tagging.SETTINGS``.
SETTINGS = {
    "thesis": dict(horizon=3, discount=1.0, respawn=False),
    "cogdice-paper": dict(horizon=150, discount=0.9, respawn=True),
}


@dataclasses.dataclass(frozen=True)
class TaggingConfig:
    """Every number of the tagging problem (static shape facts and tunable parameters)."""

    horizon: int = 3
    num_agents: int = 2
    length: float = 10.0
    obs_division: float = 0.0
    motion_noise: float = 0.0
    obs_noise: float = 0.0
    respawn: bool = False
    discount: float = 1.0
    tag_reward: float = 50.0
    miss_reward: float = -20.0
    move_reward: float = -1.0
    tag_radius: float = 1.0

    num_actions: int = 3

    @property
    def reset_noise(self) -> int:
        return self.num_agents + 1

    @property
    def step_noise(self) -> int:
        """Motion noise (n), observation noise (n), respawn positions (n + 1)."""
        return 3 * self.num_agents + 1

    @property
    def step_noise_used(self) -> int:
        """Columns of ``step_noise`` a batched rollout needs to draw: all of them when any noise
        or respawn is on, none in the noise-free setting (where ``step_batched`` reads none, and
        XLA drops the unused draws of the JAX side the same way)."""
        noisy = self.motion_noise or self.obs_noise or self.respawn
        return self.step_noise if noisy else 0


def make_tagging(
    setting: str = "thesis", horizon: int | None = None, obs_division: float = 0.0, **overrides
) -> TaggingConfig:
    """Config of a named setting (``thesis`` or ``cogdice-paper``); ``overrides`` set fields."""
    if setting not in SETTINGS:
        raise ValueError(f"unknown tagging setting {setting!r}; choose from {sorted(SETTINGS)}")
    s = SETTINGS[setting]
    return TaggingConfig(
        horizon=horizon or s["horizon"],
        obs_division=obs_division,
        discount=s["discount"],
        respawn=s["respawn"],
        **overrides,
    )


# -- scalar (Python floats) ------------------------------------------------------------------


def normal_scalar(u: float) -> float:
    """Standard normal draw from one uniform number (inverse CDF)."""
    return _STD_NORMAL.inv_cdf(min(max(u, _EPS), 1.0 - _EPS))


def discretise_scalar(z: float, division: float) -> float:
    if division <= 0:
        return z
    if division < 1:
        return round(z / division) * division
    return math.trunc(round(z) / division) * division


def reset_scalar(u: Sequence[float], cfg: TaggingConfig) -> tuple[list[float], float]:
    """``u [agents + 1]`` -> ``(taggers [agents], evader)``."""
    pos = [x * cfg.length for x in u]
    return pos[:-1], pos[-1]


def step_scalar(
    u: Sequence[float],
    taggers: Sequence[float],
    evader: float,
    actions: Sequence[int],
    cfg: TaggingConfig,
) -> tuple[list[float], float, list[float], float]:
    """One step of one rollout; returns ``(taggers', evader', obs [agents], reward)``."""
    n = cfg.num_agents
    reward = 0.0
    hit_any = False
    for p, a in zip(taggers, actions):
        if a == TAG:
            if abs(p - evader) <= cfg.tag_radius:
                reward += cfg.tag_reward
                hit_any = True
            else:
                reward += cfg.miss_reward
        else:
            reward += cfg.move_reward
    new_taggers = []
    for i, (p, a) in enumerate(zip(taggers, actions)):
        move = -1.0 if a == LEFT else (1.0 if a == RIGHT else 0.0)
        noise = cfg.motion_noise * normal_scalar(u[i]) if cfg.motion_noise else 0.0
        new_taggers.append(min(max(p + move + noise, 0.0), cfg.length))
    d = sum(p - evader for p in new_taggers)
    step_e = 1.0 if d < 0 else (-1.0 if d > 0 else 0.0)
    new_evader = min(max(evader + step_e, 0.0), cfg.length)
    if cfg.respawn and hit_any:
        new_taggers, new_evader = reset_scalar(u[2 * n :], cfg)
    obs = []
    for i, p in enumerate(new_taggers):
        noise = cfg.obs_noise * normal_scalar(u[n + i]) if cfg.obs_noise else 0.0
        obs.append(discretise_scalar(new_evader - p + noise, cfg.obs_division))
    return new_taggers, new_evader, obs, reward


# -- batched (torch tensors, leading batch axis B) ----------------------------------------------


def normal_batched(u: torch.Tensor) -> torch.Tensor:
    """Standard normal draws from uniform numbers (inverse CDF), any shape."""
    return torch.special.ndtri(u.clamp(_EPS, 1.0 - _EPS))


def discretise_batched(z: torch.Tensor, division: float) -> torch.Tensor:
    if division <= 0:
        return z
    if division < 1:
        return torch.round(z / division) * division
    return torch.trunc(torch.round(z) / division) * division


def reset_batched(u: torch.Tensor, cfg: TaggingConfig) -> tuple[torch.Tensor, torch.Tensor]:
    """``u [B, agents + 1]`` -> ``(taggers [B, agents], evader [B])``."""
    pos = u * cfg.length
    return pos[:, :-1], pos[:, -1]


def step_batched(
    u: torch.Tensor,
    taggers: torch.Tensor,
    evader: torch.Tensor,
    actions: torch.Tensor,
    cfg: TaggingConfig,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """One step of B rollouts.

    ``u [B, 3 agents + 1]``, ``taggers [B, agents]``, ``evader [B]``, ``actions [B, agents]``
    (integer); returns ``(taggers', evader', obs [B, agents], reward [B])``.
    """
    n = cfg.num_agents
    u_motion, u_obs, u_respawn = u[:, :n], u[:, n : 2 * n], u[:, 2 * n :]
    e = evader[:, None]
    tagging = actions == TAG
    hit = tagging & ((taggers - e).abs() <= cfg.tag_radius)
    per_agent = torch.where(
        tagging,
        torch.where(hit, cfg.tag_reward, cfg.miss_reward),
        torch.full_like(taggers, cfg.move_reward),
    )
    reward = per_agent.sum(-1)
    move = (actions == RIGHT).to(taggers.dtype) - (actions == LEFT).to(taggers.dtype)
    p_next = taggers + move
    if cfg.motion_noise:
        p_next = p_next + cfg.motion_noise * normal_batched(u_motion)
    p_next = p_next.clamp(0.0, cfg.length)
    d = (p_next - e).sum(-1)
    e_next = (evader - torch.sign(d)).clamp(0.0, cfg.length)
    if cfg.respawn:
        r_taggers, r_evader = reset_batched(u_respawn, cfg)
        do = hit.any(-1)
        p_next = torch.where(do[:, None], r_taggers, p_next)
        e_next = torch.where(do, r_evader, e_next)
    obs = e_next[:, None] - p_next
    if cfg.obs_noise:
        obs = obs + cfg.obs_noise * normal_batched(u_obs)
    obs = discretise_batched(obs, cfg.obs_division)
    return p_next, e_next, obs, reward
