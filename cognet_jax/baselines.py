"""The hand-written controller of a simulator, its thresholds tuned by a grid search.

Every simulator of the suite (``cognet_jax.envs.hearing_tiger``, ``beacon``, ``bearing_chase``,
``plume``, ``box_push``) has ``hand_controller(env, **thresholds) -> (controller, policy)``
(``controllers.rules``) and ``HAND_GRID``, the values a practitioner would try. ``tune``
evaluates every point of the grid on ``rollouts`` rollouts of one key (common random numbers:
the same episodes for every point), keeps the best, and re-evaluates it on a fresh key: the
reported value is that fresh evaluation, as for a search's policy (SPEC section 2, honest
value).
"""

from __future__ import annotations

import dataclasses
import functools
import importlib
import itertools
import sys

import jax
import numpy as np

from cognet_jax.registry import BUILTIN_ENVS, env_entry
from cognet_jax.rollout import rollouts

#: keys of the grid search and of the fresh evaluation of its winner
TUNE_SEED, HONEST_SEED = 101, 202


@dataclasses.dataclass(frozen=True)
class Tuned:
    """The grid search's result: every point's value (tuning key), the winner, its honest
    value ``(mean, standard error)`` on the fresh key."""

    grid: dict
    values: list  # [(thresholds dict, mean)]
    best: dict
    honest: tuple[float, float]
    rollouts: int  # of the honest value


def simulator_module(env_name: str):
    """The module of simulator ``env_name``: the built-in one, or the module that registered
    it (a plug-in may ship ``hand_controller`` and ``HAND_GRID`` too); ``ValueError`` for one
    without a hand-written controller."""
    if env_name in BUILTIN_ENVS:
        module = importlib.import_module(BUILTIN_ENVS[env_name])
    else:
        module = sys.modules[env_entry(env_name).build.__module__]
    if not hasattr(module, "hand_controller"):
        raise ValueError(f"simulator {env_name!r} has no hand-written controller")
    return module


def hand_returns(env, env_params, controller, policy, key, num: int) -> np.ndarray:
    """Returns ``[num]`` of the deterministic ``policy`` under ``env_params``."""
    return np.asarray(_program(env, controller, num)(key, env_params, policy), dtype=np.float64)


@functools.lru_cache(maxsize=32)
def _program(env, controller, num: int):
    """One compiled program per simulator, controller shape and batch: the grid's points
    differ only in the policy's thresholds, an argument."""
    return jax.jit(lambda k, e, p: rollouts(env, controller, k, num, e, p))


def tune(
    env_name: str, env, env_params, rollouts_per_point: int = 20_000, honest_rollouts: int = 0
) -> Tuned:
    """Grid search of the simulator's ``HAND_GRID`` (module docstring); the winner's honest
    value on ``honest_rollouts`` fresh rollouts (0: ``rollouts_per_point``)."""
    module = simulator_module(env_name)
    grid = module.HAND_GRID
    values = []
    for point in itertools.product(*grid.values()):
        theta = dict(zip(grid, point))
        controller, policy = module.hand_controller(env, **theta)
        r = hand_returns(
            env, env_params, controller, policy, jax.random.key(TUNE_SEED), rollouts_per_point
        )
        values.append((theta, float(r.mean())))
    best = max(values, key=lambda tv: tv[1])[0]
    controller, policy = module.hand_controller(env, **best)
    count = honest_rollouts or rollouts_per_point
    r = hand_returns(env, env_params, controller, policy, jax.random.key(HONEST_SEED), count)
    honest = (float(r.mean()), float(r.std() / np.sqrt(len(r))))
    return Tuned(dict(grid), values, best, honest, count)
