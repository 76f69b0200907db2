"""Registries (``cognet_jax.registry``): built-in names, ``make_env`` / ``make_algorithm`` with
validation, a user-written simulator registered in one call and planned (the README example,
run as written), config files that name it."""

import dataclasses
import re
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from shared_files import dpomdp_file

import cognet_jax
from cognet_jax.config import ConfigError, config_from_dict


def test_builtin_names():
    assert {"tagging", "heatmap", "dpomdp"} <= set(cognet_jax.list_envs())
    assert {"cognet-dice", "cognet-dice-thesis", "gdice", "cogdice"} <= set(
        cognet_jax.list_algorithms()
    )


def test_make_env_validates_like_a_config_file():
    env, params = cognet_jax.make_env("tagging", setting="cogdice-paper", obs_noise=0.1)
    assert env.horizon == 150 and float(params.obs_noise) == pytest.approx(0.1)
    with pytest.raises(ConfigError, match=r"env.bogus.*unknown setting of 'tagging'"):
        cognet_jax.make_env("tagging", bogus=1)
    with pytest.raises(ConfigError, match=r"env.obs_noise.*>= 0"):
        cognet_jax.make_env("tagging", obs_noise=-1.0)
    with pytest.raises(ConfigError, match=r"env.name.*unknown environment 'nope'"):
        cognet_jax.make_env("nope")
    with pytest.raises(ConfigError, match=r"experiment.algorithm.*unknown algorithm"):
        cognet_jax.make_algorithm("nope", env, params)


def test_make_algorithm_settings_and_errors():
    env, params = cognet_jax.make_env("tagging")
    algo = cognet_jax.make_algorithm("cogdice", env, params, samples=50, elites=5)
    assert (algo.settings.samples, algo.settings.elites) == (50, 5)
    with pytest.raises(ConfigError, match=r"algorithm.elites"):
        cognet_jax.make_algorithm("cogdice", env, params, samples=5, elites=50)
    # G-DICE on a continuous simulator object: refused on env.name, not deep inside JAX
    with pytest.raises(ConfigError, match=r"env.name.*G-DICE needs discrete observations"):
        cognet_jax.make_algorithm("gdice", env, params)


def test_fields_from_refuses_an_undeclared_setting():
    from cognet_jax.registry import fields_from

    @dataclasses.dataclass
    class Wanted:
        nodes: int = 1
        not_in_config: int = 0

    @dataclasses.dataclass
    class Section:
        nodes: int = 4

    assert fields_from(Wanted, Section(), not_in_config=2) == Wanted(4, 2)
    with pytest.raises(TypeError, match="not_in_config"):
        fields_from(Wanted, Section())


def _readme_block(title: str) -> str:
    text = (Path(__file__).parents[1] / "README.md").read_text()
    section = text.split(title, 1)[1]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


@pytest.fixture(scope="module")
def seek():
    """The README's user-written simulator, registered and planned as written."""
    namespace: dict = {}
    exec(compile(_readme_block("### Your own simulator"), "README.md", "exec"), namespace)
    return namespace


def test_readme_user_simulator_is_planned(seek):
    from cognet_jax.controllers.regions import DeterministicRegionPolicy

    algo, env, params = seek["algo"], seek["env"], seek["params"]
    # baseline: every agent stays where it starts (only a start near the goal pays)
    stay = DeterministicRegionPolicy(
        actions=jnp.ones((2, 3), jnp.int32),
        points=jnp.tile(jnp.array([-1.0, 1.0]), (2, 3, 1)),
        transitions=jnp.zeros((2, 3, 3), jnp.int32),
    )
    stay_value = float(algo.policy_returns(jax.random.key(2), stay, 10_000).mean())
    value = float(seek["value"])
    assert value > stay_value + 2.0 and value > 0, (value, stay_value)
    # the found controller runs through controller_step on the simulator's observations
    state = env.reset(jnp.array([0.1, 0.9, 0.5]), params)
    action, node = cognet_jax.controller_step(
        seek["policy"], jnp.zeros(2, jnp.int32), None, jax.random.key(0)
    )
    state, obs, _ = env.step(jnp.zeros(2), state, action, params)
    action, node = cognet_jax.controller_step(seek["policy"], node, obs, jax.random.key(1))
    assert action.shape == node.shape == (2,)


def test_registered_simulator_in_a_config_file(seek, tmp_path):
    config = config_from_dict(
        {
            "experiment": {"algorithm": "cogdice"},
            "env": {"name": "seek", "noise": 0.0},
            "algorithm": {"samples": 20, "elites": 2, "eval_rollouts": 5, "iterations": 2},
        }
    )
    algo = cognet_jax.build_algorithm(config)
    assert float(algo.env_params.noise) == 0.0
    state, metrics = jax.jit(algo.step)(jax.random.key(0), algo.init(jax.random.key(1)))
    assert np.isfinite(float(metrics.value))
    with pytest.raises(ConfigError, match=r"env.noise"):
        config_from_dict({"env": {"name": "seek", "noise": "loud"}})


def test_make_env_for_gdice_and_tabular_files():
    env, _ = cognet_jax.make_env("tagging", algorithm="gdice", obs_division=2.0)
    assert env.obs_index and env.num_obs == 11
    algo = cognet_jax.make_algorithm("gdice", env, _, samples=20, elites=2, nodes=3)
    assert algo.controller.num_obs == 11
    dpomdp = dpomdp_file("dectiger")
    env, params = cognet_jax.make_env("dpomdp", path=str(dpomdp), horizon=4)
    assert (env.num_states, env.horizon) == (2, 4)
    with pytest.raises(ConfigError, match=r"problem.horizon"):
        cognet_jax.make_env("dpomdp", path=str(dpomdp), horizon=0)


def test_references_come_from_the_registry():
    from cognet_jax.config import load_config
    from cognet_jax.reporting import references_for

    assert references_for(load_config("heatmap-2d-spec-n4", ['env.start="thesis"']))[
        "random actions"
    ] == pytest.approx(19.37)
    assert references_for(load_config("tagging-paper-cogdice"))["COG-DICE (paper)"] == 101.8


def test_builtin_registration_does_not_replace_a_user_entry():
    from cognet_jax import registry

    saved = dict(registry._ENVS)
    try:
        registry._ENVS.pop("heatmap", None)

        @dataclasses.dataclass
        class Mine:
            name: str = "heatmap"

        registry.register_env("heatmap", Mine, lambda s, c: None)
        import cognet_jax.envs.heatmap as heatmap_module

        heatmap_module._register()  # what importing the module runs
        assert registry.env_entry("heatmap").section is Mine
    finally:
        registry._ENVS.clear()
        registry._ENVS.update(saved)


PLUGIN = '''
import dataclasses

import jax.numpy as jnp
from flax import struct

import cognet_jax


@struct.dataclass
class LineParams:
    discount: float = 1.0


@dataclasses.dataclass(frozen=True)
class Line:
    """One agent on [0, 4]: stay (0) or step right (1); +1 per step at the goal 3 or beyond."""

    horizon: int = 6
    num_agents: int = 1
    num_actions: int = 2
    action_counts: tuple = (2,)
    obs_shape: tuple = ()
    num_obs: None = None
    obs_range: tuple = (-4.0, 4.0)
    reset_noise: int = 1
    step_noise: int = 0

    def reset(self, u, params):
        return jnp.zeros(1)

    def step(self, u, state, actions, params):
        pos = jnp.minimum(state + actions, 4.0)
        return pos, 3.0 - pos, jnp.sum(jnp.where(pos >= 3.0, 1.0, 0.0))


@dataclasses.dataclass
class LineSection:
    name: str = "line"


cognet_jax.register_env("line", LineSection, lambda s, c: (Line(), LineParams()))
'''


def test_cli_imports_a_plugin_that_registers_a_simulator(tmp_path, capsys):
    import json

    from cognet_jax.cli import main

    plugin = tmp_path / "line_plugin.py"
    plugin.write_text(PLUGIN)
    toml = tmp_path / "line.toml"
    toml.write_text(
        '[experiment]\nalgorithm = "cogdice"\n[env]\nname = "line"\n'
        "[algorithm]\nnodes = 2\nregions = 2\niterations = 15\nsamples = 60\nelites = 6\n"
        "eval_rollouts = 2\n[evaluation]\nrollouts = 100\n[run]\nplots = false\n"
    )
    out = tmp_path / "run"
    rc = main(["train", str(toml), "--import", str(plugin), "--out", str(out), "--no-progress"])
    assert rc == 0
    results = json.loads((out / "results.json").read_text())
    # stepping right three times, then staying anywhere: 4 of 6 steps at the goal
    assert results["final_value"]["mean"] == pytest.approx(4.0)
    assert main(["evaluate", str(out), "--import", str(plugin), "--rollouts", "50"]) == 0
    capsys.readouterr()
    assert main(["train", str(toml), "--import", str(tmp_path / "missing.py")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--import" in err[0] and "missing.py" in err[0]


def test_readme_states_the_user_simulator_module_size():
    """The README's line count of the user simulator (up to its registration) is the block's."""
    text = (Path(__file__).parents[1] / "README.md").read_text()
    stated = int(re.search(r"with its registration, is (\d+) lines in one module", text).group(1))
    block = _readme_block("### Your own simulator")
    upto = block[: block.index("\n", block.index("register_env("))]
    assert stated == len(upto.splitlines())
