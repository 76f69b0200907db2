"""Inputs of the seventh hostile round (issue 53): a user simulator with no agents or with
discrete observations outside its ``num_obs``, an experiment name too long for a folder, a
sweep's state naming no experiment, a controller figure of a million observations and an
``--import`` file given by a path that starts with ``..``."""

from __future__ import annotations

import dataclasses
import gzip
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


def test_a_file_name_too_long_to_name_the_experiment_says_the_file_named_it(tmp_path):
    toml = tmp_path / ("y" * 245 + ".toml")
    toml.write_text('[env]\nname = "tagging"\n')
    with pytest.raises(ConfigError, match="sets no experiment.name, so its file name gives it"):
        load_config(str(toml))
    assert load_config(str(toml), ["experiment.name=short"]).experiment.name == "short"


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
    import inspect
    import sys

    from cognet_jax.errors import UsageError
    from cognet_jax.plugins import import_plugin

    low = len(inspect.stack()) + 40  # above the depth the import runs at (xdist: deeper)
    module = tmp_path / "shallow.py"
    module.write_text(f"import sys\nsys.setrecursionlimit({low})\n")
    limit = sys.getrecursionlimit()
    with pytest.raises(UsageError, match=f"lowered Python's recursion limit to {low}"):
        import_plugin(str(module))
    assert sys.getrecursionlimit() == limit  # given back: the error is reported, not hit


def test_a_stop_while_the_figures_are_drawn_ends_them_with_the_results_written(
    tmp_path, monkeypatch, capsys
):
    """The figures come after the results, outside the deferred stop that guards writing
    them: a SIGTERM while a figure is drawn (a huge one took minutes) ends the command at
    once, status 143, one line, the run's results.json and policy complete."""
    import os
    import signal
    import time

    from shared_files import TINY_TRAIN

    from cognet_jax import records
    from cognet_jax.signals import install_stop_handlers

    def slow_figures(*args):
        os.kill(os.getpid(), signal.SIGTERM)  # the stop handler raises here
        time.sleep(30)

    monkeypatch.setattr(records, "write_plots", slow_figures)
    out = tmp_path / "run"
    previous = signal.getsignal(signal.SIGTERM)
    install_stop_handlers()
    t0 = time.monotonic()
    try:
        code = cli.main(["train", *TINY_TRAIN, "--set", "run.plots=true", "--out", str(out)])
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert time.monotonic() - t0 < 25
    assert code == 128 + signal.SIGTERM
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == "error: stopped by SIGTERM after the results were written", err
    results = json.loads((out / "results.json").read_text())
    assert results["status"] == "complete" and (out / "policy.msgpack").is_file()


def test_a_run_on_a_relative_model_path_is_evaluated_from_elsewhere_with_the_same_file(
    tmp_path, monkeypatch, capsys
):
    """A run trained on ``problem.path=dp/x.dpomdp`` (relative to where train ran): from
    another folder ``evaluate`` names the cause in one line, takes the same bytes under
    another path (``--set problem.path``, checked by the policy's model digest) and refuses
    another model."""
    from shared_files import dpomdp_file

    source = dpomdp_file("dectiger")
    (tmp_path / "dp").mkdir()
    shutil.copy(source, tmp_path / "dp" / "x.dpomdp")
    monkeypatch.chdir(tmp_path)
    tiny = ["--set", "algorithm.iterations=2", "--set", "evaluation.rollouts=50", "--no-progress"]
    argv = ["train", "gdice-dpomdp", "--set", "problem.path=dp/x.dpomdp", "--set"]
    assert cli.main([*argv, "run.plots=false", *tiny, "--out", "run"]) == 0
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    capsys.readouterr()
    run = str(tmp_path / "run")
    assert cli.main(["evaluate", run, "--rollouts", "50"]) == 2
    err = capsys.readouterr().err.strip()
    assert "which is not there from this folder" in err and len(err.splitlines()) == 1
    same = ["--set", f"problem.path={tmp_path / 'dp' / 'x.dpomdp'}"]
    assert cli.main(["evaluate", run, "--rollouts", "50", *same]) == 0
    other = tmp_path / "other.dpomdp"
    other.write_text(source.read_text().replace("discount: 1", "discount: 0.9"))
    assert other.read_text() != source.read_text()
    capsys.readouterr()
    assert cli.main(["evaluate", run, "--rollouts", "50", "--set", f"problem.path={other}"]) == 2
    assert "model file digest differs" in capsys.readouterr().err
    # a gzip copy of the model is the same model; a gzip of the other one is not
    for text, code in ((source.read_bytes(), 0), (other.read_bytes(), 2)):
        packed = tmp_path / "x.dpomdp.gz"
        packed.write_bytes(gzip.compress(text))
        argv = ["evaluate", run, "--rollouts", "50", "--set", f"problem.path={packed}"]
        assert cli.main(argv) == code, capsys.readouterr().err


def test_a_64_bit_dtype_jax_truncates_is_one_warning_line():
    import warnings

    @dataclasses.dataclass(frozen=True)
    class Wide(Coins):
        def step(self, u, state, actions, params):
            state, obs, reward = super().step(u, state, actions, params)
            return state, obs, reward.astype(jnp.float64)  # float32 without x64

    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        _check(Wide())
    texts = [str(w.message) for w in seen]
    assert len(texts) == 1, texts
    assert "asks for float64, which JAX truncates to 32 bits" in texts[0]


def test_small_refusals_of_round_seven(tmp_path, capsys):
    import os

    from cognet_jax.errors import UsageError
    from cognet_jax.plugins import import_plugin
    from cognet_jax.sweep import parse_grid

    with pytest.raises(ConfigError, match="gives the value 0.1 twice"):
        parse_grid(["algorithm.alpha=0.1,1e-1"])
    for field in ("run.plots=true,false", "run.checkpoint_every=1,2", "experiment.name=a,b"):
        with pytest.raises(ConfigError, match="gives every group the same search"):
            parse_grid([field])  # duplicate groups of one search (round eight)
    with pytest.raises(ConfigError, match="is no folder name"):
        load_config("tagging-thesis-n3", ['experiment.name="two\\nlines"'])
    fifo = tmp_path / "pipe.py"
    os.mkfifo(fifo)
    with pytest.raises(UsageError, match="not a regular file"):
        import_plugin(str(fifo))
    assert cli.main(["evaluate", str(tmp_path / "nowhere"), "--seed", "-1"]) == 2
    assert "--seed must be in 0 .. 2147483647" in capsys.readouterr().err


def test_a_unicode_line_separator_in_a_dpomdp_comment_stays_in_the_comment(tmp_path):
    """``str.splitlines`` breaks at U+2028: the rest of a comment became a line (a reward of
    1000 switched on), and every later line number was off by one."""
    from shared_files import dpomdp_file

    from cognet_jax.io.dpomdp import DpomdpParseError, parse_dpomdp

    text = dpomdp_file("dectiger").read_text()
    plain = parse_dpomdp(text)
    hidden = text + "\n# old reward, disabled:\u2028R: * : * : * : * : 1000\n"
    assert np.array_equal(parse_dpomdp(hidden).reward, plain.reward)
    broken = "# a comment\u2028with a separator\n" + text + "\nT: * : bogus\n"
    with pytest.raises(DpomdpParseError) as err:
        parse_dpomdp(broken)
    line = broken.split("\n").index("T: * : bogus") + 1  # counted at \n only
    assert f":{line}:" in str(err.value), str(err.value)


def test_a_stop_swallowed_where_python_ignores_exceptions_still_ends_the_executable():
    """A ``Stopped`` raised inside a garbage-collection callback is printed as "Exception
    ignored" and the process runs on; the executable's deadline (``arm_stop_deadline``) ends
    it anyway, with one line and status 128 + signal."""
    import subprocess
    import sys
    import time

    code = (
        "import os, signal, time\n"
        "import cognet_jax.signals as s\n"
        "s.STOP_DEADLINE_S = 0.5\n"
        "s.arm_stop_deadline()\n"
        "s.install_stop_handlers()\n"
        "try:\n"
        "    os.kill(os.getpid(), signal.SIGTERM)\n"
        "    time.sleep(5)\n"
        "except s.Stopped:\n"
        "    pass  # swallowed, as a gc callback's caller does\n"
        "time.sleep(20)\n"
    )
    t0 = time.monotonic()
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=30)
    assert time.monotonic() - t0 < 15
    assert done.returncode == 143
    assert done.stderr.strip() == "error: stopped by SIGTERM"


def test_a_sweep_state_whose_grid_was_reordered_is_refused_not_mislabelled(tmp_path, capsys):
    """A finished group's rows carry their grid values; a sweep.json edited to give the
    settings other values would publish them under the wrong labels."""
    out = tmp_path / "sw"
    argv = ["sweep", "tagging-thesis-n3", "--seeds", "1", "--grid", "algorithm.nodes=2,3"]
    argv += ["--set", "algorithm.iterations=2", "--set", "algorithm.candidates=8"]
    argv += ["--set", "algorithm.elites=2"]
    argv += ["--set", "algorithm.eval_rollouts=4", "--set", "algorithm.best_rollouts=10"]
    argv += ["--set", "evaluation.rollouts=50", "--set", "run.plots=false", "--no-progress"]
    assert cli.main([*argv, "--out", str(out)]) == 0
    assert cli.main(["sweep", "--resume", str(out), "--no-progress"]) == 0  # as it was: fine
    spec = out / "sweep-state" / "sweep.json"
    data = json.loads(spec.read_text())
    data["grid"]["algorithm.nodes"] = [3, 2]
    spec.write_text(json.dumps(data))
    capsys.readouterr()
    assert cli.main(["sweep", "--resume", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert "holds a run of setting 0 with {'algorithm.nodes': 2}" in err, err
    # round nine: the spec's overrides edited (tables that describe settings no run used)
    data["grid"]["algorithm.nodes"] = [2, 3]
    data["overrides"] = [
        "algorithm.iterations=7" if o == "algorithm.iterations=2" else o for o in data["overrides"]
    ]
    spec.write_text(json.dumps(data))
    assert cli.main(["sweep", "--resume", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert "with algorithm.iterations = 2 (now 7)" in err and "was edited" in err, err
    # and a generator given anew: groups not yet run would draw with another one
    argv = ["sweep", "--resume", str(out), "--set", "run.prng_impl=rbg", "--no-progress"]
    assert cli.main(argv) == 2
    assert "run.prng_impl cannot be given with --resume" in capsys.readouterr().err


def test_a_sweep_stopped_between_groups_names_its_resume(tmp_path, capsys, monkeypatch):
    """A stop heeded after a group's runs were written said "after the results were
    written", though the sweep's tables were not, and gave no --resume."""
    import signal

    from cognet_jax import sweep
    from cognet_jax.signals import Stopped

    def stopped(*args, **kwargs):
        raise Stopped(signal.SIGTERM, after="the results were written")

    monkeypatch.setattr(sweep, "run_sweep", stopped)
    out = tmp_path / "sw"
    assert cli.main(["sweep", "tagging-thesis-n3", "--seeds", "1", "--out", str(out)]) == 143
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err == (
        "error: stopped by SIGTERM after a group's runs were written, before the sweep's "
        f"tables; continue with --resume {out}"
    )


def test_the_on_demand_vae_is_sized_as_vae_train_sizes_it():
    """``network.vae_latent`` 17 trained a VAE that ``evaluate`` then refused to read, 100000
    took 24 GB; ``network.vae_epochs`` 2e9 trained for weeks: both bounded as ``vae train``."""
    with pytest.raises(ConfigError, match="network.vae_latent.*at most 16"):
        load_config("heatmap-encoded-n4", ["network.vae_latent=17"])
    with pytest.raises(ConfigError, match="network.vae_epochs.*at most 100000"):
        load_config("heatmap-encoded-n4", ["network.vae_epochs=2000000000"])


@pytest.mark.parametrize("fd", [1, 2])
def test_a_module_that_closes_the_output_descriptors_is_named(tmp_path, fd):
    """``os.close(1)`` in an --import module left Python's stdout object open over nothing:
    ``list`` said "Bad file descriptor" and ``train`` ended 0 showing no result. Now the
    command refuses in one line (fd 1) or ends 2 (fd 2: nowhere left to say it)."""
    import subprocess
    import sys

    module = tmp_path / "closer.py"
    module.write_text(f"import os\nos.close({fd})\n")
    argv = [sys.executable, "-m", "cognet_jax", "--import", str(module), "list"]
    done = subprocess.run(argv, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    if fd == 1:
        assert done.stderr.strip().splitlines() == [
            f"error: --import {module} closed the standard output (file descriptor 1)"
        ]


def test_a_byte_order_mark_is_read_past_in_experiment_and_model_files(tmp_path):
    """Windows editors start UTF-8 files with U+FEFF: an experiment file was "invalid TOML
    at line 1, column 1" and a model file's first token unknown."""
    from shared_files import dpomdp_file

    from cognet_jax.config import read_experiment
    from cognet_jax.io.dpomdp import load_dpomdp

    toml = tmp_path / "bom.toml"
    toml.write_bytes(b'\xef\xbb\xbf[experiment]\nname = "bom"\n')
    assert read_experiment(str(toml))["experiment"]["name"] == "bom"
    source = dpomdp_file("dectiger")
    model = tmp_path / "bom.dpomdp"
    model.write_bytes(b"\xef\xbb\xbf" + source.read_bytes())
    assert np.array_equal(load_dpomdp(model).reward, load_dpomdp(source).reward)


def test_a_gzip_models_policy_recorded_by_its_bytes_still_belongs_to_it():
    """Policies of gzip models written before the model's digest was its text's recorded the
    file's bytes: those bytes (``model_file``) still match; another model's do not."""
    from cognet_jax.checkpoint import fingerprint_difference

    now = {"model": "text-digest", "model_file": "bytes-digest"}
    assert fingerprint_difference({"model": "bytes-digest"}, now) == ""
    assert fingerprint_difference({"model": "text-digest"}, now) == ""
    assert "model" in fingerprint_difference({"model": "another"}, now)
