"""Checkpoint and resume: SIGINT and SIGKILL a training subprocess mid-run, then resume and
compare with an uninterrupted run bit for bit."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from shared_files import compile_cache_env

from cognet_jax.atomic_files import atomic_write_bytes
from cognet_jax.checkpoint import CHECKPOINT_NAME, read_checkpoint
from cognet_jax.cli import main
from cognet_jax.config import ConfigError
from cognet_jax.driver import train as run_training
from cognet_jax.registry import load_config
from cognet_jax.saved_runs import resume_target

ROOT = Path(__file__).resolve().parents[1]
ITERATIONS = 400
TINY = [
    f"algorithm.iterations={ITERATIONS}",
    "algorithm.rollouts=40",
    "algorithm.top=8",
    "algorithm.keep=3",
    "algorithm.eval_rollouts=8",
    "network.train_steps=2",
    "evaluation.rollouts=200",
    "evaluation.batch=200",
    "run.plots=false",
    "run.progress=false",
]


def _env():
    env = dict(os.environ)
    env.update(compile_cache_env())
    env["PYTHONPATH"] = str(ROOT)
    return env


def _start(out: Path, extra=("--checkpoint-every", "10")):
    args = [sys.executable, "-m", "cognet_jax", "train", "tagging-thesis-spec-n3"]
    args += ["--seed", "3", "--out", str(out)]
    for o in TINY:
        args += ["--set", o]
    args += [*extra]
    return subprocess.Popen(
        args, cwd=ROOT, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )


def _wait_for_checkpoint(proc, path: Path, timeout=240.0):
    t0 = time.time()
    while not path.exists():
        assert proc.poll() is None, proc.communicate()
        assert time.time() - t0 < timeout, "no checkpoint appeared"
        time.sleep(0.02)


def _same_results(a: dict, b: dict, dir_a: Path, dir_b: Path):
    for k in ("values_per_iteration", "in_loop_best_per_iteration", "threshold_per_iteration"):
        assert a[k] == b[k], k
    assert a["final_value"] == b["final_value"]
    assert (dir_a / "policy.msgpack").read_bytes() == (dir_b / "policy.msgpack").read_bytes()


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    out = tmp_path_factory.mktemp("ref")
    config = load_config("tagging-thesis-spec-n3", TINY)
    return run_training(config, 3, out, log=lambda *_: None), out


def test_sigint_writes_policy_and_checkpoint_then_resume_is_identical(reference, tmp_path):
    ref, ref_dir = reference
    proc = _start(tmp_path)
    _wait_for_checkpoint(proc, tmp_path / CHECKPOINT_NAME)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "interrupted at iteration" in err and "--resume" in err
    assert (tmp_path / "policy.msgpack").exists()
    raw = read_checkpoint(tmp_path / CHECKPOINT_NAME)
    assert 10 <= raw["iteration"] < ITERATIONS
    partial = json.loads((tmp_path / "results.json").read_text())
    assert partial["status"] == "interrupted" and partial["iteration"] == raw["iteration"]
    # the interrupted run's history so far equals the reference's prefix
    stored = np.asarray(raw["history"]["value"])
    assert np.array_equal(stored, np.float32(ref["values_per_iteration"][: raw["iteration"]]))

    config, seed = resume_target(tmp_path)
    assert seed == 3
    resumed = run_training(config, seed, tmp_path, resume=True, log=lambda *_: None)
    assert resumed["resumed_from_iteration"] == raw["iteration"]
    _same_results(ref, resumed, ref_dir, tmp_path)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP])
def test_sigterm_and_sighup_stop_like_sigint_then_resume_is_identical(reference, tmp_path, sig):
    """What ``timeout`` and job schedulers send (SIGTERM), and what a closed terminal sends
    (SIGHUP): the run ends after its iteration with the policy, results and checkpoint
    written, exit 128 + the signal, and resumes to the same numbers."""
    ref, ref_dir = reference
    proc = _start(tmp_path)
    _wait_for_checkpoint(proc, tmp_path / CHECKPOINT_NAME)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 128 + sig, err
    name = signal.Signals(sig).name
    assert "interrupted at iteration" in err and name in err and "--resume" in err
    assert len(err.strip().splitlines()[-1]) > 0 and "Traceback" not in err
    assert (tmp_path / "policy.msgpack").exists()
    raw = read_checkpoint(tmp_path / CHECKPOINT_NAME)
    partial = json.loads((tmp_path / "results.json").read_text())
    assert partial["status"] == "interrupted" and partial["iteration"] == raw["iteration"]
    config, seed = resume_target(tmp_path)
    resumed = run_training(config, seed, tmp_path, resume=True, log=lambda *_: None)
    _same_results(ref, resumed, ref_dir, tmp_path)


def test_sigkill_leaves_an_intact_checkpoint_and_resume_is_identical(reference, tmp_path, capsys):
    ref, ref_dir = reference
    proc = _start(tmp_path)
    ckpt = tmp_path / CHECKPOINT_NAME
    _wait_for_checkpoint(proc, ckpt)
    first = read_checkpoint(ckpt)["iteration"]
    # let it write a few more checkpoints, then kill it without warning
    t0 = time.time()
    while read_checkpoint(ckpt)["iteration"] < first + 20 and time.time() - t0 < 60:
        assert proc.poll() is None
        time.sleep(0.01)
    proc.kill()
    proc.wait(timeout=60)
    assert proc.returncode == -signal.SIGKILL
    raw = read_checkpoint(ckpt)  # intact: parses, and its history is the reference's prefix
    n = raw["iteration"]
    assert n % 10 == 0 and 10 <= n < ITERATIONS
    assert np.array_equal(
        np.asarray(raw["history"]["value"]), np.float32(ref["values_per_iteration"][:n])
    )
    leftovers = [p.name for p in tmp_path.iterdir() if p.name.endswith(".tmp")]
    assert len(leftovers) <= 1  # at most the temp file the kill interrupted

    # resume through the command line's entry point (in this process)
    capsys.readouterr()
    assert main(["train", "--resume", str(tmp_path), "--no-progress"]) == 0
    assert f"at iteration {n}/{ITERATIONS}" in capsys.readouterr().out
    resumed = json.loads((tmp_path / "results.json").read_text())
    _same_results(ref, resumed, ref_dir, tmp_path)


def test_checkpoints_by_time_by_default_then_sigkill_and_resume_is_identical(reference, tmp_path):
    """No ``--checkpoint-every``: the state is still written every ``run.checkpoint_seconds``
    (60 s by default; 0.05 s here), so a SIGKILL loses at most that much and the resumed run
    gives the uninterrupted run's numbers (the ``run`` section is not part of the search)."""
    assert load_config("tagging-thesis-spec-n3").run.checkpoint_seconds == 60.0
    ref, ref_dir = reference
    out = tmp_path / "cut"
    proc = _start(out, extra=["--set", "run.checkpoint_seconds=0.05"])
    ckpt = out / CHECKPOINT_NAME
    _wait_for_checkpoint(proc, ckpt)
    first = read_checkpoint(ckpt)["iteration"]
    t0 = time.time()
    while read_checkpoint(ckpt)["iteration"] == first and time.time() - t0 < 60:
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.01)
    proc.kill()
    proc.wait(timeout=60)
    n = read_checkpoint(ckpt)["iteration"]
    assert 0 < first < n < ITERATIONS
    config, seed = resume_target(out)
    resumed = run_training(config, seed, out, resume=True, log=lambda *_: None)
    assert resumed["resumed_from_iteration"] == n
    _same_results(ref, resumed, ref_dir, out)


def test_resume_refuses_changes_outside_run_section(tmp_path):
    atomic_write_bytes(tmp_path / "x.bin", b"abc")
    assert (tmp_path / "x.bin").read_bytes() == b"abc"
    with pytest.raises(ConfigError) as err:
        resume_target(tmp_path, ["algorithm.nodes=4"])
    assert err.value.field == "algorithm.nodes"
    with pytest.raises(FileNotFoundError):
        resume_target(tmp_path, ["run.plots=false"])


def test_a_checkpoint_of_another_config_names_the_field_that_differs():
    from cognet_jax.records import _first_difference

    old = {"runs": [[0, 1]], "configs": [{"algorithm": {"nodes": 3}, "env": {"noise": 0.1}}]}
    new = {"runs": [[0, 1]], "configs": [{"algorithm": {"nodes": 3, "best_pool": 4}}]}
    assert _first_difference(old, new) == "config (algorithm.best_pool: not written there, 4 now)"
    assert _first_difference({**old, "runs": [[0, 2]]}, new) == "group of seeds and settings"


def test_a_field_added_since_the_checkpoint_does_not_block_its_resume():
    """A field the checkpoint's config did not write (added to the library since; the resumed
    config holds its default) is not a difference; a field it wrote with another value is."""
    from cognet_jax.records import _first_difference, _written_fields

    old = {"runs": [[0, 1]], "configs": [{"algorithm": {"nodes": 3}, "env": {"noise": 0.1}}]}
    new = {
        "runs": [[0, 1]],
        "configs": [{"algorithm": {"nodes": 3, "tied_vote_scale": 1.0}, "env": {"noise": 0.1}}],
    }
    assert _written_fields(new, old) == old
    changed = {"runs": [[0, 1]], "configs": [{"algorithm": {"nodes": 4}, "env": {"noise": 0.1}}]}
    kept = _written_fields(changed, old)
    assert kept != old
    assert _first_difference(old, kept) == "config (algorithm.nodes: 3 there, 4 now)"


def test_a_checkpoint_written_before_best_value_was_named_in_loop_best_still_restores():
    """State and history stored under the old name ``best_value`` read under ``in_loop_best``
    (``checkpoint.RENAMED_FIELDS``)."""
    import jax
    from flax import serialization

    from cognet_jax.algorithms.engine import SearchMetrics
    from cognet_jax.checkpoint import restore_history, restore_state

    one = SearchMetrics(value=np.float32(1), in_loop_best=np.float32(2), mean_value=np.float32(0))
    stacked = jax.tree.map(lambda x: np.stack([x, x + 1]), one)
    old = serialization.to_state_dict(stacked)
    old["best_value"] = old.pop("in_loop_best")
    raw = {"history": old, "iteration": 2, "state": {"progress": old}}
    assert [float(h.in_loop_best) for h in restore_history(one, raw)] == [2.0, 3.0]
    state = restore_state({"progress": stacked}, raw)
    np.testing.assert_array_equal(state["progress"].in_loop_best, [2.0, 3.0])
