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
from cognet_jax.config import ConfigError
from cognet_jax.registry import config_from_dict


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
    with pytest.raises(ConfigError, match=r"env.name.*unknown environment 'nope'.*--import"):
        cognet_jax.make_env("nope")
    with pytest.raises(ConfigError, match=r"experiment.algorithm.*unknown algorithm"):
        cognet_jax.make_algorithm("nope", env, params)


def test_make_algorithm_settings_and_errors():
    env, params = cognet_jax.make_env("tagging")
    algo, search_params = cognet_jax.make_algorithm("cogdice", env, params, samples=50, elites=5)
    assert (algo.settings.samples, algo.settings.elites) == (50, 5)
    assert search_params.env is params and float(search_params.hyper.alpha) == 0.1
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

    env, params, search = seek["env"], seek["params"], seek["search"]
    # baseline: every agent stays where it starts (only a start near the goal pays)
    stay = DeterministicRegionPolicy(
        actions=jnp.ones((2, 3), jnp.int32),
        points=jnp.tile(jnp.array([-1.0, 1.0]), (2, 3, 1)),
        transitions=jnp.zeros((2, 3, 3), jnp.int32),
    )
    stay_value = float(seek["returns"](jax.random.key(2), stay, 10_000, search).mean())
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
    algo, params = cognet_jax.build_algorithm(config)
    assert float(params.env.noise) == 0.0
    state = algo.init(jax.random.key(1), params)
    state, metrics = jax.jit(algo.step)(jax.random.key(0), state, params)
    assert np.isfinite(float(metrics.value))
    with pytest.raises(ConfigError, match=r"env.noise"):
        config_from_dict({"env": {"name": "seek", "noise": "loud"}})


def test_make_env_for_gdice_and_tabular_files():
    env, _ = cognet_jax.make_env("tagging", algorithm="gdice", obs_division=2.0)
    assert env.obs_index and env.num_obs == 11
    algo, _ = cognet_jax.make_algorithm("gdice", env, _, samples=20, elites=2, nodes=3)
    assert algo.controller.num_obs == 11
    dpomdp = dpomdp_file("dectiger")
    env, params = cognet_jax.make_env("dpomdp", path=str(dpomdp), horizon=4)
    assert (env.num_states, env.horizon) == (2, 4)
    with pytest.raises(ConfigError, match=r"problem.horizon"):
        cognet_jax.make_env("dpomdp", path=str(dpomdp), horizon=0)


def test_references_come_from_the_registry():
    from cognet_jax.registry import load_config
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

        # what importing the module runs
        registry.register_env(
            "heatmap",
            heatmap_module.HeatmapSection,
            heatmap_module.build_from_section,
            overwrite=False,
        )
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


def test_a_step_that_calls_back_into_python_is_named_before_compiling(tmp_path, capsys):
    """``jax.debug.print`` in a user's step: refused in one line before anything compiles (it
    would make every step of every rollout print); a ``jax.pure_callback``: one warning; one
    that cannot run under ``vmap``: refused as the simulator's error."""
    from cognet_jax.cli import main

    step = "        pos = jnp.minimum(state + actions, 4.0)\n"
    calls = {
        "debug": "        jax.debug.print('pos {}', pos)\n",
        "pure": "        pos = jax.pure_callback(lambda p: p, jax.ShapeDtypeStruct((1,), "
        "jnp.float32), pos, vmap_method='sequential')\n",
        "unbatched": "        pos = jax.pure_callback(lambda p: p, jax.ShapeDtypeStruct((1,), "
        "jnp.float32), pos)\n",
    }
    for kind, call in calls.items():
        name = f"{kind}-line"
        plugin = tmp_path / f"{kind}_plugin.py"
        code = PLUGIN.replace('"line"', f'"{name}"').replace(step, step + call)
        plugin.write_text("import jax\n" + code)
        toml = tmp_path / f"{kind}.toml"
        toml.write_text(
            f'[experiment]\nalgorithm = "cogdice"\n[env]\nname = "{name}"\n'
            "[algorithm]\nnodes = 2\nregions = 2\niterations = 2\nsamples = 4\n"
            "elites = 2\neval_rollouts = 2\n[evaluation]\nrollouts = 10\n"
        )
        rc = main(["--import", str(plugin), "check", str(toml)])
        err = capsys.readouterr().err.strip().splitlines()
        if kind == "debug":
            assert rc == 2 and len(err) == 1, err
            assert "jax.debug.print" in err[0] and name in err[0] and "remove it" in err[0]
        elif kind == "pure":
            warned = [line for line in err if line.startswith("warning:")]
            assert rc == 0 and len(warned) == 1, err
            assert "pure_callback" in warned[0] and name in warned[0]
        else:  # the user's error under vmap, named as the simulator's, not an internal one
            errors = [line for line in err if line.startswith("error:")]
            assert rc == 2 and len(errors) == 1, err
            assert name in errors[0] and "under jax.vmap raised" in errors[0]


TOY_ALGORITHM = '''
"""A toy search, registered by a user: keep the best of uniformly random region controllers.
One module and one register call; nothing in cognet_jax is edited."""
import dataclasses

import jax
import jax.numpy as jnp
from flax import struct

import cognet_jax
from cognet_jax.algorithms.cross_entropy import Progress, select_tree
from cognet_jax.algorithms.engine import Search, SearchMetrics, streams
from cognet_jax.config import require, require_positive
from cognet_jax.controllers.regions import DeterministicRegionPolicy, RegionController


@dataclasses.dataclass
class RandomSection:
    nodes: int = 2
    iterations: int = 4
    samples: int = 20
    eval_rollouts: int = 8
    best_rollouts: int = 0
    common_random_numbers: bool = True

    def check(self, config):
        require_positive(self, "algorithm", "nodes", "iterations", "samples", "eval_rollouts")
        require(self.samples <= 10_000, "algorithm.samples", "a toy: at most 10000")


@struct.dataclass
class RandomState:
    best_policy: DeterministicRegionPolicy
    progress: Progress


@dataclasses.dataclass(frozen=True, eq=False)
class RandomRegions(Search):
    def __post_init__(self):
        env = self.env
        self._set(controller=RegionController(env.num_agents, self.settings.nodes, 2))

    def _draw(self, key, num):
        a, n = self.env.num_agents, self.settings.nodes
        k_a, k_p, k_t = jax.random.split(key, 3)
        low, high = self.env.obs_range
        return DeterministicRegionPolicy(
            actions=jax.random.randint(k_a, (num, a, n), 0, self.env.num_actions),
            points=jax.random.uniform(k_p, (num, a, n, 1), minval=low, maxval=high),
            transitions=jax.random.randint(k_t, (num, a, n, 2), 0, n),
        )

    def init(self, key, params):
        first = jax.tree.map(lambda x: x[0], self._draw(key, 1))
        return RandomState(first, Progress.create())

    @property
    def rollouts_per_iteration(self):
        return self.settings.samples * self.settings.eval_rollouts

    def ask(self, key, state, params):
        policies = self._draw(streams(key).sample, self.settings.samples)
        return policies, policies

    def tell(self, key, state, samples, values, params, *, fresh_value=None):
        i = jnp.argmax(values)
        progress, improved = state.progress.record(values[i])
        winner = jax.tree.map(lambda x: x[i], samples)
        best = select_tree(improved, winner, state.best_policy)
        metrics = SearchMetrics(
            value=values[i],
            in_loop_best=progress.in_loop_best,
            mean_value=values.mean(),
            threshold=values[i],
            kept=jnp.int32(1),
            injected=jnp.bool_(False),
        )
        return RandomState(best, progress), metrics


def build(config, env, env_params, memory):
    return RandomRegions(env, config.algorithm, memory)


cognet_jax.register_algorithm("random-regions", RandomSection, build)
'''


def test_a_toy_algorithm_is_one_module_and_one_register_call(tmp_path, capsys):
    """A user's algorithm, registered from its own module: its section validates itself, the
    command line trains it through the driver, ``evaluate`` reproduces its value, and
    ``make_train`` returns the policy the command line wrote."""
    import json

    from cognet_jax.cli import main

    module = tmp_path / "toy_search.py"
    module.write_text(TOY_ALGORITHM)
    toml = tmp_path / "toy.toml"
    toml.write_text(
        '[experiment]\nalgorithm = "random-regions"\n[algorithm]\nsamples = 40\n'
        "[evaluation]\nrollouts = 300\n[run]\nplots = false\n"
    )
    out = tmp_path / "run"
    args = ["train", str(toml), "--import", str(module), "--out", str(out), "--no-progress"]
    assert main(args) == 0
    results = json.loads((out / "results.json").read_text())
    assert results["algorithm"] == "random-regions" and results["iterations"] == 4
    assert results["final_value"]["mean"] > -30  # better than always tagging (-40 per step)
    assert main(["evaluate", str(out), "--import", str(module)]) == 0
    logged = json.loads((out / "evaluations.jsonl").read_text().splitlines()[-1])
    assert logged["mean"] == results["final_value"]["mean"]
    # the section checks itself, naming the field (the module is imported in this process)
    assert main(["train", str(toml), "--import", str(module), "--set", "algorithm.samples=0"]) == 2
    assert "algorithm.samples" in capsys.readouterr().err
    config = cognet_jax.load_config(str(toml), ["run.progress=false"])
    state, _ = jax.jit(cognet_jax.make_train(config))(cognet_jax.seed_key(config, 0))
    saved = json.loads((out / "results.json").read_text())["seed"]
    assert saved == 0
    from flax.serialization import msgpack_restore

    raw = msgpack_restore((out / "policy.msgpack").read_bytes())
    leaves = jax.tree.leaves(msgpack_restore(raw["policy"]))
    for a, b in zip(jax.tree.leaves(state.best_policy), leaves, strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    # nothing in config.py or api.py names it
    package = Path(cognet_jax.__file__).parent
    for name in ("config.py", "api.py"):
        assert "random-regions" not in (package / name).read_text()
