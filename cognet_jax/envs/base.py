"""The simulator interface every Dec-POMDP environment implements.

Conventions (gymnax style, key first):

* ``env.reset(key, params) -> state`` draws ``s_0 ~ b0``. There is no observation before the
  first action (SPEC section 1).
* ``env.step(key, state, actions, params) -> (next_state, obs, reward)`` with ``actions`` of shape
  ``[agents]`` (int32). ``reward`` is the joint reward ``R(s_t, a_t)`` on the *pre-step* state,
  ``obs`` is ``z_{t+1}`` computed on ``s_{t+1}``: ``[agents, *obs_shape]`` float32 for continuous
  observations, ``[agents]`` int32 for discrete ones.

An environment object is a frozen (hashable) dataclass holding only *static* facts -- shapes,
horizon, number of agents -- so that it can be closed over by jitted code. Every tunable number
(noise levels, rewards, discount) lives in the ``params`` pytree, so sweeping over it needs no
recompilation.
"""

from __future__ import annotations

from typing import Any, Protocol

import jax

EnvState = Any
EnvParams = Any


class Environment(Protocol):
    """Static description plus pure step functions of a Dec-POMDP simulator."""

    #: Number of agents n.
    num_agents: int
    #: Actions per agent (the maximum over agents when they differ; see ``action_counts``).
    num_actions: int
    #: Per-agent action counts; controllers mask actions ``>= action_counts[i]``.
    action_counts: tuple[int, ...]
    #: Shape of one agent's observation: ``()`` for a scalar, ``(16,)`` for a 4x4 patch.
    obs_shape: tuple[int, ...]
    #: Number of discrete observations per agent (maximum over agents), or ``None`` if continuous.
    num_obs: int | None
    #: Episode length h (static: it is the scan length).
    horizon: int
    #: Range ``(low, high)`` of a scalar continuous observation (for regions and plots).
    obs_range: tuple[float, float] | None

    def default_params(self) -> EnvParams: ...

    def reset(self, key: jax.Array, params: EnvParams) -> EnvState: ...

    def step(
        self, key: jax.Array, state: EnvState, actions: jax.Array, params: EnvParams
    ) -> tuple[EnvState, jax.Array, jax.Array]: ...
