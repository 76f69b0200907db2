"""A plug-in is one module: an algorithm with its own policy type, controller and figure,
registered from a user's file with nothing in cognet_jax edited, runs through every command."""

import json
import shutil

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cognet_jax import driver
from cognet_jax.cli import main
from cognet_jax.controllers.step import controller_step
from cognet_jax.records import save_group
from cognet_jax.saved_runs import load_run

THRESHOLD_SEARCH = '''
"""A user's search, one module: every agent plays ``low`` below its threshold on the
observation and ``high`` above it (a two-node Moore controller of its own policy type); the
search keeps the best of random draws. Its own figure: thresholds.png."""
import dataclasses
from pathlib import Path

import jax
import jax.numpy as jnp
from flax import struct

import cognet_jax
from cognet_jax.algorithms.cross_entropy import Progress, select_tree
from cognet_jax.algorithms.engine import Search, SearchMetrics, streams
from cognet_jax.config import require_positive


@struct.dataclass
class ThresholdPolicy:
    thresholds: jax.Array  # [agents] float32
    actions: jax.Array  # [agents, 2] int32: the action below and above


@dataclasses.dataclass(frozen=True)
class ThresholdController:
    num_agents: int
    num_nodes: int = 2

    def act(self, u, policy, nodes):
        return policy.actions[jnp.arange(self.num_agents), nodes]

    def next_node(self, u, policy, nodes, obs):
        return (obs > policy.thresholds).astype(jnp.int32)


@dataclasses.dataclass
class ThresholdSection:
    iterations: int = 4
    samples: int = 32
    eval_rollouts: int = 16
    best_rollouts: int = 0
    common_random_numbers: bool = True

    def check(self, config):
        require_positive(self, "algorithm", "iterations", "samples", "eval_rollouts")


@struct.dataclass
class ThresholdState:
    best_policy: ThresholdPolicy
    progress: Progress


@dataclasses.dataclass(frozen=True, eq=False)
class ThresholdSearch(Search):
    def __post_init__(self):
        self._set(controller=ThresholdController(self.env.num_agents))

    def _draw(self, key, num):
        k_t, k_a = jax.random.split(key)
        low, high = self.env.obs_range
        agents = self.env.num_agents
        return ThresholdPolicy(
            thresholds=jax.random.uniform(k_t, (num, agents), minval=low, maxval=high),
            actions=jax.random.randint(k_a, (num, agents, 2), 0, self.env.num_actions),
        )

    def init(self, key, params):
        return ThresholdState(jax.tree.map(lambda x: x[0], self._draw(key, 1)), Progress.create())

    @property
    def rollouts_per_iteration(self):
        return self.settings.samples * self.settings.eval_rollouts

    def ask(self, key, state, params):
        policies = self._draw(streams(key).sample, self.settings.samples)
        return policies, policies

    def tell(self, key, state, samples, values, params, *, fresh_value=None):
        i = jnp.argmax(values)
        progress, improved = state.progress.record(values[i])
        best = select_tree(improved, jax.tree.map(lambda x: x[i], samples), state.best_policy)
        metrics = SearchMetrics(
            value=values[i],
            in_loop_best=progress.in_loop_best,
            mean_value=values.mean(),
        )
        return ThresholdState(best, progress), metrics

    def history_record(self, history):  # its own per-iteration figure in results.json
        return {"mean_value_per_iteration": [float(v) for v in history.mean_value]}

    def write_plots(self, config, policy, record, out_dir):
        from matplotlib.figure import Figure

        fig = Figure(figsize=(3, 2))
        fig.subplots().bar(range(self.env.num_agents), policy.thresholds)
        path = Path(out_dir) / "thresholds.png"
        fig.savefig(path)
        return [path]


def build(config, env, env_params, memory):
    return ThresholdSearch(env, config.algorithm, memory)


cognet_jax.register_algorithm("thresholds", ThresholdSection, build)
cognet_jax.register_policy_type(
    ThresholdPolicy,
    lambda p: ThresholdController(p.thresholds.shape[0]),
    lambda p: p.thresholds.shape[0],
)
'''


def test_an_algorithm_with_its_own_policy_and_figure_runs_through_every_command(
    tmp_path, monkeypatch, capsys
):
    module = tmp_path / "threshold_search.py"
    module.write_text(THRESHOLD_SEARCH)
    toml = tmp_path / "thresholds.toml"
    toml.write_text('[experiment]\nalgorithm = "thresholds"\n[evaluation]\nrollouts = 200\n')
    out = tmp_path / "run"
    imports = ["--import", str(module)]
    train = [*imports, "train", str(toml), "--out", str(out), "--no-progress"]
    first = tmp_path / "checkpoint-at-2.msgpack"  # the checkpoint written mid-run, kept

    def keep_first(program, path, iteration, state, history):
        save_group(program, path, iteration, state, history)
        if iteration == 2:
            shutil.copyfile(path, first)

    monkeypatch.setattr(driver, "save_group", keep_first)
    assert main([*train, "--checkpoint-every", "2"]) == 0
    results = json.loads((out / "results.json").read_text())
    assert len(results["mean_value_per_iteration"]) == 4  # its history_record
    assert results["algorithm"] == "thresholds" and results["status"] == "complete"
    assert (out / "thresholds.png").stat().st_size > 0  # its own figure
    assert (out / "values.png").stat().st_size > 0  # the driver's, for every search
    assert (out / "checkpoint.msgpack").is_file()
    # a search without cross-entropy figures writes none (SearchMetrics' optional fields)
    assert "threshold_per_iteration" not in results and "entropy_injections" not in results
    value = results["final_value"]["mean"]

    assert main([*imports, "evaluate", str(out)]) == 0
    logged = json.loads((out / "evaluations.jsonl").read_text().splitlines()[-1])
    assert logged["mean"] == value

    shutil.copyfile(first, out / "checkpoint.msgpack")  # as if stopped after iteration 2
    capsys.readouterr()
    assert main([*imports, "train", "--resume", str(out), "--no-progress"]) == 0
    assert "at iteration 2/4" in capsys.readouterr().out  # iterations 3 and 4 run again
    again = json.loads((out / "results.json").read_text())
    assert again["final_value"]["mean"] == value  # the checkpoint held the search's own state
    assert again["mean_value_per_iteration"] == results["mean_value_per_iteration"]

    sweep = tmp_path / "sweep"
    args = [*imports, "sweep", str(toml), "--seeds", "2", "--out", str(sweep), "--no-progress"]
    assert main(args) == 0
    rows = json.loads((sweep / "runs.json").read_text())["rows"]
    assert len(rows) == 2 and rows[0]["final_value"]["mean"] == value  # seed 0 is train's
    assert np.isfinite(rows[1]["final_value"]["mean"])

    # the saved policy runs in the user's own loop (controller_step), as the built-in ones do
    policy = load_run(out).policy
    agents = policy.thresholds.shape[0]
    obs = jnp.stack([policy.thresholds - 1.0, policy.thresholds + 1.0])  # [2, agents]
    for below_above, observation in enumerate(obs):
        action, node = controller_step(
            policy, jnp.zeros(agents, jnp.int32), observation, jax.random.key(0)
        )
        np.testing.assert_array_equal(np.asarray(node), np.full(agents, below_above))
        np.testing.assert_array_equal(
            np.asarray(action), np.asarray(policy.actions)[np.arange(agents), below_above]
        )


def test_an_error_in_a_plugin_algorithm_names_its_code(tmp_path, capsys):
    """An algorithm from --import whose ask fails while tracing (a shape mismatch) is the
    user's code: exit 2, one line naming the module, the function, the file and line, and
    JAX's message with the shapes -- not 'internal error'."""
    broken = THRESHOLD_SEARCH.replace(
        "        policies = self._draw(streams(key).sample, self.settings.samples)\n",
        "        policies = self._draw(streams(key).sample, self.settings.samples)\n"
        "        policies = policies.replace(thresholds=policies.thresholds @ jnp.ones((3, 1)))\n",
    )
    assert broken != THRESHOLD_SEARCH
    module = tmp_path / "broken_search.py"
    module.write_text(broken)
    toml = tmp_path / "thresholds.toml"
    toml.write_text('[experiment]\nalgorithm = "thresholds"\n')
    code = main(
        ["--import", str(module), "train", str(toml), "--out", str(tmp_path / "r"), "--no-progress"]
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2, err
    assert len(err) == 1 and "internal error" not in err[0], err
    line = broken.splitlines().index(
        "        policies = policies.replace(thresholds=policies.thresholds @ jnp.ones((3, 1)))"
    )
    assert f"the code of --import {module} failed in ask() at {module}:{line + 1}" in err[0]
    assert "TypeError" in err[0] and "got (2,) and (3,)" in err[0], err[0]


def test_a_build_that_returns_no_search_is_named(tmp_path, capsys):
    """A plug-in's ``build`` that returns something other than a search: ``check`` and
    ``train`` both end in one line naming the algorithm and its build function, exit 2."""
    module = tmp_path / "broken_search.py"
    source = THRESHOLD_SEARCH.replace(
        "    return ThresholdSearch(env, config.algorithm, memory)", "    return None"
    ).replace('register_algorithm("thresholds"', 'register_algorithm("thresholds-none"')
    module.write_text(source)
    toml = tmp_path / "none.toml"
    toml.write_text('[experiment]\nalgorithm = "thresholds-none"\n')
    for command in (["check"], ["train", "--out", str(tmp_path / "run"), "--no-progress"]):
        capsys.readouterr()
        assert main(["--import", str(module), command[0], str(toml), *command[1:]]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "thresholds-none" in err[0], err
        assert "broken_search.build" in err[0] and "not a search" in err[0], err


@pytest.mark.parametrize("count", ["10**30", "-1", "2.5"])
def test_a_rollout_count_past_64_bit_or_no_count_is_refused_before_the_search(
    tmp_path, capsys, count
):
    """A plug-in's ``rollouts_per_iteration`` of 10**30 (or one that is no count): ``train``
    refuses it in one line naming the search's code, before anything runs (it was refused
    after the search, when the results were written)."""
    module = tmp_path / "huge_search.py"
    source = THRESHOLD_SEARCH.replace(
        "        return self.settings.samples * self.settings.eval_rollouts",
        f"        return {count}",
    ).replace('register_algorithm("thresholds"', 'register_algorithm("thresholds-huge"')
    module.write_text(source)
    toml = tmp_path / "huge.toml"
    toml.write_text('[experiment]\nalgorithm = "thresholds-huge"\n')
    out = tmp_path / "run"
    argv = ["--import", str(module), "train", str(toml), "--out", str(out), "--no-progress"]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "ThresholdSearch.rollouts_per_iteration (the search's code)" in err[0]
    assert ("past 64-bit integers" if count == "10**30" else "an integer >= 0") in err[0], err
    assert not (out / "results.json").exists()


#: (code of THRESHOLD_SEARCH, its replacement, what the refusal says): a controller that acts
#: past its agents' actions, and one whose ``next_node`` leads past its ``num_nodes``
OUT_OF_RANGE = {
    "actions": (
        "        return policy.actions[jnp.arange(self.num_agents), nodes]",
        "        return policy.actions[jnp.arange(self.num_agents), nodes] + 5",
        "an action its agent lacks",
    ),
    "nodes": (
        "    def next_node(self, u, policy, nodes, obs):\n        return ",
        "    def next_node(self, u, policy, nodes, obs):\n        return 7 + ",
        "a node its controller lacks",
    ),
}


@pytest.mark.parametrize("kind", sorted(OUT_OF_RANGE))
def test_actions_or_nodes_a_plugin_draws_out_of_range_are_refused(tmp_path, capsys, kind):
    """A plug-in whose controller acts with indices past its agents' actions, or moves past
    its ``num_nodes`` (JAX would clamp the gathers and give a number of another policy): the
    honest evaluation refuses the run in one line."""
    old, new, said = OUT_OF_RANGE[kind]
    assert old in THRESHOLD_SEARCH
    name = f"thresholds-wild-{kind}"
    source = THRESHOLD_SEARCH.replace(old, new).replace(
        'register_algorithm("thresholds"', f'register_algorithm("{name}"'
    )
    module = tmp_path / f"wild_{kind}.py"
    module.write_text(source)
    toml = tmp_path / "wild.toml"
    toml.write_text(f'[experiment]\nalgorithm = "{name}"\n[evaluation]\nrollouts = 200\n')
    capsys.readouterr()
    argv = ["--import", str(module), "train", str(toml), "--out", str(tmp_path / "run")]
    assert main([*argv, "--no-progress"]) == 2
    assert said in capsys.readouterr().err


#: (what the plug-in's hook returns instead, what the refusal names)
BAD_HOOKS = {
    "exact-over-the-honest-value": (
        '    def exact_record(self, config, policy):\n        return {"mean": 999.0}\n',
        "exact_record() (the search's code) returned mean",
    ),
    "history-over-the-seed": (
        '    def history_record(self, history):\n        return {"seed": 77}\n',
        "history_record() (the search's code) returned seed",
    ),
    "history-not-json": (
        '    def history_record(self, history):\n        return {"x": {1, 2}}\n',
        "history_record() (the search's code) returned a value JSON cannot write",
    ),
    "history-not-a-dict": (
        "    def history_record(self, history):\n        return [1]\n",
        "history_record() (the search's code) returned list",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD_HOOKS))
def test_a_record_hook_that_returns_the_drivers_fields_or_no_record_is_named(
    tmp_path, capsys, case
):
    """A plug-in's record hooks add fields to results.json: one that would replace the
    honest value or the seed (evaluate then gave another number), or returns what JSON
    cannot hold, is refused in one line naming the hook, before any results are written."""
    code, says = BAD_HOOKS[case]
    name = f"thresholds-{case}"
    source = THRESHOLD_SEARCH.replace(
        "    def write_plots(self, config, policy, record, out_dir):",
        code + "\n    def write_plots(self, config, policy, record, out_dir):",
    ).replace('register_algorithm("thresholds"', f'register_algorithm("{name}"')
    if case.startswith("history"):  # the hook replaces the module's own history_record
        source = source.replace(
            "    def history_record(self, history):  # its own",
            "    def _own(self, history):  # its own",
        )
    module = tmp_path / f"hook_{case.replace('-', '_')}.py"
    module.write_text(source)
    toml = tmp_path / "thresholds.toml"
    toml.write_text(f'[experiment]\nalgorithm = "{name}"\n[evaluation]\nrollouts = 200\n')
    out = tmp_path / "r"
    argv = ["--import", str(module), "train", str(toml), "--out", str(out), "--no-progress"]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()  # after the compile's progress lines
    assert [line for line in err if line.startswith("error:")] == err[-1:], err
    assert says in err[-1] and "internal error" not in err[-1], err
    assert not (out / "results.json").exists()


@pytest.mark.parametrize(
    "old,new,expected",
    [
        (  # init keeps the draw's batch axis: the honest evaluation cannot run the policy
            "ThresholdState(jax.tree.map(lambda x: x[0], self._draw(key, 1)), Progress.create())",
            "ThresholdState(self._draw(key, 1), Progress.create())",
            "ThresholdSearch.best_policy (the search's code) gives a policy its controller "
            "cannot evaluate",
        ),
        (  # tell hands back a state of another dtype
            "        return ThresholdState(best, progress), metrics",
            "        best = best.replace(thresholds=best.thresholds.astype(jnp.float16))\n"
            "        return ThresholdState(best, progress), metrics",
            "returned a state unlike the one it was given (float32[2] became float16[2])",
        ),
        (  # a NaN of the search's own, on a built-in simulator
            "            value=values[i],",
            "            value=values[i] * jnp.nan,",
            "ThresholdSearch.tell (the search's code) returned a NaN value at iteration 1",
        ),
    ],
)
def test_a_plugin_search_whose_state_policy_or_value_is_wrong_is_named(
    tmp_path, capsys, old, new, expected
):
    """Found before the search (the state and policy, on shapes) or right after it (a NaN
    value), named as the search's code: exit 2, one line, nothing written."""
    assert THRESHOLD_SEARCH.count(old) == 1
    module = tmp_path / "wrong_search.py"
    module.write_text(THRESHOLD_SEARCH.replace(old, new))
    toml = tmp_path / "thresholds.toml"
    toml.write_text('[experiment]\nalgorithm = "thresholds"\n')
    out = tmp_path / "r"
    code = main(["--import", str(module), "train", str(toml), "--out", str(out), "--no-progress"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2, err
    assert expected in err[-1] and "internal error" not in err[-1], err
    assert not (out / "results.json").exists()


def _train_variant(tmp_path, source: str, name: str, out) -> int:
    """``train`` of the threshold search's module ``source`` registered as ``name``."""
    module = tmp_path / f"{name.replace('-', '_')}.py"
    module.write_text(
        source.replace('register_algorithm("thresholds"', f'register_algorithm("{name}"')
    )
    toml = tmp_path / "thresholds.toml"
    toml.write_text(f'[experiment]\nalgorithm = "{name}"\n[evaluation]\nrollouts = 200\n')
    argv = ["--import", str(module), "train", str(toml), "--out", str(out), "--no-progress"]
    return main(argv)


def test_numpy_numbers_and_nan_from_user_code_are_written_as_strict_json(tmp_path):
    """A plug-in's numbers reach results.json as NumPy scalars (a simulator's
    ``numpy.int64`` horizon was the agent-steps count: the search ran, then results.json
    failed and the run was lost) and as NaN (no JSON: jq refuses the file). Both are written:
    the integer as a number, NaN as null."""
    source = THRESHOLD_SEARCH.replace(
        '        return {"mean_value_per_iteration": [float(v) for v in history.mean_value]}',
        "        import numpy\n"
        '        return {"steps": numpy.int64(3), "gap": float("nan"), '
        '"per_agent": numpy.arange(2)}',
    )
    out = tmp_path / "r"
    assert _train_variant(tmp_path, source, "thresholds-numpy", out) == 0
    text = (out / "results.json").read_text()
    record = json.loads(text, parse_constant=lambda c: pytest.fail(f"{c} in results.json"))
    assert (record["steps"], record["gap"], record["per_agent"]) == (3, None, [0, 1])


def test_a_stop_while_a_record_hook_blocks_stops_it(tmp_path):
    """A plug-in's history_record ran inside the section that writes the run folders, where a
    stop only sets a flag: a hook that blocked held SIGTERM for as long as it blocked (119 s
    measured). The hooks now run before that section: the stop ends the command at once and
    keeps the search's best policy as any stop after the search does."""
    import signal
    import subprocess
    import sys
    import time

    marker = tmp_path / "in_hook"
    source = THRESHOLD_SEARCH.replace(
        "    def history_record(self, history):  # its own per-iteration figure in results.json\n",
        "    def history_record(self, history):  # its own per-iteration figure in results.json\n"
        "        import time\n"
        f"        open({str(marker)!r}, 'w').close()\n"
        "        time.sleep(120)\n",
    ).replace('register_algorithm("thresholds"', 'register_algorithm("thresholds-slow"')
    module = tmp_path / "slow_record.py"
    module.write_text(source)
    toml = tmp_path / "thresholds.toml"
    toml.write_text('[experiment]\nalgorithm = "thresholds-slow"\n[evaluation]\nrollouts = 200\n')
    out = tmp_path / "r"
    argv = ["--import", str(module), "train", str(toml), "--out", str(out), "--no-progress"]
    proc = subprocess.Popen(
        [sys.executable, "-m", "cognet_jax", *argv], stderr=subprocess.PIPE, text=True
    )
    try:
        deadline = time.monotonic() + 240
        while not marker.exists() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.2)
        assert marker.exists(), proc.stderr.read() if proc.poll() is not None else "no hook"
        proc.send_signal(signal.SIGTERM)
        t0 = time.monotonic()
        code = proc.wait(timeout=60)
        assert time.monotonic() - t0 < 20
    finally:
        proc.kill()
    err = proc.stderr.read()
    assert code == 128 + signal.SIGTERM, err
    assert "interrupted at iteration 4/4 (SIGTERM)" in err, err
    assert json.loads((out / "results.json").read_text())["status"] == "interrupted"


def test_run_files_named_outside_the_run_folder_are_refused_before_anything_is_written(tmp_path):
    """A plug-in's run_files named ``../x`` was refused after policy.msgpack was written (a
    folder with a policy and no results); now before any file of the run is written."""
    source = THRESHOLD_SEARCH.replace(
        "    def write_plots(self, config, policy, record, out_dir):",
        "    def run_files(self):\n"
        '        return {"../escape.bin": ("algorithm.samples", b"x")}\n\n'
        "    def write_plots(self, config, policy, record, out_dir):",
    )
    out = tmp_path / "r"
    assert _train_variant(tmp_path, source, "thresholds-files", out) == 2
    assert not (out / "policy.msgpack").exists() and not (out / "results.json").exists()
    assert not (tmp_path / "escape.bin").exists()


#: a finish whose step holds a 4 GB array (the iteration a few kilobytes)
HEAVY_FINISH = """
    def finish_start(self, state, params):
        return jnp.float32(0.0)

    def finish_advance(self, work, params):
        return work + jnp.ones((32768, 32768), jnp.float32).sum() * 0.0 + 1.0

    def finish_done(self, work):
        return work >= 1.0

    def history_record(self, history):"""


def test_a_finish_over_the_memory_budget_is_refused_before_the_search(tmp_path, capsys):
    """A search whose ``finish`` step needs more than ``run.memory_gb`` is refused when it is
    compiled, before the first iteration (it was compiled after the search, whose time was
    then lost), and a sweep's group runs in batches when fewer runs side by side fit it."""
    old = "\n    def history_record(self, history):"
    module = tmp_path / "heavy_finish.py"
    module.write_text(
        THRESHOLD_SEARCH.replace(old, HEAVY_FINISH, 1).replace(
            'register_algorithm("thresholds"', 'register_algorithm("thresholds-heavy"'
        )
    )
    toml = tmp_path / "heavy.toml"
    toml.write_text('[experiment]\nalgorithm = "thresholds-heavy"\n[run]\nmemory_gb = 1.0\n')
    out = tmp_path / "run"
    argv = ["--import", str(module), "train", str(toml), "--out", str(out), "--no-progress"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "a finish step needs" in err and "over the memory budget of 1 GB" in err, err
    assert "compiled" not in err  # refused while compiling: no iteration ran
    assert not (out / "results.json").exists() and not (out / "checkpoint.msgpack").exists()
