"""Build once: every command builds its simulator once and checks a run's budget once
(``api.build``), and every public name of the package resolves."""

import dataclasses

import pytest

import cognet_jax
from cognet_jax import api, registry
from cognet_jax.cli import main
from tests.shared_files import TINY_TRAIN


@pytest.fixture
def counts(monkeypatch):
    """Counters of the tagging simulator's builds, of the simulator checks it went through
    (``check_simulator`` past its cache) and of budget checks, from a clean slate."""
    from cognet_jax.envs import base

    seen = {"builds": 0, "checks": 0, "traced": 0}
    original_sizes = base._check_sizes

    def counting_sizes(env, owner):
        seen["traced"] += 1
        return original_sizes(env, owner)

    monkeypatch.setattr(base, "_check_sizes", counting_sizes)
    monkeypatch.setattr(base, "_CHECKED", {})
    entry = registry.env_entry("tagging")
    original_build, original_check = entry.build, api.check_budget

    def counting_build(section, config):
        seen["builds"] += 1
        return original_build(section, config)

    counting_build.__module__ = original_build.__module__  # still the built-in simulator

    def counting_check(config, env):
        seen["checks"] += 1
        return original_check(config, env)

    monkeypatch.setitem(registry._ENVS, "tagging", dataclasses.replace(entry, build=counting_build))
    monkeypatch.setattr(api, "check_budget", counting_check)
    monkeypatch.setattr(registry, "_BUILT_ENVS", {})

    def reset():
        registry._BUILT_ENVS.clear()
        base._CHECKED.clear()
        seen.update(builds=0, checks=0, traced=0)
        return seen

    return reset


def test_every_command_builds_its_simulator_once_and_checks_its_budget_once(counts, tmp_path):
    out = tmp_path / "run"
    seen = counts()
    assert main(["train", "tagging-thesis-n3", "--out", str(out), *TINY_TRAIN]) == 0
    assert seen == {"builds": 1, "checks": 1, "traced": 1}

    seen = counts()
    assert main(["check", "tagging-thesis-n3"]) == 0
    assert seen == {"builds": 1, "checks": 1, "traced": 1}

    seen = counts()
    assert main(["evaluate", str(out), "--rollouts", "64"]) == 0
    assert seen == {"builds": 1, "checks": 1, "traced": 1}

    seen = counts()
    sweep = ["sweep", "tagging-thesis-n3", "--seeds", "2", "--out", str(tmp_path / "sweep")]
    assert main([*sweep, *TINY_TRAIN]) == 0
    assert seen == {"builds": 1, "checks": 1, "traced": 1}  # one group of two runs: one build

    seen = counts()
    config = cognet_jax.load_config("tagging-thesis-n3", ["algorithm.iterations=2"])
    cognet_jax.make_train(config)
    assert seen == {"builds": 1, "checks": 1, "traced": 1}

    seen = counts()  # a library user builds once and hands the run to both makers
    built = cognet_jax.build(config)
    cognet_jax.make_train(built)
    cognet_jax.make_evaluate(built)
    sets = [s for s in TINY_TRAIN if "=" in s]  # the --set values
    tiny = cognet_jax.build(cognet_jax.load_config("tagging-thesis-n3", sets))
    assert seen == {"builds": 1, "checks": 2, "traced": 1}  # the same simulator, another run
    cognet_jax.train(tiny, 0, tmp_path / "library-run", progress=False, log=lambda line: None)
    assert seen == {"builds": 1, "checks": 2, "traced": 1}  # train took the run as built


def test_evaluate_checks_the_rollouts_it_was_given(counts, tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["train", "tagging-thesis-n3", "--out", str(out), *TINY_TRAIN]) == 0
    capsys.readouterr()
    small = ["--set", "run.memory_gb=0.001"]  # 1e6 returns need 4 MB
    assert main(["evaluate", str(out), "--rollouts", "1000000", *small]) == 2
    assert "evaluation.rollouts" in capsys.readouterr().err
    # a large evaluation says its size and least time before it compiles (h 3, 2 agents)
    assert main(["evaluate", str(out), "--rollouts", "1000000"]) == 0
    assert "1000000 rollouts, 6e+06 agent-steps, at least" in capsys.readouterr().err


def test_every_public_name_resolves():
    for name in cognet_jax.__all__:
        assert getattr(cognet_jax, name) is not None, name
