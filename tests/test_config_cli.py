"""Configuration validation and the command line."""

import json

import pytest
from shared_files import SUITE_EXPERIMENTS

from cognet_jax.cli import main
from cognet_jax.config import ConfigError, builtin_experiments
from cognet_jax.registry import config_from_dict, load_config


@pytest.mark.parametrize(
    "overrides,field",
    [
        (["algorithm.nodes=-3"], "algorithm.nodes"),
        (["algorithm.keep=500"], "algorithm.keep"),
        (["algorithm.top=5000"], "algorithm.top"),
        (["algorithm.nodez=3"], "algorithm.nodez"),
        (["algorithm.nodes=3.5"], "algorithm.nodes"),
        (["algorithm.alpha=1.5"], "algorithm.alpha"),
        (["algorithm.separate=maybe"], "algorithm.separate"),
        (["network.optimizer=rmsprop"], "network.optimizer"),
        (["env.setting=nowhere"], "env.setting"),
        (["env.obs_noise=-0.1"], "env.obs_noise"),
        (["envs.horizon=3"], "envs"),
        (["run.prng_impl=mt19937"], "run.prng_impl"),
    ],
)
def test_bad_values_name_the_field(overrides, field):
    with pytest.raises(ConfigError) as err:
        load_config("tagging-thesis-spec-n3", overrides)
    assert err.value.field == field
    assert field in str(err.value)


def test_overrides_are_typed_and_applied():
    c = load_config(
        "tagging-thesis-spec-n3",
        [
            "algorithm.nodes=6",
            "network.learning_rate=0.5",
            "env.setting=cogdice-paper",
            "algorithm.separate=true",
        ],
    )
    assert c.algorithm.nodes == 6 and c.network.learning_rate == 0.5
    assert c.env.setting == "cogdice-paper" and c.algorithm.separate is True
    thesis = {"experiment": {"algorithm": "cognet-dice-thesis"}}
    typed = config_from_dict({**thesis, "network": {"learning_rate": 1}})
    assert isinstance(typed.network.learning_rate, float)
    # the default cognet-dice has no optimiser: its settings are refused, naming the field
    with pytest.raises(ConfigError) as err:
        config_from_dict({"network": {"learning_rate": 1}})
    assert err.value.field == "network.learning_rate"


def test_builtin_experiments_load():
    names = builtin_experiments()
    for name in [
        "tagging-thesis-spec-n3",
        "tagging-thesis-n6",
        "tagging-separate-n3",
        "tagging-separate-n6",
        "gdice-dpomdp",
    ]:
        assert name in names
    for name in set(names) - set(SUITE_EXPERIMENTS):
        if not name.startswith("gdice-dpomdp"):  # needs problem.path
            load_config(name)


def test_toml_file_experiment(tmp_path):
    path = tmp_path / "mine.toml"
    path.write_text("[algorithm]\nnodes = 4\n[network]\nhidden = 7\n")
    c = load_config(str(path))
    assert c.algorithm.nodes == 4 and c.network.hidden == 7 and c.experiment.name == "mine"
    bad = tmp_path / "bad.toml"
    bad.write_text("[algorithm\nnodes = 4\n")
    with pytest.raises(ConfigError, match="invalid TOML"):
        load_config(str(bad))


def test_cli_reports_config_errors(capsys):
    assert main(["train", "--set", "algorithm.elites=0"]) == 2
    assert "algorithm.elites" in capsys.readouterr().err
    assert main(["train", "tagging-thesis-spec-n3", "--set", "algorithm.keep=0"]) == 2
    assert "algorithm.keep" in capsys.readouterr().err
    assert main(["train", "no-such-experiment"]) == 2
    assert "unknown experiment" in capsys.readouterr().err


def test_cli_train_and_evaluate(tmp_path, capsys):
    out = tmp_path / "run"
    small = [
        "--set",
        "algorithm.iterations=3",
        "--set",
        "algorithm.candidates=10",
        "--set",
        "algorithm.elites=3",
        "--set",
        "algorithm.eval_rollouts=10",
        "--set",
        "algorithm.best_rollouts=20",
        "--set",
        "evaluation.rollouts=200",
    ]
    # the default experiment: the default cognet-dice
    assert main(["train", "--out", str(out), "--no-progress", *small]) == 0
    for name in [
        "results.json",
        "policy.msgpack",
        "values.png",
        "actions.png",
        "node_responses.png",
        "controllers.png",
    ]:
        assert (out / name).stat().st_size > 0, name
    assert main(["evaluate", str(out), "--rollouts", "300", "--set", "env.obs_noise=0.5"]) == 0
    line = json.loads((out / "evaluations.jsonl").read_text().splitlines()[-1])
    assert line["rollouts"] == 300 and line["overrides"] == ["env.obs_noise=0.5"]
    assert "value" in capsys.readouterr().out
    assert "no_effect" not in line  # the noise is the simulator's: it is applied
    # a search's field changes nothing evaluate reads: said, not shown as applied
    sets = ["--set", "algorithm.iterations=9", "--set", "env.obs_noise=0.5"]
    assert main(["evaluate", str(out), "--rollouts", "300", *sets]) == 0
    said = capsys.readouterr()
    assert "warning: --set algorithm.iterations=9 changes nothing" in said.err
    assert said.out.startswith("value ") and "iterations" not in said.out.splitlines()[0]
    assert f"{line['mean']:.3f}" in said.out  # the same value as with the noise alone
    logged = json.loads((out / "evaluations.jsonl").read_text().splitlines()[-1])
    assert logged["no_effect"] == ["algorithm.iterations=9"]
    # the simulator's field at the run's own value: said as such, not as a search's field
    assert main(["evaluate", str(out), "--rollouts", "300", "--set", "env.obs_noise=0.0"]) == 0
    said = capsys.readouterr().err
    assert "--set env.obs_noise=0.0 gives the run's own value" in said, said
    assert "changes nothing an evaluation reads" not in said
    # another generator: another sample of the policy, said so
    assert main(["evaluate", str(out), "--rollouts", "300", "--set", "run.prng_impl=rbg"]) == 0
    assert "run.prng_impl rbg where the run had threefry2x32" in capsys.readouterr().err
    sets = ["--set", "experiment.algorithm=cogdice"]  # was "unknown key algorithm.<field>"
    assert main(["evaluate", str(out), *sets]) == 2
    assert "another algorithm cannot evaluate it" in capsys.readouterr().err
    assert main(["evaluate", str(tmp_path / "missing")]) == 2


@pytest.mark.parametrize("experiment", ["tagging-paper-cogdice", "tagging-paper-gdice-d1"])
def test_best_rollouts_must_not_be_negative(experiment):
    with pytest.raises(ConfigError) as err:
        load_config(experiment, ["algorithm.best_rollouts=-1"])
    assert err.value.field == "algorithm.best_rollouts"
