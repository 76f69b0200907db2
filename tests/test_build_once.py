"""Build once: every command builds its simulator once and checks a run's budget once
(``api.build``), and every public name of the package resolves."""

import dataclasses
import json

import pytest

import cognet_jax
from cognet_jax import api, registry
from cognet_jax.cli import main
from cognet_jax.config import apply_overrides
from cognet_jax.errors import MismatchError, UsageError
from cognet_jax.sweep import read_spec, run_sweep
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


def test_a_library_sweep_and_its_evaluations_take_the_run_as_built(counts, tmp_path):
    sets = [s for s in TINY_TRAIN if "=" in s]
    config = cognet_jax.load_config("tagging-thesis-n3", sets)
    seen = counts()
    built = cognet_jax.build(config, lanes=2)  # two seeds side by side share the memory
    assert seen == {"builds": 1, "checks": 1, "traced": 1}
    out = tmp_path / "sweep"
    result = cognet_jax.run_sweep(built, [0, 1], out=out, log=lambda *a: None)
    assert seen == {"builds": 1, "checks": 1, "traced": 1}  # the sweep built nothing again
    for row in result["rows"]:  # every folder evaluated with the one build, to its own value
        folder = out / "runs" / f"setting0-seed{row['seed']}"
        value = cognet_jax.evaluate_run(folder, built=built)
        assert value["mean"] == pytest.approx(row["final_value"]["mean"], rel=1e-5)
    assert seen == {"builds": 1, "checks": 1, "traced": 1}
    # the same sweep from the command line (which builds its own run) gives the same values
    cli = tmp_path / "cli"
    assert main(["sweep", "tagging-thesis-n3", "--seeds", "2", "--out", str(cli), *TINY_TRAIN]) == 0
    again = json.loads((cli / "runs.json").read_text())["rows"]
    assert [r["final_value"]["mean"] for r in again] == [
        r["final_value"]["mean"] for r in result["rows"]
    ]
    with pytest.raises(UsageError, match="no grid"):
        cognet_jax.run_sweep(built, [0], grid={"algorithm.alpha": [0.1, 0.2]})


def test_evaluate_refuses_a_built_run_of_another_config(tmp_path):
    out = tmp_path / "run"
    assert main(["train", "tagging-thesis-n3", "--out", str(out), *TINY_TRAIN]) == 0
    sets = [s for s in TINY_TRAIN if "=" in s]
    other = cognet_jax.build(
        cognet_jax.load_config("tagging-thesis-n3", [*sets, "env.obs_noise=0.3"])
    )
    with pytest.raises(MismatchError, match=r"env\.obs_noise \(0\.3"):
        cognet_jax.evaluate_run(out, built=other)
    # the same change given as an override is the run under another noise: accepted
    value = cognet_jax.evaluate_run(out, overrides=["env.obs_noise=0.3"], built=other)
    assert value["overrides"] == ["env.obs_noise=0.3"]


def test_a_sweep_of_a_config_resumes_from_that_config(tmp_path):
    config = cognet_jax.load_config("tagging-thesis-n3", [s for s in TINY_TRAIN if "=" in s])
    changed = cognet_jax.config_from_dict(
        apply_overrides(config.to_dict(), ["algorithm.alpha=0.35"])
    )  # not the built-in experiment's alpha: only the saved config has it
    out = tmp_path / "sweep"
    result = run_sweep(changed, [3], out=out, log=lambda *a: None)
    spec = read_spec(out)
    assert spec["experiment"] == changed and result["experiment"] == "tagging-thesis-n3"
    assert result["config"]["algorithm"]["alpha"] == 0.35


def test_evaluate_checks_the_rollouts_it_was_given(counts, tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["train", "tagging-thesis-n3", "--out", str(out), *TINY_TRAIN]) == 0
    capsys.readouterr()
    small = ["--set", "run.memory_gb=0.01"]  # 1e6 returns need 20 MB
    assert main(["evaluate", str(out), "--rollouts", "1000000", *small]) == 2
    assert "evaluation.rollouts" in capsys.readouterr().err
    # a large evaluation says its size and least time before it compiles (h 3, 2 agents)
    assert main(["evaluate", str(out), "--rollouts", "1000000"]) == 0
    assert "1000000 rollouts, 6e+06 agent-steps, at least" in capsys.readouterr().err


def test_every_public_name_resolves():
    for name in cognet_jax.__all__:
        assert getattr(cognet_jax, name) is not None, name
