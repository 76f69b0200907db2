"""Inputs of the seventh hostile round (issue 53): a user simulator with no agents or with
discrete observations outside its ``num_obs``, an experiment name too long for a folder, a
sweep's state naming no experiment, a controller figure of a million observations and an
``--import`` file given by a path that starts with ``..``."""

from __future__ import annotations

import dataclasses
import json
import shutil

import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct

from cognet_jax import cli, plots
from cognet_jax.config import ConfigError
from cognet_jax.envs.base import _CHECKED, GuardedSteps, check_simulator
from cognet_jax.errors import SimulatorError
from cognet_jax.registry import load_config


@struct.dataclass
class Params:
    discount: float = 0.9


@dataclasses.dataclass(frozen=True)
class Coins:
    """Two agents observing a discrete sign; ``low``/``high``: the observations it returns."""

    low: int = 0
    high: int = 1
    num_agents: int = 2
    horizon: int = 4
    num_actions: int = 2
    action_counts: tuple = (2, 2)
    obs_shape: tuple = ()
    num_obs: int = 2
    obs_range: None = None
    reset_noise: int = 1
    step_noise: int = 2

    def reset(self, u, params):
        return u[0]

    def step(self, u, state, actions, params):
        obs = jnp.where(u[: self.num_agents] > state, self.high, self.low).astype(jnp.int32)
        return state, obs, jnp.sum(actions == 1).astype(jnp.float32)


def _check(env):
    _CHECKED.clear()
    check_simulator(env, Params(), "coins-test", values=True)


def test_discrete_observations_outside_num_obs_are_refused_not_clamped():
    _check(Coins())
    with pytest.raises(
        SimulatorError, match=r"discrete observation outside 0 \.\. 1 \(num_obs 2\)"
    ):
        _check(Coins(low=-3, high=7))
    with pytest.raises(SimulatorError, match="outside 0 .. 1"):
        _check(Coins(high=2))  # only some steps: the random episodes find them


def test_the_honest_evaluation_makes_an_outside_observation_nan():
    """What the random episodes could miss, the honest evaluation's guard still refuses:
    the episode's return is NaN (``honest_value.final_value_of`` names the cause)."""
    env = GuardedSteps(Coins(high=5))
    u = jnp.asarray([0.9, 0.9])
    _, _, reward = env.step(u, jnp.float32(0.1), jnp.asarray([0, 1]), Params())
    assert np.isnan(float(reward))
    _, _, reward = GuardedSteps(Coins()).step(u, jnp.float32(0.1), jnp.asarray([0, 1]), Params())
    assert float(reward) == 1.0


def test_no_agents_and_a_bad_num_obs_are_named():
    with pytest.raises(SimulatorError, match="num_agents must be an integer >= 1, got 0"):
        _check(Coins(num_agents=0, action_counts=()))
    with pytest.raises(SimulatorError, match="num_obs must be None .* got 0"):
        _check(Coins(num_obs=0))
    with pytest.raises(SimulatorError, match=r"num_obs must be None .* got 2\.5"):
        _check(Coins(num_obs=2.5))


def test_an_experiment_name_too_long_for_a_folder_is_a_config_error():
    with pytest.raises(ConfigError, match="experiment.name.*300 bytes long, at most 240"):
        load_config("tagging-thesis-n3", ["experiment.name=" + "x" * 300])
    load_config("tagging-thesis-n3", ["experiment.name=" + "x" * 240])


def test_a_sweep_state_without_an_experiment_name_is_named(tmp_path, capsys):
    from shared_files import TINY_TRAIN

    out = tmp_path / "sw"
    assert cli.main(["sweep", *TINY_TRAIN, "--seeds", "1", "--out", str(out)]) == 0
    spec = out / "sweep-state" / "sweep.json"
    data = json.loads(spec.read_text())
    data["experiment"] = 5
    spec.write_text(json.dumps(data))
    capsys.readouterr()
    assert cli.main(["sweep", "--resume", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "sweep.json" in err and "experiment is not an experiment name" in err
    assert len(err.splitlines()) == 1


def test_a_controller_figure_of_a_million_observations_stays_small(tmp_path):
    transitions = np.zeros((2, 1_000_000), np.int32)
    transitions[:, 1::2] = 1
    edges = plots.tabular_graph_edges(transitions)
    assert [(s, d, len(labels)) for s, d, labels in edges] == [
        (0, 0, 500_000),
        (0, 1, 500_000),
        (1, 0, 500_000),
        (1, 1, 500_000),
    ]
    text = plots._edge_text(edges[0][2])
    assert text.endswith("... (500000 in all)") and len(text) < 200


def test_an_import_file_given_as_a_parent_relative_path_is_imported(tmp_path, monkeypatch):
    module = tmp_path / "mods" / "my-sim.py"
    module.parent.mkdir()
    module.write_text("VALUE = 7\n")
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    from cognet_jax.errors import UsageError
    from cognet_jax.plugins import import_plugin

    import_plugin("../mods/my-sim.py")
    with pytest.raises(UsageError, match="give a module name or a .py file"):
        import_plugin(".relative_module")
    shutil.rmtree(tmp_path / "mods")


def test_a_stop_during_an_import_is_seen_by_a_thread_while_the_main_thread_is_busy():
    """``plugins._StopWatcher``: a stop signal's byte reaches a thread of its own, which runs
    the import's stop handler itself (the main thread may be inside one long compiled call of
    the module, where no Python handler runs: a 20000 x 20000 matmul held SIGTERM for 24 s)."""
    import os
    import signal
    import threading
    import time

    from cognet_jax.plugins import _StopWatcher

    calls = []

    def stop(signum, frame):
        calls.append((signum, threading.current_thread() is threading.main_thread()))

    previous = signal.signal(signal.SIGTERM, stop)
    watcher = _StopWatcher(stop, os._exit)
    try:
        os.kill(os.getpid(), signal.SIGTERM)
        deadline = time.monotonic() + 5
        while (signal.SIGTERM, False) not in calls and time.monotonic() < deadline:
            time.sleep(0.01)
    finally:
        watcher.close()
        signal.signal(signal.SIGTERM, previous)
    assert (signal.SIGTERM, False) in calls  # the watcher's own call, off the main thread


def test_a_module_that_lowers_the_recursion_limit_is_named(tmp_path):
    import sys

    from cognet_jax.errors import UsageError
    from cognet_jax.plugins import import_plugin

    module = tmp_path / "shallow.py"
    module.write_text("import sys\nsys.setrecursionlimit(50)\n")
    limit = sys.getrecursionlimit()
    with pytest.raises(UsageError, match="lowered Python's recursion limit to 50"):
        import_plugin(str(module))
    assert sys.getrecursionlimit() == limit  # given back: the error is reported, not hit
