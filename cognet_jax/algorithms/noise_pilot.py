"""How noisy one candidate's evaluation is against how much candidates differ: the measurement
``sizing`` reads to choose ``eval_rollouts``.

``measure_noise(algorithm, env_params)`` draws ``PILOT_CANDIDATES`` joint controllers from the
search's initial distribution and rolls each out ``PILOT_ROLLOUTS`` times on the same keys
(common random numbers, as the search evaluates them). ``within`` is the standard deviation of
one rollout's return (root mean of the candidates' variances), ``between`` the spread of the
candidates' true means (the variance of their sample means less the noise's share,
``within^2 / PILOT_ROLLOUTS``).

**[choice]** The pilot uses the fixed key ``PILOT_KEY``, not the run's seed: every seed of a
sweep then runs the same sizes (one program for all seeds), a run's sizes are a function of its
config alone, and the pilot consumes none of the run's random streams. Its cost is one small
program (64 x 64 rollouts), compiled and run once per process and problem
(``measure_noise_cached``).
"""

from __future__ import annotations

import dataclasses
import json
import math
import time

import jax
import numpy as np

from cognet_jax import status
from cognet_jax.memory import check_made_fits
from cognet_jax.rollout import rollouts
from cognet_jax.signals import in_background

PILOT_CANDIDATES = 64
PILOT_ROLLOUTS = 64
PILOT_KEY = 0


@dataclasses.dataclass(frozen=True)
class Noise:
    """``within``: std of one rollout's return; ``between``: std of the candidates' true mean
    returns, under the initial distribution."""

    within: float
    between: float
    #: agent-steps per second of the pilot's rollouts (its compiled program's one call, timed
    #: apart from compiling): a lower bound on a search's rate, whose iterations roll out
    #: larger batches
    rate: float = math.nan

    def rollouts_to_resolve(self, resolution: float) -> float:
        """Rollouts that make a candidate's standard error ``between / resolution``:
        ``(resolution x within / between)^2``; ``inf`` when candidates do not differ (or the
        measurement is not finite), 0 when rollouts have no noise."""
        if not (math.isfinite(self.within) and math.isfinite(self.between)):
            return math.inf
        if self.within == 0.0:
            return 0.0
        if self.between <= 0.0:
            return math.inf
        return (resolution * self.within / self.between) ** 2


def noise_of_returns(returns: np.ndarray) -> Noise:
    """``Noise`` of returns ``[candidates, rollouts]`` (rollouts on common keys)."""
    r = np.asarray(returns, np.float64)
    within = float(np.sqrt(r.var(axis=1, ddof=1).mean()))
    means = r.mean(axis=1)
    share = within**2 / r.shape[1]
    between = float(np.sqrt(max(0.0, means.var(ddof=1) - share)))
    return Noise(within, between)


def check_pilot_fits(algorithm) -> None:
    """Refuse (``ResourceError``, before anything is made) a search whose pilot candidates'
    arrays are over its memory budget (``algorithm.memory``); only their shapes are read, so a
    search built without its input statistics may be checked first."""
    memory, key = getattr(algorithm, "memory", None), jax.random.key(PILOT_KEY)
    check_made_fits(algorithm.controller.init, (key,), memory, "one joint policy's arrays")
    check_made_fits(algorithm.init_distribution, (), memory, "the search's distribution")

    def drawn(k):
        return algorithm.to_policy(
            algorithm.draw(k, algorithm.init_distribution(), PILOT_CANDIDATES)
        )

    check_made_fits(drawn, (key,), memory, f"the noise pilot's {PILOT_CANDIDATES} candidates")


def measure_noise(algorithm, env_params) -> Noise:
    """``Noise`` of ``algorithm``'s initial distribution on the simulator of ``env_params``
    (``algorithm``: a search with ``init_distribution``, ``draw``, ``to_policy``, ``env`` and
    ``controller``, as ``CognetWeights``)."""
    draw_key, rollout_key = jax.random.split(jax.random.key(PILOT_KEY))
    check_pilot_fits(algorithm)  # before anything is made
    dist = algorithm.init_distribution()
    samples = algorithm.draw(draw_key, dist, PILOT_CANDIDATES)
    policies = algorithm.to_policy(samples)

    def returns(policy):
        return rollouts(
            algorithm.env, algorithm.controller, rollout_key, PILOT_ROLLOUTS, env_params, policy
        )

    program = jax.jit(jax.vmap(returns))

    def measure():  # in a worker thread: a stop signal is obeyed while XLA runs
        compiled = program.lower(policies).compile()  # compiled apart: the run alone is timed
        start = time.perf_counter()
        measured = noise_of_returns(np.asarray(compiled(policies)))  # one run: values, rate
        return measured, time.perf_counter() - start

    measured, seconds = in_background(measure)
    steps = PILOT_CANDIDATES * PILOT_ROLLOUTS * algorithm.env.horizon * algorithm.env.num_agents
    return dataclasses.replace(measured, rate=steps / max(seconds, 1e-9))


#: measurements of this process, by ``measure_noise_cached``'s key (the most recent few)
_MEASURED: dict[str, Noise] = {}
_MEASURED_MAX = 8


def measure_noise_cached(key_parts, build) -> Noise:
    """``measure_noise(*build())``, once per ``key_parts`` (a JSON-able description of the
    simulator and the search's distribution) in this process."""
    key = json.dumps(key_parts, sort_keys=True, default=repr)
    if key not in _MEASURED:
        if len(_MEASURED) >= _MEASURED_MAX:
            _MEASURED.pop(next(iter(_MEASURED)))
        # a measurement with its compile takes seconds: one line first (``status``)
        status.say(
            f"measuring the simulator's noise ({PILOT_CANDIDATES} candidates x "
            f"{PILOT_ROLLOUTS} rollouts) to size the search ..."
        )
        _MEASURED[key] = measure_noise(*build())
    return _MEASURED[key]
