"""Inputs of the fifth hostile round (issue 53): a user simulator's returns of other kinds
(a Python float reward, a list observation, a dict state, a negative noise count), configs
nested thousands deep, NaN in a sweep's grid, a model whose discount is 0, a policy file
gone, an ``--out`` that is a link to nowhere, a results.json of a newer schema, two modules
registering one name, one-seed summaries and an evaluation in other chunks."""

from __future__ import annotations

import dataclasses
import json
import shutil
import warnings

import jax.numpy as jnp
import pytest
from flax import struct
from shared_files import TINY_TRAIN, dpomdp_file

from cognet_jax import cli, registry
from cognet_jax.config import ConfigError
from cognet_jax.envs.base import _CHECKED, check_simulator
from cognet_jax.errors import OneLineWarning, SimulatorError
from cognet_jax.sweep import _mean_se, parse_grid


@struct.dataclass
class Params:
    discount: float = 0.9


@dataclasses.dataclass(frozen=True)
class Line:
    """Two agents on a line; ``kind`` picks what ``step`` returns wrongly."""

    kind: str = "ok"
    horizon: int = 4
    num_agents: int = 2
    num_actions: int = 3
    action_counts: tuple = (3, 3)
    obs_shape: tuple = ()
    num_obs: None = None
    obs_range: tuple = (-10.0, 10.0)
    reset_noise: int = 2
    step_noise: int = 0

    def reset(self, u, params):
        return 5.0 * u

    def step(self, u, state, actions, params):
        pos = jnp.clip(state + actions - 1.0, 0.0, 10.0)
        obs, reward = 3.0 - pos, jnp.sum(-jnp.abs(pos - 3.0))
        if self.kind == "float-reward":
            return pos, obs, 1.0
        if self.kind == "list-obs":
            return pos, [obs[0], obs[1]], reward
        if self.kind == "dict-state":
            return {"s": pos}, obs, reward
        return pos, obs, reward


def _check(env):
    _CHECKED.clear()
    check_simulator(env, Params(), "line-test", values=True)


def test_a_float_reward_is_a_reward_and_other_kinds_are_named():
    _check(Line("float-reward"))  # a Python number is one reward, as the rollouts take it
    with pytest.raises(SimulatorError, match="observation as a list .*expected one array"):
        _check(Line("list-obs"))
    with pytest.raises(SimulatorError, match=r"state's structure.*PyTreeDef\(\{'s': \*\}\)"):
        _check(Line("dict-state"))
    with pytest.raises(SimulatorError, match="reset_noise .* integer >= 0, got -1"):
        _check(Line(reset_noise=-1))


def test_values_nested_thousands_deep_are_a_config_error(tmp_path):
    deep = "[" * 3000 + "]" * 3000
    with pytest.raises(ConfigError, match="nested too deeply"):
        parse_grid([f"algorithm.nodes={deep}"])
    toml = tmp_path / "deep.toml"
    toml.write_text(f"[run]\nx = {deep}\n")
    with pytest.raises(ConfigError, match="deep.toml: invalid TOML: a value is nested too deep"):
        registry.load_config(str(toml))


def test_nan_in_a_grid_is_refused_as_with_set(tmp_path, capsys):
    out = tmp_path / "sweep"
    args = ["sweep", "tagging-thesis-n3", "--grid", "algorithm.alpha=nan,0.1", "--out", str(out)]
    assert cli.main(args) == 2
    assert "must be a finite number, got nan" in capsys.readouterr().err
    assert _mean_se(1.5, float("nan")) == "1.500" and _mean_se(1.5, 0.25) == "1.500 +- 0.250"


def test_a_model_whose_discount_is_zero_names_the_file_and_the_override(tmp_path, capsys):
    text = open(dpomdp_file("dectiger")).read()
    model = tmp_path / "discount0.dpomdp"
    model.write_text(text.replace("discount: 1", "discount: 0", 1))
    args = ["check", "gdice-dpomdp", "--set", f"problem.path={model}"]
    assert cli.main(args) == 2
    err = capsys.readouterr().err
    assert "discount0.dpomdp: its discount line gives 0" in err and "problem.discount" in err
    assert cli.main([*args, "--set", "problem.discount=0.9"]) == 0


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    out = tmp_path_factory.mktemp("h5") / "run"
    assert cli.main(["train", "--out", str(out), *TINY_TRAIN]) == 0
    return out


def test_run_folders_that_lost_a_file_or_come_from_a_newer_version(trained, tmp_path, capsys):
    gone = tmp_path / "gone"
    shutil.copytree(trained, gone)
    (gone / "policy.msgpack").unlink()
    assert cli.main(["evaluate", str(gone)]) == 2
    assert "no policy file there" in capsys.readouterr().err
    newer = tmp_path / "newer"
    shutil.copytree(trained, newer)
    results = json.loads((newer / "results.json").read_text())
    (newer / "results.json").write_text(json.dumps({**results, "schema": 999}))
    assert cli.main(["evaluate", str(newer)]) == 2
    assert "schema 999: this cognet-jax reads results.json schemas" in capsys.readouterr().err


def test_evaluating_in_other_chunks_says_it_is_another_sample(trained, capsys):
    args = ["evaluate", str(trained), "--set", "evaluation.batch=7"]
    assert cli.main(args) == 0
    assert "is another honest sample of the policy" in capsys.readouterr().err


def test_an_out_that_links_to_nowhere_is_named(tmp_path, capsys):
    (tmp_path / "a").symlink_to(tmp_path / "b")
    (tmp_path / "b").symlink_to(tmp_path / "a")
    assert cli.main(["train", "--out", str(tmp_path / "a"), *TINY_TRAIN]) == 2
    assert "a symbolic link that leads nowhere" in capsys.readouterr().err


def test_a_name_two_modules_of_one_command_register_is_named(monkeypatch):
    monkeypatch.setattr(registry, "_ENVS", dict(registry._ENVS))

    def build_a(section, config):
        return None

    def build_b(section, config):
        return None

    build_b.__module__ = "other_module"

    @dataclasses.dataclass
    class Section:
        name: str = "twice-test"

    registry.begin_command()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        registry.register_env("twice-test", Section, build_a)
        registry.register_env("twice-test", Section, build_a)  # its own module again: silent
    with pytest.warns(OneLineWarning, match="'twice-test' registered by .* replaced by the one"):
        registry.register_env("twice-test", Section, build_b)
    registry.begin_command()  # the next command: a new registration replaces it silently
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        registry.register_env("twice-test", Section, build_a)


def test_sixth_round_search_and_controller_returns_are_named():
    """A controller's float actions are refused where the honest evaluation traces them (a
    simulator indexes with them); ``write_plots`` returning no paths is named; an
    observation of no features is refused with the simulator's sizes."""
    from cognet_jax.envs.base import GuardedSteps
    from cognet_jax.errors import UsageError
    from cognet_jax.hook_results import checked_paths

    env = Line()
    state = env.reset(jnp.array([0.1, 0.2]), Params())
    with pytest.raises(UsageError, match="actions are float32, expected integers"):
        GuardedSteps(env).step(jnp.zeros(0), state, jnp.array([0.4, 1.0]), Params())
    with pytest.raises(UsageError, match="expected a list of the paths written"):
        checked_paths(object(), "write_plots", ["a.png", 5])
    with pytest.raises(SimulatorError, match=r"obs_shape \(0,\) must be sizes of at least 1"):
        _check(Line(obs_shape=(0,)))


def test_a_model_of_ten_agents_has_no_exact_value_but_its_run_stands(tmp_path, capsys):
    """The exact value's joint tables grow as nodes ** agents: past ``EXACT_MAX_ENTRIES``
    the record skips it with one line, and the run's honest value is written."""
    model = tmp_path / "agents10.dpomdp"
    model.write_text(
        "agents: 10\ndiscount: 1\nvalues: reward\nstates: 2\nstart: uniform\nactions:\n"
        + "2\n" * 10
        + "observations:\n"
        + "2\n" * 10
        + "T: * :\nuniform\nO: * :\nuniform\nR: * : * : * : * : 1\n"
    )
    out = tmp_path / "run"
    args = ["train", "gdice-dpomdp", "--set", f"problem.path={model}", "--set"]
    args += ["problem.horizon=2", "--set", "algorithm.iterations=2", "--set", "algorithm.nodes=4"]
    args += ["--set", "evaluation.rollouts=100", "--set", "run.plots=false"]
    # few samples and rollouts: the defaults' 1000 x 100 took 53 s of sampling 1024 joint
    # observations at the suite's optimisation level, and the record is the point here
    for size in ("samples=50", "eval_rollouts=10", "best_rollouts=100"):
        args += ["--set", f"algorithm.{size}"]
    assert cli.main([*args, "--out", str(out), "--no-progress"]) == 0
    assert "no exact value of the policy" in capsys.readouterr().err
    assert json.loads((out / "results.json").read_text())["status"] == "complete"


def test_a_simulator_number_whose_square_overflows_float32_is_refused(capsys):
    # noise 3e38 made every observation inf and every value NaN, found only after the search
    args = ["check", "beacon-n5", "--set", "env.obs_noise=3e38"]
    assert cli.main(args) == 2
    err = capsys.readouterr().err
    assert "'env.obs_noise': 3e+38 overflows the simulator's float32 arithmetic" in err
    with pytest.raises(ConfigError, match="env.obs_noise"):
        registry.load_config("beacon-n5", ["env.obs_noise=-2e19"])
    assert registry.load_config("beacon-n5", ["env.obs_noise=1e3"]).env.obs_noise == 1e3
    with pytest.raises(ConfigError, match=r"env.obs_noise.*1e-46 is 0 in the simulator"):
        registry.load_config("beacon-n5", ["env.obs_noise=1e-46"])  # named the model's params


def test_a_diverged_training_names_the_learning_rate(tmp_path, capsys):
    # it blamed a damaged checkpoint or policy file: this run wrote both itself
    out = tmp_path / "run"
    args = ["train", "tagging-thesis-spec-n3", "--set", "network.learning_rate=1e20"]
    args += ["--set", "algorithm.iterations=3", "--set", "run.plots=false", "--out", str(out)]
    assert cli.main([*args, "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "NaN parameters" in err and "network.learning_rate" in err, err
