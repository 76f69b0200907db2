"""Dec-Tiger with Gaussian hearing: the classic Dec-POMDP benchmark (Nair et al. 2003) with a
continuous scalar observation, as pure JAX step functions.

A tiger sits behind the left (state 0) or the right door (state 1). Two agents each ``listen``
(0), ``open-left`` (1) or ``open-right`` (2). Rewards, joint, on the pre-step state (MADP's
``dectiger``): both listen -2; one listens while the other opens the treasure door +9, the
tiger door -101; both open the treasure door +20, both the tiger door -50; different doors
-100. Any opened door resets the tiger uniformly; listening leaves it.

Observation (**[choice]**, the continuous reading of Dec-Tiger's 0.85 hearing accuracy): when
both listened, agent i hears ``z_i = -1 (tiger left) or +1 (right) + N(0, hearing_std)``,
independently; otherwise ``z_i = N(0, hearing_std)`` (nothing to hear). ``hearing_std = 1``
gives a correct sign with probability 0.84; 3 makes the noise dominate (0.63). Coordination is
the point: a door pays only when both agents open it in the same step.

Defaults: h 10, gamma 1. Hand-written controller (``hand_controller``): count the clear
hearings (``|z| > margin``) to one side and the other; open the door away from the tiger when
the count reaches ``count``, then start over.
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
    ContinuousObservations,
    scaled_normal,
)
from cognet_jax.registry import register_fields_env

LISTEN, OPEN_LEFT, OPEN_RIGHT = 0, 1, 2
ACTION_NAMES = ("listen", "open-left", "open-right")
#: joint reward ``[tiger, action of agent 0, action of agent 1]`` (MADP dectiger)
REWARDS = np.array(
    [
        [[-2, -101, 9], [-101, -50, -100], [9, -100, 20]],  # tiger left: open-right is safe
        [[-2, 9, -101], [9, 20, -100], [-101, -100, -50]],  # tiger right: open-left is safe
    ],
    dtype=np.float32,
)


@struct.dataclass
class TigerParams:
    hearing_std: jax.Array | float = 1.0
    discount: jax.Array | float = 1.0


@dataclasses.dataclass(frozen=True)
class HearingTiger(ContinuousObservations):
    """Static facts: two agents, three actions, a scalar observation."""

    horizon: int = 10
    num_agents: typing.ClassVar[int] = 2
    num_actions: typing.ClassVar[int] = 3
    action_names: typing.ClassVar[tuple[str, ...]] = ACTION_NAMES
    obs_shape: typing.ClassVar[tuple[int, ...]] = ()
    obs_range: typing.ClassVar[tuple[float, float]] = (-4.0, 4.0)
    reset_noise: typing.ClassVar[int] = 1
    step_noise: typing.ClassVar[int] = 3  # the tiger's reset, each agent's hearing

    def default_params(self) -> TigerParams:
        return TigerParams()

    def reset(self, u: jax.Array, params: TigerParams) -> jax.Array:
        """``u [1]`` -> the tiger's side, int32 ``[]`` (0 left, 1 right)."""
        return (u[0] >= 0.5).astype(jnp.int32)

    def step(self, u, tiger, actions, params: TigerParams):
        """``u [3]``: the tiger's reset, then the two agents' hearing noise. Returns
        ``(tiger', obs [2] float32, reward [])``."""
        reward = jnp.asarray(REWARDS)[tiger, actions[0], actions[1]]
        listened = jnp.all(actions == LISTEN)
        tiger_next = jnp.where(listened, tiger, (u[0] >= 0.5).astype(jnp.int32))
        side = jnp.where(tiger_next == 0, -1.0, 1.0)
        obs = jnp.where(listened, side, 0.0) + scaled_normal(params.hearing_std, u[1:])
        return tiger_next, obs.astype(jnp.float32), reward


def upper_bound(horizon: int, discount: float) -> float:
    """Both agents open the treasure door at every step, as if they saw the tiger: ``20 sum_t
    gamma^t``. No controller reaches it (the first step is blind, hearing is noisy)."""
    return float(20.0 * sum(discount**t for t in range(horizon)))


# ---------------------------------------------------------------------------------------------
# the hand-written controller
# ---------------------------------------------------------------------------------------------
#: thresholds tried by the grid search: ``count`` clear hearings, ``margin`` for a clear one
#: (wide enough that the tuned point is inside it at hearing noise 1 and 3)
HAND_GRID = {
    "count": (1, 2, 3, 4, 5),
    "margin": (0.0, 0.25, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 4.0),
}


def hand_controller(env: HearingTiger, count: int, margin: float):
    """``(controller, policy)``: nodes ``0 .. 2 count - 2`` listen and hold the tally ``c``
    (``|c| < count``; node 0 is ``c = 0``, ``c > 0`` is node ``2c - 1``, ``c < 0`` node
    ``-2c``); each hearing adds ``+1`` if ``z > margin`` (tiger right), ``-1`` if ``z < -margin``.
    At ``c = count`` the agent opens the left door (node ``2 count - 1``), at ``-count`` the
    right one (node ``2 count``); after opening it starts over at node 0."""
    open_left, open_right = 2 * count - 1, 2 * count
    actions = [LISTEN] * (2 * count - 1) + [OPEN_LEFT, OPEN_RIGHT]

    def rule(theta, nodes, obs):
        tally = jnp.where(nodes % 2 == 1, (nodes + 1) // 2, -(nodes // 2))
        heard = (obs > theta["margin"]).astype(jnp.int32) - (obs < -theta["margin"])
        tally = tally + heard
        listening = nodes < open_left
        nxt = jnp.where(tally > 0, 2 * tally - 1, -2 * tally)
        nxt = jnp.where(tally >= count, open_left, jnp.where(tally <= -count, open_right, nxt))
        return jnp.where(listening, nxt, 0)

    controller = RuleController(2, 2 * count + 1, rule)
    return controller, rule_policy(2, actions, {"margin": margin})


# ---------------------------------------------------------------------------------------------
# configuration
# ---------------------------------------------------------------------------------------------
@dataclasses.dataclass
class HearingTigerSection:
    """``[env]`` of Dec-Tiger with Gaussian hearing (module docstring)."""

    name: str = "hearing-tiger"
    horizon: int = 10
    discount: float = 1.0
    hearing_std: float = 1.0

    def check(self, config) -> None:
        require_positive(self, "env", "horizon")
        require_discount(self.discount, "env.discount")
        require_nonnegative(self, "env", "hearing_std")
        require(self.horizon <= 10_000, "env.horizon", f"at most 10000, got {self.horizon}")


#: ``build_from_section(section, config) -> (env, params)``: the registered builder
build_from_section = register_fields_env(
    "hearing-tiger", HearingTigerSection, HearingTiger, TigerParams
).build
