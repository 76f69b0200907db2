"""Sizes of ``cognet-dice`` from its budget and the simulator's noise (``algorithms.sizing``,
``algorithms.noise_pilot``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cognet_jax.algorithms.noise_pilot import Noise, noise_of_returns
from cognet_jax.algorithms.sizing import (
    EVAL_ROLLOUTS_RANGE,
    ITERATIONS_RANGE,
    resolving_rollouts,
    sized,
)


def test_the_pilot_separates_the_noise_from_the_spread_of_the_candidates():
    rng = np.random.default_rng(0)
    true_means = rng.normal(0.0, 2.0, size=(400, 1))
    returns = true_means + rng.normal(0.0, 5.0, size=(400, 200))
    noise = noise_of_returns(returns)
    assert noise.within == pytest.approx(5.0, rel=0.03)
    assert noise.between == pytest.approx(true_means.std(ddof=1), rel=0.1)


def test_rollouts_to_resolve_on_the_edges():
    assert Noise(2.0, 1.0).rollouts_to_resolve(8) == pytest.approx(256.0)
    assert Noise(0.0, 1.0).rollouts_to_resolve(8) == 0.0  # deterministic rollouts
    assert Noise(1.0, 0.0).rollouts_to_resolve(8) == math.inf  # candidates all alike
    assert Noise(float("nan"), 1.0).rollouts_to_resolve(8) == math.inf
    assert resolving_rollouts(Noise(0.0, 1.0)) == EVAL_ROLLOUTS_RANGE[0]
    assert resolving_rollouts(Noise(1.0, 0.0)) == math.inf
    assert resolving_rollouts(Noise(float("inf"), 1.0)) == math.inf
    assert resolving_rollouts(None) == math.inf


def _env():
    from cognet_jax.envs.tagging import make_tagging

    env, _ = make_tagging("cogdice-paper")
    return env


@pytest.mark.parametrize("noise", [None, Noise(1.0, 1.0), Noise(10.0, 1.0), Noise(0.1, 1.0)])
def test_every_size_grows_with_the_budget_and_the_budget_is_spent(noise):
    from cognet_jax.algorithms.cognet_weights_settings import CognetWeightsSection

    env = _env()
    per_rollout = env.horizon * env.num_agents
    previous = None
    for budget in (1e5, 1e6, 1e8, 1e9, 1e10, 1e11, 3e11, 1e12):
        s = sized(CognetWeightsSection(budget=budget), env, noise)
        spent = s.iterations * s.candidates * s.eval_rollouts * per_rollout
        assert spent <= 1.05 * budget or s.iterations == 1
        assert 2 <= s.elites <= s.candidates
        assert EVAL_ROLLOUTS_RANGE[0] <= s.eval_rollouts <= EVAL_ROLLOUTS_RANGE[1]
        if s.iterations >= ITERATIONS_RANGE[0]:
            assert spent >= 0.9 * budget
        if previous is not None:
            assert s.iterations >= previous.iterations
            assert s.eval_rollouts >= previous.eval_rollouts
            assert s.candidates >= previous.candidates
        previous = s


def test_noise_only_moves_the_budget_from_rollouts_to_candidates():
    """A quiet simulator (few rollouts tell candidates apart) gets a larger population with
    fewer rollouts each; a noisy one the budget's own split, never fewer iterations."""
    from cognet_jax.algorithms.cognet_weights_settings import CognetWeightsSection

    env = _env()
    section = CognetWeightsSection(budget=1e10)
    unmeasured = sized(section, env)
    quiet = sized(section, env, Noise(1.0, 1.0))  # resolves with 64 rollouts
    loud = sized(section, env, Noise(10.0, 1.0))  # would need 6400
    assert loud == unmeasured
    assert quiet.iterations == unmeasured.iterations
    assert quiet.eval_rollouts == int((64 * unmeasured.eval_rollouts) ** 0.5)
    assert quiet.candidates > unmeasured.candidates
    spent = lambda s: s.iterations * s.candidates * s.eval_rollouts  # noqa: E731
    assert spent(quiet) == pytest.approx(spent(unmeasured), rel=0.02)
    given = sized(CognetWeightsSection(budget=1e10, eval_rollouts=50), env, Noise(10.0, 1.0))
    assert given.eval_rollouts == 50


def test_a_loaded_config_is_sized_from_one_pilot_whatever_the_budget(monkeypatch):
    from cognet_jax import status
    from cognet_jax.algorithms import noise_pilot
    from cognet_jax.registry import load_config

    calls = []
    real = noise_pilot.measure_noise

    def counted(algorithm, env_params):
        calls.append(1)
        return real(algorithm, env_params)

    told = []
    monkeypatch.setattr(noise_pilot, "measure_noise", counted)
    monkeypatch.setattr(noise_pilot, "_MEASURED", {})
    monkeypatch.setattr(status, "listener", told.append)
    first = load_config("hearing-tiger-n7", ["run.plots=false"]).algorithm
    overrides = ["run.progress=false", "algorithm.budget=1e8"]
    second = load_config("hearing-tiger-n7", overrides).algorithm
    assert len(calls) == 1  # the budget and the run section do not change what is measured
    assert len(told) == 1 and "measuring the simulator's noise" in told[0]
    assert isinstance(first.eval_rollouts, int) and isinstance(second.eval_rollouts, int)
    load_config("hearing-tiger-noisy-n7")
    assert len(calls) == 2  # another simulator: measured again


def test_a_budget_in_minutes_becomes_agent_steps_at_the_measured_rate(monkeypatch):
    """``budget_minutes``: the resolved config holds the agent-steps the minutes are at the
    pilot's rate (so a saved run repeats its sizes), twice the minutes twice the budget; with
    ``budget`` also set it is refused, naming the field."""
    from cognet_jax.algorithms import noise_pilot
    from cognet_jax.config import ConfigError
    from cognet_jax.registry import load_config

    monkeypatch.setattr(noise_pilot, "_MEASURED", {})
    one = load_config("hearing-tiger-n7", ["algorithm.budget_minutes=0.5"]).algorithm
    rate = next(iter(noise_pilot._MEASURED.values())).rate
    assert one.budget_minutes == 0.0 and one.budget == pytest.approx(rate * 30.0, rel=0.01)
    two = load_config("hearing-tiger-n7", ["algorithm.budget_minutes=1"]).algorithm
    assert two.budget == pytest.approx(2 * one.budget, rel=0.01)
    assert isinstance(one.iterations, int) and isinstance(one.eval_rollouts, int)
    with pytest.raises(ConfigError) as err:
        load_config("hearing-tiger-n7", ["algorithm.budget_minutes=1", "algorithm.budget=1e9"])
    assert err.value.field == "algorithm.budget_minutes"


@pytest.mark.parametrize(
    ("experiment", "setting", "blamed"),
    [
        # the sizes grown from the budget are not blamed
        ("tagging-paper-auto", "algorithm.budget=1e16", "algorithm.budget"),
        # an "auto" size given as a number
        ("tagging-paper-auto", "algorithm.iterations=1000000000", "algorithm.iterations"),
        ("tagging-thesis-n3", "env.horizon=1000000", "env.horizon"),
    ],
)
def test_a_run_too_long_names_the_size_that_made_it_so(experiment, setting, blamed, capsys):
    """``budget.check_budget`` refuses a run of weeks naming the field that is the largest
    multiple of its reference: "auto" sizes and the budget are measured against what the
    sizing rules give by default, not skipped."""
    from cognet_jax import cli

    assert cli.main(["check", experiment, "--set", setting]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"config field '{blamed}'" in err[0] and "days" in err[0], err


def test_an_iteration_that_simulates_nothing_still_takes_time():
    """A search whose iterations value their candidates exactly simulates no agent-steps: its
    least time is its iterations at ``FASTEST_ITERATION`` each, and a count of them that takes
    weeks is refused naming ``algorithm.iterations``."""
    from types import SimpleNamespace

    from cognet_jax import budget
    from cognet_jax.config import ConfigError

    def config(iterations):
        algorithm = SimpleNamespace(iterations=iterations, rollouts_per_iteration=lambda: 0)
        return SimpleNamespace(
            algorithm=algorithm,
            evaluation=SimpleNamespace(rollouts=10_000),
            run=SimpleNamespace(memory_gb=0.0),
        )

    env = SimpleNamespace(horizon=4, num_agents=2)
    least = budget.estimated_seconds(config(2_000_000), env)
    assert least == pytest.approx(2_000_000 * budget.FASTEST_ITERATION + 8e4 / budget.FASTEST_RATE)
    with pytest.raises(ConfigError, match="algorithm.iterations.*iterations take at least"):
        budget.check_budget(config(2 * 10**10), env)
