"""2D static-source heatmap problem (SPEC section 7.2), as pure JAX step functions.

A ``16 x 16`` scene holds the value ``exp(-(x^2 + y^2) / 50)`` in cell ``(x, y)`` (source at the
corner ``(0, 0)``, sigma 5, peak 1). Two independent agents move one cell per step; the joint
reward is the sum of the agents' rewards. Actions: ``0`` x+1, ``1`` x-1, ``2`` y-1, ``3`` y+1;
after each move every coordinate is clipped to ``[2, 13]``. One step:

1. reward per agent on the *pre-move* position, with ``D = x^2 + y^2``: ``D < 9`` -> +50,
   ``9 <= D < 16`` -> +1, otherwise -1 (``near_reward`` / ``mid_reward`` / ``far_reward``);
2. move and clip;
3. each agent observes the ``4 x 4`` patch of rows ``x-2..x+1`` and columns ``y-2..y+1`` (the
   agent sits at patch index ``(2, 2)``), flattened row-major: ``obs [agents, 16]``. Optional
   noise: ``patch + obs_noise_amplitude * N(obs_noise_mean, obs_noise_std)`` per pixel
   **[choice]**: the SPEC's "per-pixel additive amplitude * N(mean, std)" read literally; the
   noisy value is not clipped. ``obs_signal`` (default 1) scales the clean patch, so
   ``obs_signal = 0`` replaces the observation by the noise alone, or by the constant
   ``obs_noise_amplitude * obs_noise_mean`` with ``obs_noise_std = 0`` (the noise study's
   "does the policy use what it sees?" rows).

Start: ``x, y`` i.i.d. uniform integers in ``{start_low, ..., start_high}`` (params, so both
ranges share one compiled program). Thesis range ``{-1..12}`` (positions below 2 are rewarded
unclipped at t = 0, then clipped by the first move); default ``{2..13}`` (``START_RANGES``).
h = 4, gamma = 1.
"""

from __future__ import annotations

import dataclasses
from typing import Literal

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from cognet_jax.config import require, require_discount, require_nonnegative, require_positive
from cognet_jax.envs.base import scaled_normal
from cognet_jax.registry import register_env

SIZE = 16
PATCH = 4
LOW, HIGH = 2, 13
#: Named start ranges ``(low, high)``, both inclusive.
START_RANGES = {"thesis": (-1, 12), "default": (2, 13)}
ACTION_NAMES = ("x+1", "x-1", "y-1", "y+1")
#: ``(dx, dy)`` of each action.
MOVES = np.array([[1, 0], [-1, 0], [0, -1], [0, 1]], dtype=np.int32)


def scene(size: int = SIZE, sigma: float = 5.0) -> np.ndarray:
    """The heatmap ``[size, size]``: ``exp(-(x^2 + y^2) / (2 sigma^2))``, indexed ``[x, y]``."""
    x = np.arange(size, dtype=np.float64)
    return np.exp(-(x[:, None] ** 2 + x[None, :] ** 2) / (2.0 * sigma**2)).astype(np.float32)


def all_patches(image: np.ndarray | None = None) -> np.ndarray:
    """Every ``4 x 4`` stride-1 window of ``image`` (default: the scene), ``[144, 16]``, ordered by
    the window's top-left corner ``(r, c)`` row-major. The agent at ``(x, y)`` sees the window
    with top-left corner ``(x - 2, y - 2)``."""
    image = scene() if image is None else np.asarray(image)
    n = image.shape[0] - PATCH + 1
    return np.stack(
        [image[r : r + PATCH, c : c + PATCH].reshape(-1) for r in range(n) for c in range(n)]
    )


@struct.dataclass
class HeatmapParams:
    """Tunable numbers of the heatmap problem (a pytree)."""

    start_low: jax.Array | int = START_RANGES["default"][0]
    start_high: jax.Array | int = START_RANGES["default"][1]
    obs_noise_std: jax.Array | float = 0.0
    obs_noise_mean: jax.Array | float = 0.0
    obs_noise_amplitude: jax.Array | float = 1.0
    obs_signal: jax.Array | float = 1.0
    discount: jax.Array | float = 1.0
    near_reward: jax.Array | float = 50.0
    mid_reward: jax.Array | float = 1.0
    far_reward: jax.Array | float = -1.0


@struct.dataclass
class HeatmapState:
    pos: jax.Array  # [agents, 2] int32 (x, y)


def reward_of(pos, params: HeatmapParams):
    """Per-agent reward ``[agents]`` of positions ``pos [agents, 2]`` (pre-move)."""
    d = jnp.sum(pos.astype(jnp.int32) ** 2, axis=-1)
    return jnp.where(
        d < 9, params.near_reward, jnp.where(d < 16, params.mid_reward, params.far_reward)
    ).astype(jnp.float32)


@dataclasses.dataclass(frozen=True)
class Heatmap:
    """Static description of the heatmap problem (see module docstring)."""

    horizon: int = 4
    num_agents: int = 2

    num_actions: int = 4
    obs_shape: tuple[int, ...] = (PATCH * PATCH,)
    num_obs: int | None = None
    obs_range: tuple[float, float] | None = None
    action_names: tuple[str, ...] = ACTION_NAMES

    @property
    def action_counts(self) -> tuple[int, ...]:
        return (self.num_actions,) * self.num_agents

    @property
    def reset_noise(self) -> int:
        return 2 * self.num_agents

    @property
    def step_noise(self) -> int:
        """One normal draw per observed pixel: ``agents * 16``."""
        return self.num_agents * PATCH * PATCH

    def default_params(self) -> HeatmapParams:
        return HeatmapParams()

    def reset(self, u: jax.Array, params: HeatmapParams) -> HeatmapState:
        """``u [2 agents]``: uniform x then y of each agent, mapped to integers in the start
        range."""
        lo = jnp.asarray(params.start_low, jnp.int32)
        width = jnp.asarray(params.start_high, jnp.int32) - lo + 1
        cells = jnp.minimum(jnp.floor(u * width).astype(jnp.int32), width - 1) + lo
        return HeatmapState(pos=cells.reshape(self.num_agents, 2))

    def observe(self, pos: jax.Array, u: jax.Array, params: HeatmapParams) -> jax.Array:
        """Patches ``[agents, 16]`` at (clipped) positions ``pos [agents, 2]``; ``u
        [agents * 16]`` drives the noise."""
        image = jnp.asarray(scene())

        def patch(p):
            return jax.lax.dynamic_slice(image, (p[0] - 2, p[1] - 2), (PATCH, PATCH)).reshape(-1)

        clean = jax.vmap(patch)(pos)
        spread = scaled_normal(params.obs_noise_std, u).reshape(clean.shape)  # std * N(0, 1)
        noise = params.obs_noise_amplitude * (params.obs_noise_mean + spread)
        return params.obs_signal * clean + noise

    def step(
        self, u: jax.Array, state: HeatmapState, actions: jax.Array, params: HeatmapParams
    ) -> tuple[HeatmapState, jax.Array, jax.Array]:
        """One step; ``u [agents * 16]`` drive the observation noise. Returns
        ``(next_state, obs [agents, 16] float32, joint reward [])``."""
        reward = jnp.sum(reward_of(state.pos, params))
        pos = jnp.clip(state.pos + jnp.asarray(MOVES)[actions], LOW, HIGH)
        obs = self.observe(pos, u, params)
        return HeatmapState(pos=pos), obs, reward


def make_heatmap(
    start: str = "default", horizon: int = 4, **overrides
) -> tuple[Heatmap, HeatmapParams]:
    """The env and params for a named start range (``"thesis"`` or ``"default"``);
    ``overrides`` set params fields."""
    if start not in START_RANGES:
        raise ValueError(f"unknown start range {start!r}; choose from {sorted(START_RANGES)}")
    lo, hi = START_RANGES[start]
    params = HeatmapParams(start_low=lo, start_high=hi).replace(**overrides)
    return Heatmap(horizon=horizon), params


def _knowledge_values(start: str, horizon: int) -> tuple[dict, dict]:
    """Per-agent optimal values with full knowledge of the own position: ``value[k][(x, y)]``
    with ``k`` steps to go (reward of the current state, then the best move), backward dynamic
    programming over every position that can be started in or reached."""
    lo, _ = START_RANGES[start]
    coords = np.arange(lo, HIGH + 1)

    def r(x, y):
        d = x * x + y * y
        return 50.0 if d < 9 else (1.0 if d < 16 else -1.0)

    values = [{(x, y): 0.0 for x in coords for y in coords}]
    for _ in range(horizon):
        value, new = values[-1], {}
        for x in coords:
            for y in coords:
                best = max(value[_moved(x, y, dx, dy)] for dx, dy in MOVES)
                new[(x, y)] = r(x, y) + best
        values.append(new)
    return values, {(x, y): r(x, y) for x in coords for y in coords}


def _moved(x, y, dx, dy) -> tuple[int, int]:
    return min(max(x + dx, LOW), HIGH), min(max(y + dy, LOW), HIGH)


def _starts(start: str) -> list[tuple[int, int]]:
    lo, hi = START_RANGES[start]
    return [(x, y) for x in range(lo, hi + 1) for y in range(lo, hi + 1)]


def full_knowledge_value(start: str = "thesis", horizon: int = 4, num_agents: int = 2) -> float:
    """Best expected return with full knowledge of each agent's own position from the start:
    backward dynamic programming over the (x, y) grid for one agent, averaged over the uniform
    start range, times the number of agents (agents are independent; the joint reward is a
    sum). Plain numpy. SPEC's 53.14 (thesis range)."""
    values, _ = _knowledge_values(start, horizon)
    return num_agents * float(np.mean([values[horizon][s] for s in _starts(start)]))


def first_move_blind_value(start: str = "thesis", horizon: int = 4, num_agents: int = 2) -> float:
    """Upper bound on the expected return of any policy that makes its first move before it
    observes anything, as every controller here does (all agents start in node 0 and act from
    it; the first observation comes after the first move): the best single first move for the
    whole start range, then full knowledge of the own position. Plain numpy.

    It is attained, so it is the optimum of that class: a noise-free patch determines the
    position, and the 2-node reactive controller "move x-1 first; then x-1 while x > 2, else
    y-1" reaches it (tests/test_heatmap.py). Thesis range: 46.898 (against 53.143 for a first
    move that knows the start)."""
    values, reward = _knowledge_values(start, horizon)
    starts = _starts(start)
    return num_agents * max(
        float(np.mean([reward[s] + values[horizon - 1][_moved(*s, dx, dy)] for s in starts]))
        for dx, dy in MOVES
    )


def distance_only_value(start: str = "thesis", horizon: int = 4, num_agents: int = 2) -> float:
    """Best expected return of any policy whose observations tell only the squared distance
    ``x^2 + y^2`` of the own position to the source (with perfect memory of everything it saw
    and did), as a patch encoder that keeps only the distance does (the thesis's 1-D VAE).

    Exact: the moves are deterministic, so an agent's knowledge after a history is the set of
    start positions consistent with it; backward recursion over these sets (act, then split the
    set by the distance observed after the move). The first move is blind as in every
    controller here. Thesis range 42.73, default range 3.01 (below 46.898 / 4.431 of
    ``first_move_blind_value``, which knows the position after the first move)."""
    _, reward = _knowledge_values(start, horizon)

    def value(positions: list[tuple[int, int]], to_go: int) -> float:
        total = sum(reward[p] for p in positions)
        if to_go == 1:
            return total
        best = -np.inf
        for dx, dy in MOVES:
            groups: dict[int, list[tuple[int, int]]] = {}
            for x, y in positions:
                q = _moved(x, y, dx, dy)
                groups.setdefault(q[0] * q[0] + q[1] * q[1], []).append(q)
            best = max(best, sum(value(g, to_go - 1) for g in groups.values()))
        return total + best

    starts = _starts(start)
    return num_agents * value(starts, horizon) / len(starts)


def random_value(start: str = "thesis", horizon: int = 4, num_agents: int = 2) -> float:
    """Exact expected return of uniformly random moves: dynamic programming over the (x, y)
    grid of one agent (value = reward + mean over the 4 moves), averaged over the uniform start
    range, times the number of agents. Plain numpy."""
    lo, hi = START_RANGES[start]
    coords = np.arange(lo, HIGH + 1)
    x, y = np.meshgrid(coords, coords, indexing="ij")
    d = x**2 + y**2
    reward = np.where(d < 9, 50.0, np.where(d < 16, 1.0, -1.0))
    value = np.zeros_like(reward)
    for _ in range(horizon):
        nxt = [
            value[np.clip(x + dx, LOW, HIGH) - lo, np.clip(y + dy, LOW, HIGH) - lo]
            for dx, dy in MOVES
        ]
        value = reward + np.mean(nxt, axis=0)
    return num_agents * float(value[: hi - lo + 1, : hi - lo + 1].mean())


# ---------------------------------------------------------------------------------------------
# configuration: the [env] section and the registration (cognet_jax.registry)
# ---------------------------------------------------------------------------------------------
@dataclasses.dataclass
class HeatmapSection:
    """``[env]`` of the 2D heatmap (SPEC 7.2). ``start``: ``"thesis"`` ({-1..12}) or
    ``"default"`` ({2..13}); observation ``obs_signal * patch + obs_noise_amplitude *
    N(obs_noise_mean, obs_noise_std)`` per pixel (``obs_signal = 0``: the patch replaced by
    noise or a constant); rewards per agent on the pre-move state (``D < 9`` / ``9 <= D < 16`` /
    else)."""

    name: str = "heatmap"
    start: Literal["thesis", "default"] = "default"
    horizon: int = 4
    discount: float = 1.0
    obs_noise_amplitude: float = 1.0
    obs_noise_mean: float = 0.0
    obs_noise_std: float = 0.0
    obs_signal: float = 1.0
    near_reward: float = 50.0
    mid_reward: float = 1.0
    far_reward: float = -1.0

    def check(self, config) -> None:
        require_positive(self, "env", "horizon")
        require_discount(self.discount, "env.discount")
        require_nonnegative(self, "env", "obs_noise_std", "obs_noise_amplitude")
        require(
            0.0 <= self.obs_signal <= 1.0,
            "env.obs_signal",
            f"must be in [0, 1], got {self.obs_signal}",
        )


def build_from_section(section: HeatmapSection, config) -> tuple[Heatmap, HeatmapParams]:
    fields = dataclasses.asdict(section)
    for static in ("name", "start", "horizon"):
        fields.pop(static)
    return make_heatmap(section.start, horizon=section.horizon, **fields)


register_env(
    "heatmap",
    HeatmapSection,
    build_from_section,
    dynamic=("discount",),
    # SPEC section 8
    references={"thesis": {"full knowledge of own position": 53.14, "random actions": 19.37}},
    reference_field="start",
    overwrite=False,
)
