"""A run folder is never lost (cognet_jax/run_folder.py, issue 53): an existing run is refused
without --resume / --overwrite, a second writer fails at once, --out '' is refused, and a
policy records the numeric settings and imported code it was made with."""

from __future__ import annotations

import json
import os

import pytest
from shared_files import TINY_TRAIN

from cognet_jax import cli, registry
from cognet_jax.checkpoint import policy_bytes, read_policy
from cognet_jax.errors import MismatchError, UsageError
from cognet_jax.run_folder import check_out, claim


def test_an_existing_run_is_refused_unless_resumed_or_overwritten(tmp_path, capsys):
    out = tmp_path / "run"
    assert cli.main(["train", "--out", str(out), *TINY_TRAIN]) == 0
    first = (out / "results.json").read_bytes()
    capsys.readouterr()
    assert cli.main(["train", "--out", str(out), "--seed", "1", *TINY_TRAIN]) == 2
    err = capsys.readouterr().err
    assert "already holds a run" in err and "--resume" in err and "--overwrite" in err
    assert (out / "results.json").read_bytes() == first  # untouched
    assert cli.main(["train", "--out", str(out), "--seed", "1", "--overwrite", *TINY_TRAIN]) == 0
    assert json.loads((out / "results.json").read_text())["seed"] == 1


def test_a_second_writer_fails_at_once_naming_the_holder(tmp_path):
    with claim(tmp_path / "run"):
        with pytest.raises(UsageError, match="being written by another cognet-jax process"):
            with claim(tmp_path / "run", overwrite=True):
                pass
    with claim(tmp_path / "run"):  # released when the first writer is done
        pass


def test_an_empty_out_and_an_unwritable_folder_are_refused(tmp_path):
    with pytest.raises(UsageError, match="--out ''"):
        check_out("")
    (tmp_path / "file").write_text("x")
    with pytest.raises(UsageError, match="not a folder"):
        with claim(tmp_path / "file"):
            pass
    (tmp_path / "run" / "results.json").mkdir(parents=True)
    with pytest.raises(UsageError, match="results.json is a folder"):
        with claim(tmp_path / "run", overwrite=True):
            pass
    with pytest.raises(UsageError, match="cannot write there"):
        with claim(tmp_path / "file" / "sub"):
            pass


def test_a_policy_made_with_other_numerics_or_imported_code_is_refused(tmp_path, monkeypatch):
    import jax.numpy as jnp

    policy = {"w": jnp.ones(3)}
    made = {"config": "c", "numerics": {"x64": False, "prng": "threefry2x32", "imported": {}}}
    path = tmp_path / "policy.msgpack"
    path.write_bytes(policy_bytes(policy, made))
    assert read_policy(path, policy, fingerprint=made)["w"].shape == (3,)
    other = dict(made, numerics=dict(made["numerics"], imported={"mine.py": "ab12"}))
    with pytest.raises(MismatchError, match="imported: trained {}, now {'mine.py': 'ab12'}"):
        read_policy(path, policy, fingerprint=other)


def test_imported_code_or_a_replaced_builtin_keeps_no_program(monkeypatch):
    entry = registry.env_entry("tagging")
    assert registry.is_builtin(entry)
    replaced = registry.EnvEntry("tagging", entry.section, lambda s, c: entry.build(s, c))
    assert not registry.is_builtin(replaced)  # a user's registration of a built-in name
    monkeypatch.setattr(registry, "_FOREIGN_CODE", {})
    registry.note_foreign_code("doubled", __file__)
    assert list(registry.foreign_code()) == ["test_run_folder.py"]


def test_with_imported_code_the_driver_keeps_no_program(monkeypatch):
    from cognet_jax import compiled as program
    from cognet_jax.registry import load_config

    keys = []
    monkeypatch.setattr(
        program, "compile_kept", lambda fn, args, key, check, checked: keys.append(key)
    )
    monkeypatch.setattr(program, "program_key", lambda *a: "a key")
    config = load_config("tagging-thesis-n3")
    program.compiled_program(config, "p", None, (), None, {})
    monkeypatch.setattr(registry, "_FOREIGN_CODE", {"mine.py": "ab12"})
    program.compiled_program(config, "p", None, (), None, {})
    assert keys == ["a key", None]


def _beacon_plugin(path, cls: str, name: str, last_line: str):
    """Write an ``--import`` module registering ``name``: the beacon simulator whose step ends
    with ``last_line`` (``s, obs, r`` are the built-in step's outputs); returns ``path``."""
    path.write_text(
        "import jax.numpy as jnp\n"
        "from cognet_jax.envs import beacon\n"
        "from cognet_jax.registry import register_env\n"
        f"class {cls}(beacon.Beacon):\n"
        "    def step(self, u, state, actions, params):\n"
        "        s, obs, r = super().step(u, state, actions, params)\n"
        f"        {last_line}\n"
        "def build(section, config):\n"
        "    env, params = beacon.build_from_section(section, config)\n"
        f"    return {cls}(horizon=env.horizon, num_agents=env.num_agents), params\n"
        f"register_env({name!r}, beacon.BeaconSection, build)\n"
    )
    return path


def test_a_simulator_that_returns_wrong_shapes_is_named_not_an_internal_error(
    tmp_path, capsys, monkeypatch
):
    monkeypatch.setattr(registry, "_FOREIGN_CODE", {})  # this process's record, restored after
    plugin = _beacon_plugin(
        tmp_path / "badsim.py", "Bad", "bad-beacon-test", "return s, obs[:, :1], r"
    )
    args = ["--import", str(plugin), "train", "beacon-n5", "--set", "env.name=bad-beacon-test"]
    assert cli.main([*args, "--out", str(tmp_path / "r"), *TINY_TRAIN]) == 2
    err = capsys.readouterr().err
    assert "simulator 'bad-beacon-test' (badsim.Bad)" in err and "expected floating [3, 2]" in err
    nan = tmp_path / "nansim.py"
    nan.write_text(
        plugin.read_text()
        .replace("obs[:, :1]", "obs * jnp.nan")
        .replace("bad-beacon-test", "nan-beacon-test")
    )
    args = ["--import", str(nan), "train", "beacon-n5", "--set", "env.name=nan-beacon-test"]
    assert cli.main([*args, "--out", str(tmp_path / "n"), *TINY_TRAIN]) == 2
    assert "step returned a NaN observation" in capsys.readouterr().err
    late = _beacon_plugin(  # NaN on about 1 step in 1,000: rarely in the first episodes
        tmp_path / "latensim.py",
        "Late",
        "late-nan-beacon-test",
        "return s, jnp.where(u[0] < 1e-3, jnp.nan, obs), r",
    )
    args = ["--import", str(late), "train", "beacon-n5", "--set", "env.name=late-nan-beacon-test"]
    assert cli.main([*args, "--out", str(tmp_path / "l"), *TINY_TRAIN]) == 2
    assert "NaN observation at step" in capsys.readouterr().err
    rare = _beacon_plugin(  # NaN on 1 step in 100,000: past the check, met by the evaluation
        tmp_path / "rarensim.py",
        "Rare",
        "rare-nan-beacon-test",
        "return s, jnp.where(u[0] < 1e-5, jnp.nan, obs), r",
    )
    args = ["--import", str(rare), "train", "beacon-n5", "--set", "env.name=rare-nan-beacon-test"]
    honest = ["--set", "evaluation.rollouts=20000"]  # 20,000 x 30 steps x 3 agents' draws
    assert cli.main([*args, "--out", str(tmp_path / "rare"), *TINY_TRAIN, *honest]) == 2
    assert "rewards or observations are NaN" in capsys.readouterr().err
    (tmp_path / "exits.py").write_text("import sys\nsys.exit(7)\n")
    assert cli.main(["--import", str(tmp_path / "exits.py"), "list"]) == 2
    assert "exited with status 7" in capsys.readouterr().err


def test_a_module_that_ends_the_process_or_hangs_at_import_is_named(tmp_path, capsys, monkeypatch):
    (tmp_path / "quits.py").write_text("import os\nos._exit(3)\n")
    assert cli.main(["--import", str(tmp_path / "quits.py"), "list"]) == 2
    assert "--import" in (err := capsys.readouterr().err) and "exited with status 3" in err
    (tmp_path / "hangs.py").write_text("import time\nwhile True:\n    time.sleep(0.05)\n")
    monkeypatch.setenv("COGNET_JAX_IMPORT_TIMEOUT", "0.5")
    assert cli.main(["--import", str(tmp_path / "hangs.py"), "list"]) == 2
    assert "still importing after 0.5 s" in capsys.readouterr().err
    import os

    assert os._exit.__module__ == "posix"  # given back after the import
    # a module that turns the alarm off and hangs: a watchdog thread ends the process
    import subprocess
    import sys

    (tmp_path / "deaf.py").write_text(
        "import signal, time\nsignal.signal(signal.SIGALRM, signal.SIG_IGN)\ntime.sleep(60)\n"
    )
    argv = [sys.executable, "-m", "cognet_jax", "--import", str(tmp_path / "deaf.py"), "list"]
    env = dict(os.environ, COGNET_JAX_IMPORT_TIMEOUT="0.5")
    proc = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=50)
    assert proc.returncode == 2 and "still importing after 0.5 s" in proc.stderr, proc.stderr


def test_a_thread_left_running_by_a_module_does_not_keep_the_command_alive(tmp_path):
    import subprocess
    import sys
    import time

    module = tmp_path / "spins.py"
    module.write_text(
        "import threading, time\nthreading.Thread(target=time.sleep, args=(60,)).start()\n"
    )
    t0 = time.monotonic()
    done = subprocess.run(
        [sys.executable, "-m", "cognet_jax", "--import", str(module), "list"],
        capture_output=True,
        text=True,
        timeout=50,
    )
    assert done.returncode == 0 and time.monotonic() - t0 < 40
    assert "not waiting for thread" in done.stderr and "tagging-thesis-n3" in done.stdout


def test_a_failed_write_names_the_file_and_keeps_the_previous_one(tmp_path, monkeypatch):
    from cognet_jax import atomic_files as checkpoint

    path = tmp_path / "results.json"
    checkpoint.atomic_write_text(path, "old")

    def full(fd, data):
        raise OSError(27, "File too large")

    monkeypatch.setattr(checkpoint.os, "fsync", lambda fd: full(fd, None))
    with pytest.raises(OSError, match=f"cannot write {path}: File too large"):
        checkpoint.atomic_write_text(path, "new")
    assert path.read_text() == "old" and [p.name for p in tmp_path.iterdir()] == ["results.json"]


def test_sweep_tables_and_figures_are_written_whole(tmp_path, monkeypatch):
    """runs.csv and the figures go through the same atomic write: a failure names the file and
    leaves the previous one (they were written in place before)."""
    from cognet_jax import atomic_files, plots, sweep

    (tmp_path / "runs.csv").write_text("old table")
    monkeypatch.setattr(
        atomic_files.os, "fsync", lambda fd: (_ for _ in ()).throw(OSError(28, "No space"))
    )
    row = dict(
        setting=0, group=0, seed=0, grid={}, in_loop_best=1.0,
        final_value=dict(mean=1.0, stderr=0.1, rollouts=10),
    )  # fmt: skip
    with pytest.raises(OSError, match="cannot write .*runs.csv: No space"):
        sweep.write_outputs(dict(grid={}, rows=[row]), tmp_path)
    assert (tmp_path / "runs.csv").read_text() == "old table"
    import matplotlib.figure

    fig = matplotlib.figure.Figure()
    fig.subplots().plot([0, 1])
    with pytest.raises(OSError, match="cannot write .*values.png: No space"):
        plots._save(fig, tmp_path / "values.png", dpi=50)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["runs.csv"]


@pytest.mark.parametrize(
    "change, expected",
    [
        ("return s, obs, jnp.stack([r, r, r])", "reward"),
        ("return s.replace(agents=jnp.concatenate([s.agents, s.agents])), obs, r", "state"),
        ("raise ValueError('my step is broken')", "my step is broken"),
    ],
    ids=["reward-of-shape-3", "growing-state", "raising-step"],
)
def test_a_broken_user_step_is_the_simulators_error(
    tmp_path, capsys, monkeypatch, change, expected
):
    """The cases of issue 53 that ended as "internal error": each is refused before compiling,
    exit 2, one line naming the simulator and what is wrong."""
    monkeypatch.setattr(registry, "_FOREIGN_CODE", {})
    plugin = _beacon_plugin(tmp_path / "brokensim.py", "Broken", "broken-beacon-test", change)
    args = ["--import", str(plugin), "train", "beacon-n5", "--set", "env.name=broken-beacon-test"]
    assert cli.main([*args, "--out", str(tmp_path / "r"), *TINY_TRAIN]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "internal error" not in err[0], err
    assert "broken-beacon-test" in err[0] and expected in err[0], err[0]


def test_a_folder_of_the_other_command_is_refused_with_advice_that_works(tmp_path):
    """``train`` into a sweep's folder (or a sweep into a ``train``'s) is not told to
    ``--resume`` it, which the other command cannot; a sweep's ``runs/`` alone holds runs."""
    sweep = tmp_path / "sweep"
    (sweep / "runs" / "setting0-seed0").mkdir(parents=True)
    (sweep / "runs" / "setting0-seed0" / "results.json").write_text("{}")
    with pytest.raises(UsageError, match="run of `sweep` \\(runs\\); `train` cannot continue"):
        with claim(sweep):
            pass
    with pytest.raises(UsageError, match="no sweep state to resume"):
        with claim(sweep, kind="sweep"):  # run folders alone: a sweep's --resume would fail
            pass
    (sweep / "sweep-state").mkdir()
    (sweep / "sweep-state" / "sweep.json").write_text("{}")
    with pytest.raises(UsageError, match="continue it with --resume"):
        with claim(sweep, kind="sweep"):
            pass
    single = tmp_path / "single"
    single.mkdir()
    (single / "results.json").write_text("{}")
    with pytest.raises(UsageError, match="`sweep` cannot continue it"):
        with claim(single, kind="sweep"):
            pass
    (tmp_path / "plain" / "runs").mkdir(parents=True)  # a folder merely named runs: free
    with claim(tmp_path / "plain"):
        pass


def test_a_policy_copied_from_another_run_is_refused(tmp_path, capsys):
    """Two seeds of the same config: the second's policy file copied into the first's folder
    must not be evaluated as the first's (results.json's ``policy_sha256``)."""
    a, b = tmp_path / "a", tmp_path / "b"
    assert cli.main(["train", "--out", str(a), *TINY_TRAIN]) == 0
    assert cli.main(["train", "--out", str(b), "--seed", "1", *TINY_TRAIN]) == 0
    assert json.loads((a / "results.json").read_text())["policy_sha256"]
    (a / "policy.msgpack").write_bytes((b / "policy.msgpack").read_bytes())
    capsys.readouterr()
    assert cli.main(["evaluate", str(a)]) == 2
    err = capsys.readouterr().err
    assert "not the file this run wrote" in err and "policy_sha256" in err


def test_a_lone_policy_a_linked_lock_and_an_unwritable_folder_are_refused(tmp_path):
    """A folder holding only a policy is a run (refused without --overwrite); a ``.lock`` that
    is a link is refused and the file it points to left alone; a folder where no file can be
    created is refused before anything runs, even with a lock file already in it."""
    lone = tmp_path / "lone"
    lone.mkdir()
    (lone / "policy.msgpack").write_bytes(b"x")
    with pytest.raises(UsageError, match="policy.msgpack.*no checkpoint to resume"):
        with claim(lone):
            pass
    linked = tmp_path / "linked"
    linked.mkdir()
    notes = tmp_path / "notes.txt"
    notes.write_text("mine")
    (linked / ".lock").symlink_to(notes)
    with pytest.raises(UsageError, match=r"\.lock: not a regular file"):
        with claim(linked):
            pass
    assert notes.read_text() == "mine"
    shut = tmp_path / "shut"
    shut.mkdir()
    (shut / ".lock").write_text("")
    # a file cannot be created under the probe's name (root writes into read-only folders)
    (shut / f".write-check-{os.getpid()}").mkdir()
    with pytest.raises(UsageError, match="cannot write there"):
        with claim(shut):
            pass


def test_overwrite_removes_what_described_the_replaced_run(tmp_path):
    """``--overwrite``: once the new run finished, the replaced run's evaluations log, results
    and a sweep's earlier run folders are gone, and what the new run wrote stays; a run stopped
    before (an error or a signal while compiling) leaves the old run as it was."""
    run = tmp_path / "run"
    run.mkdir()
    for name in ("results.json", "evaluations.jsonl", "policy.msgpack"):
        (run / name).write_text("{}")
    with pytest.raises(KeyboardInterrupt):
        with claim(run, overwrite=True):
            raise KeyboardInterrupt  # a stop while compiling
    assert (run / "results.json").exists() and (run / "evaluations.jsonl").exists()
    with claim(run, overwrite=True):
        (run / "results.json").write_text('{"new": 1}')
    assert not (run / "evaluations.jsonl").exists() and not (run / "policy.msgpack").exists()
    assert (run / "results.json").read_text() == '{"new": 1}'
    sweep = tmp_path / "sweep"
    for seed in (0, 2):
        (sweep / "runs" / f"setting0-seed{seed}").mkdir(parents=True)
        (sweep / "runs" / f"setting0-seed{seed}" / "results.json").write_text("{}")
    (sweep / "runs.json").write_text("{}")
    with claim(sweep, overwrite=True, kind="sweep"):
        (sweep / "runs" / "setting0-seed0" / "results.json").write_text('{"new": 1}')
    assert not (sweep / "runs" / "setting0-seed2").exists() and not (sweep / "runs.json").exists()
    assert (sweep / "runs" / "setting0-seed0" / "results.json").exists()


def test_a_sweeps_run_folder_points_to_the_sweep(tmp_path):
    """``train`` into a run folder of a sweep names the sweep to continue, not a ``--resume``
    of the run folder that has no checkpoint."""
    run = tmp_path / "sw" / "runs" / "setting0-seed0"
    run.mkdir(parents=True)
    (run / "results.json").write_text("{}")
    (tmp_path / "sw" / "runs.json").write_text("{}")
    with pytest.raises(UsageError, match=r"a run of the sweep in .*sweep --resume"):
        with claim(run):
            pass


def test_a_sweep_never_writes_through_a_linked_run_folder(tmp_path, capsys):
    """A sweep folder whose run folder is a symbolic link to another run: ``--overwrite``
    replaces the sweep, never the linked run (it was overwritten through the link)."""
    precious = tmp_path / "precious"
    precious.mkdir()
    (precious / "results.json").write_text('{"mine": true}')
    sweep = tmp_path / "sweep"
    (sweep / "runs").mkdir(parents=True)
    (sweep / "runs.json").write_text("{}")
    (sweep / "runs" / "setting0-seed0").symlink_to(precious)
    capsys.readouterr()
    argv = ["sweep", "tagging-thesis-n3", "--seeds", "1", "--out", str(sweep), "--overwrite"]
    assert cli.main([*argv, *TINY_TRAIN]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "symbolic link" in err[0] and "setting0-seed0" in err[0], err
    assert (precious / "results.json").read_text() == '{"mine": true}'


def test_a_train_over_a_sweep_leaves_no_sweep_to_resume(tmp_path, capsys):
    """``train --overwrite`` into a sweep's folder replaces the whole sweep: its run folders
    and state go, so ``sweep --resume`` cannot write its tables over the new run."""
    out = tmp_path / "both"
    assert (
        cli.main(["sweep", "tagging-thesis-n3", "--seeds", "2", "--out", str(out), *TINY_TRAIN])
        == 0
    )
    assert cli.main(["train", "--out", str(out), "--overwrite", *TINY_TRAIN]) == 0
    assert not (out / "runs").exists() and not (out / "sweep-state").exists()
    assert not (out / "runs.json").exists() and (out / "results.json").is_file()
    capsys.readouterr()
    assert cli.main(["sweep", "--resume", str(out)]) == 2
    assert "sweep.json" in capsys.readouterr().err


def test_a_folder_of_the_users_among_a_sweeps_run_folders_survives_overwrite(tmp_path):
    """``sweep --overwrite`` replaces the sweep's run folders, not a folder of the user's own
    that only looks like one (``runs/setting9-seed9`` holding notes)."""
    out = tmp_path / "sweep"
    argv = ["sweep", "tagging-thesis-n3", "--seeds", "1", "--out", str(out), *TINY_TRAIN]
    assert cli.main(argv) == 0
    mine = out / "runs" / "setting9-seed9"
    mine.mkdir()
    (mine / "mine.txt").write_text("notes")
    assert cli.main([*argv, "--overwrite", "--set", "env.obs_noise=0.5"]) == 0
    assert (mine / "mine.txt").read_text() == "notes"
    assert (out / "runs" / "setting0-seed0" / "results.json").is_file()


def test_figures_of_a_replaced_run_never_stay_beside_another_runs_results(tmp_path, capsys):
    """``--overwrite`` by a run without figures removes the old run's; a figure that cannot be
    written is one warning line, the run's results are saved, and no old figure stays."""
    out = tmp_path / "run"
    with_plots = [*TINY_TRAIN, "--set", "run.plots=true"]  # the later setting holds
    assert cli.main(["train", "--out", str(out), *with_plots]) == 0
    old = sorted(p.name for p in out.glob("*.png"))
    assert "values.png" in old and len(old) > 1
    (out / "values.png").unlink()
    (out / "values.png").mkdir()  # the first figure cannot be written
    capsys.readouterr()
    argv = ["train", "--out", str(out), "--seed", "1", "--overwrite", *TINY_TRAIN]
    assert cli.main([*argv, "--set", "run.plots=true"]) == 0
    said = capsys.readouterr()
    assert "figures could not be written" in said.err and "results are saved" in said.err
    assert "and plots" not in said.out  # the line naming what was written does not claim them
    assert json.loads((out / "results.json").read_text())["seed"] == 1
    assert [p.name for p in out.glob("*.png") if p.is_file()] == []  # no old figure
    assert (out / "values.png").is_dir()  # a folder of the user's is not removed
    (out / "values.png").rmdir()
    assert cli.main([*argv, "--set", "run.plots=true", "--seed", "2"]) == 0
    assert cli.main([*argv, "--set", "run.plots=false", "--seed", "3"]) == 0
    assert list(out.glob("*.png")) == []


def test_another_runs_checkpoint_beside_finished_results_is_not_resumed(tmp_path, capsys):
    """A checkpoint of another run copied into a finished run's folder: ``--resume`` refuses
    it, naming what differs, and the finished results stay. The checkpoint of a run started
    with ``--overwrite`` and stopped is resumed, and replaces the old results."""
    a, b = tmp_path / "a", tmp_path / "b"
    assert cli.main(["train", "--out", str(a), *TINY_TRAIN]) == 0
    assert cli.main(["train", "--out", str(b), "--seed", "1", *TINY_TRAIN]) == 0
    finished = (a / "results.json").read_bytes()
    copied = (b / "checkpoint.msgpack").read_bytes()
    (a / "checkpoint.msgpack").write_bytes(copied)
    capsys.readouterr()
    assert cli.main(["train", "--resume", str(a)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "checkpoint of another run" in err[0] and "seed" in err[0], err
    assert (a / "results.json").read_bytes() == finished
    with pytest.raises(KeyboardInterrupt):  # --overwrite stopped before its first checkpoint
        with claim(a, overwrite=True):
            raise KeyboardInterrupt
    assert not (a / ".replacing").exists()  # the checkpoint there is still the old run's
    with pytest.raises(KeyboardInterrupt):  # --overwrite with seed 1, stopped after a checkpoint
        with claim(a, overwrite=True):
            (a / "checkpoint.msgpack").write_bytes(copied)
            raise KeyboardInterrupt
    assert (a / "results.json").read_bytes() == finished  # the old run stays until then
    (a / "evaluations.jsonl").write_text('{"mean": 1.0}\n')  # an evaluation of the old run
    assert cli.main(["train", "--resume", str(a)]) == 0
    assert json.loads((a / "results.json").read_text())["seed"] == 1
    assert not (a / ".replacing").exists()
    assert not (a / "evaluations.jsonl").exists()  # it described the replaced run


def test_resuming_a_complete_run_writes_nothing(tmp_path, capsys):
    """``train --resume`` of a run whose search and evaluation are done says so and leaves
    every file as it was (it re-evaluated and rewrote results.json with new timings)."""
    a = tmp_path / "a"
    assert cli.main(["train", "--out", str(a), *TINY_TRAIN]) == 0
    before = {p.name: p.read_bytes() for p in a.iterdir()}
    capsys.readouterr()
    assert cli.main(["train", "--resume", str(a)]) == 0
    out = capsys.readouterr().out
    assert "the run is complete (2 iterations" in out and "nothing written" in out, out
    assert {p.name: p.read_bytes() for p in a.iterdir()} == before


@pytest.mark.parametrize("discount", [float("nan"), float("inf"), 1.5, 0.0, -0.5])
def test_a_simulator_whose_discount_is_not_in_zero_one_is_named(discount):
    """A NaN discount made every return NaN, blamed on the rewards after the whole search; one
    above 1 trained to returns that grow without bound: refused at the simulator's check."""
    from cognet_jax.envs.base import _CHECKED, check_simulator
    from cognet_jax.envs.tagging import make_tagging
    from cognet_jax.errors import SimulatorError

    env, params = make_tagging("thesis")
    check_simulator(env, params, "tagging", values=False)
    bad = params.replace(discount=discount)
    with pytest.raises(SimulatorError, match=r"simulator 'tagging' .*discount is .*\(0, 1\]"):
        check_simulator(env, bad, "tagging", values=False)
    assert (id(env), id(bad), False) not in _CHECKED


def test_evaluate_and_a_writer_of_the_same_folder_exclude_each_other(tmp_path, capsys):
    """``evaluate`` holds a shared lock on the run folder (``run_folder.reading``): refused
    while a ``train`` writes it, and a ``train --overwrite`` started meanwhile is refused, so no
    evaluation of the replaced policy is appended beside the new run's results."""
    from cognet_jax.run_folder import reading

    out = tmp_path / "run"
    assert cli.main(["train", "--out", str(out), *TINY_TRAIN]) == 0
    with claim(out, resume=True):  # a writer (here one that would continue the run)
        with pytest.raises(UsageError, match="being written by another cognet-jax process"):
            with reading(out):
                pass
    capsys.readouterr()
    with reading(out):
        argv = ["train", "--out", str(out), "--overwrite", "--seed", "1", *TINY_TRAIN]
        assert cli.main(argv) == 2
        assert "read by a `cognet-jax evaluate`" in capsys.readouterr().err
    with reading(out), reading(out):  # readers share it
        pass
    assert cli.main(["evaluate", str(out)]) == 0
    assert len((out / "evaluations.jsonl").read_text().splitlines()) == 1


def test_a_checkpoint_edited_by_hand_is_named_on_resume(tmp_path, capsys):
    """A checkpoint whose iteration is negative or past the run's, or whose state holds an
    array of another shape, is refused naming the file (it rewrote the run's history, or
    failed inside a compiled call); one whose best policy holds NaN has no honest value."""
    import numpy as np
    from flax import serialization

    base = tmp_path / "base"
    assert cli.main(["train", "--out", str(base), *TINY_TRAIN]) == 0
    blob = serialization.msgpack_restore((base / "checkpoint.msgpack").read_bytes())

    def resumed(name, edit):
        import shutil

        folder = tmp_path / name
        shutil.copytree(base, folder)
        damaged = serialization.msgpack_restore((base / "checkpoint.msgpack").read_bytes())
        edit(damaged)
        (folder / "checkpoint.msgpack").write_bytes(serialization.msgpack_serialize(damaged))
        capsys.readouterr()
        code = cli.main(["train", "--resume", str(folder), "--no-progress"])
        return code, capsys.readouterr().err.strip().splitlines()

    code, err = resumed("negative", lambda b: b.update(iteration=-3))
    assert code == 2 and "checkpoint.msgpack" in err[-1] and "iteration -3" in err[-1], err
    first = sorted(blob["state"]["distribution"])[0]
    shape = np.asarray(blob["state"]["distribution"][first]).shape

    def reshape(b):
        b["state"]["distribution"][first] = np.zeros((*shape, 2), np.float32)
        b["iteration"] = 1

    code, err = resumed("shape", reshape)
    assert code == 2 and f"state.distribution.{first}" in err[-1], err


def test_a_resume_under_other_numeric_settings_or_modules_is_refused(tmp_path, capsys):
    """A checkpoint records, per run, the model digest, numeric settings and imported modules
    it was started with; a resume under others (another generator, an edited --import module,
    an edited model) is refused naming the difference, as ``evaluate`` refuses a policy."""
    import shutil

    from flax import serialization

    base = tmp_path / "base"
    assert cli.main(["train", "--out", str(base), *TINY_TRAIN]) == 0
    blob = serialization.msgpack_restore((base / "checkpoint.msgpack").read_bytes())
    meta = json.loads(blob["meta"])
    assert meta["fingerprints"][0]["numerics"]["prng"] == "threefry2x32"
    meta["fingerprints"][0]["numerics"]["prng"] = "rbg"
    blob.update(meta=json.dumps(meta), iteration=1)
    folder = tmp_path / "other"
    shutil.copytree(base, folder)
    (folder / "checkpoint.msgpack").write_bytes(serialization.msgpack_serialize(blob))
    capsys.readouterr()
    assert cli.main(["train", "--resume", str(folder), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "checkpoint.msgpack" in err and "prng: trained 'rbg', now 'threefry2x32'" in err, err


#: a 1-D seek simulator whose reward turns NaN once every agent has taken action 2 five times:
#: random episodes almost never do (a chance of 1 in 9 a step), a search's controllers often
RARE_NAN_SEEK = """
import dataclasses
import jax.numpy as jnp
from flax import struct
from cognet_jax.registry import register_env

@struct.dataclass
class SeekParams:
    discount: float = 0.95

@dataclasses.dataclass(frozen=True)
class Seek:
    horizon: int = 5
    num_agents: int = 2
    num_actions: int = 3
    action_counts: tuple = (3, 3)
    obs_shape: tuple = ()
    num_obs: None = None
    obs_range: tuple = (-10.0, 10.0)
    reset_noise: int = 2
    step_noise: int = 0

    def reset(self, u, params):
        return jnp.concatenate([5.0 * u, jnp.array([10.0, 0.0])])

    def step(self, u, state, actions, params):
        pos = jnp.clip(state[:2] + actions - 1.0, 0.0, 10.0)
        reward = jnp.sum(jnp.where(jnp.abs(pos - state[2]) < 1.0, 1.0, -0.1))
        count = state[3] + jnp.all(actions == 2).astype(jnp.float32)
        reward = jnp.where(count >= COUNT, BAD, reward)
        return state.at[:2].set(pos).at[3].set(count), state[2] - pos, reward

@dataclasses.dataclass
class SeekSection:
    name: str = "rare-nan-seek-test"

register_env("rare-nan-seek-test", SeekSection, lambda s, cfg: (Seek(), SeekParams()))
"""


@pytest.mark.parametrize("bad", ["NaN", "infinite"])
def test_nan_rewards_only_the_search_reaches_are_refused(tmp_path, capsys, monkeypatch, bad):
    """A NaN reward, or rewards whose return passes float32 (each finite), that
    ``check_simulator``'s random episodes miss but the search's candidates reach: refused when
    the search ends, naming the simulator and the first iteration whose value is NaN (or
    infinite: the run ended in an internal error after writing results.json); no results are
    written."""
    monkeypatch.setattr(registry, "_FOREIGN_CODE", {})
    module = tmp_path / "rare_nan_seek.py"
    count, reward = ("5.0", "jnp.nan") if bad == "NaN" else ("4.0", "3e38")
    module.write_text(RARE_NAN_SEEK.replace("COUNT", count).replace("BAD", reward))
    toml = tmp_path / "seek.toml"
    toml.write_text(
        '[experiment]\nalgorithm = "cogdice"\n[env]\nname = "rare-nan-seek-test"\n'
        "[algorithm]\nnodes = 2\niterations = 20\nsamples = 20\nelites = 5\n"
        "eval_rollouts = 10\nbest_rollouts = 10\n[evaluation]\nrollouts = 200\n"
    )
    out = tmp_path / "run"
    args = ["--import", str(module), "train", str(toml), "--out", str(out), "--no-progress"]
    assert cli.main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "simulator 'rare-nan-seek-test'" in err and f"value is {bad} at iteration" in err, err
    assert not (out / "results.json").exists()


def test_results_are_written_as_strict_json_whatever_numbers_they_hold(tmp_path):
    import numpy as np

    from cognet_jax.atomic_files import atomic_write_json, plain

    value = {"a": np.int64(4), "b": (np.float32(0.5), float("inf")), "c": np.zeros((1, 2))}
    assert plain(value) == {"a": 4, "b": [0.5, None], "c": [[0.0, 0.0]]}
    atomic_write_json(tmp_path / "r.json", {"nan": np.float64("nan")})
    assert json.loads((tmp_path / "r.json").read_text()) == {"nan": None}
    with pytest.raises(TypeError):
        atomic_write_json(tmp_path / "s.json", {"set": {1}})


def test_a_stopped_overwrite_leaves_the_replaced_run_readable(tmp_path, capsys, monkeypatch):
    """``train --overwrite`` stopped after its first checkpoint: the replaced run's
    results.json and policy stay as they were (the stop wrote the new run's interrupted
    results over them), the new checkpoint beside them with ``.replacing``; ``--resume``
    finishes the new run, which then replaces the old one."""
    import signal

    from cognet_jax import driver
    from cognet_jax.signals import install_stop_handlers

    out = tmp_path / "run"
    assert cli.main(["train", "--out", str(out), *TINY_TRAIN]) == 0
    old = {n: (out / n).read_bytes() for n in ("results.json", "policy.msgpack")}
    saved = driver.save_group

    def save_then_stop(*args):
        saved(*args)
        os.kill(os.getpid(), signal.SIGTERM)  # the stop handler raises at the next check

    monkeypatch.setattr(driver, "save_group", save_then_stop)
    previous = signal.getsignal(signal.SIGTERM)
    install_stop_handlers()
    longer = [*TINY_TRAIN, "--set", "algorithm.iterations=6", "--checkpoint-every", "1"]
    try:
        args = ["train", "--out", str(out), "--seed", "1", "--overwrite", *longer]
        code = cli.main(args)
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert code == 128 + signal.SIGTERM
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "beside the results of the run it replaces" in err, err
    assert {n: (out / n).read_bytes() for n in old} == old
    assert (out / ".replacing").exists()
    monkeypatch.setattr(driver, "save_group", saved)
    assert cli.main(["train", "--resume", str(out), "--no-progress"]) == 0
    assert json.loads((out / "results.json").read_text())["seed"] == 1
    assert not (out / ".replacing").exists()


def test_a_stopped_sweep_overwrite_is_resumed_and_then_replaces_the_old_run(tmp_path):
    """``sweep --overwrite`` of a train's folder stopped after a group state: ``.replacing``
    stays (it was removed, so the resumed sweep left the old train's results and policy beside
    its tables); the resume removes the replaced files it recorded and keeps its own."""
    out = tmp_path / "run"
    out.mkdir()
    (out / "results.json").write_text("{}")
    (out / "policy.msgpack").write_bytes(b"old")
    (out / "evaluations.jsonl").write_text('{"mean": 1.0}\n')
    with pytest.raises(KeyboardInterrupt):
        with claim(out, overwrite=True, kind="sweep"):
            (out / "sweep-state").mkdir()
            (out / "sweep-state" / "group0-p0.checkpoint.msgpack").write_bytes(b"new")
            raise KeyboardInterrupt
    assert (out / ".replacing").exists() and (out / "results.json").exists()
    with claim(out, resume=True, kind="sweep"):
        (out / "runs.json").write_text("{}")  # the sweep's tables, written at its end
    assert not (out / "results.json").exists() and not (out / "policy.msgpack").exists()
    assert not (out / "evaluations.jsonl").exists() and not (out / ".replacing").exists()
    assert (out / "sweep-state" / "group0-p0.checkpoint.msgpack").read_bytes() == b"new"


def test_train_resume_of_a_sweep_names_sweep_resume(tmp_path, capsys):
    """``train --resume`` of a sweep's folder or of one of its run folders: one line naming
    ``sweep --resume`` and the sweep (it said "no checkpoint at ...")."""
    sweep = tmp_path / "sw"
    run = sweep / "runs" / "setting0-seed0"
    run.mkdir(parents=True)
    (sweep / "sweep.json").write_text("{}")
    (sweep / "runs.json").write_text("{}")
    (run / "results.json").write_text("{}")
    for folder, what in ((sweep, "is the sweep"), (run, "is a run of the sweep")):
        assert cli.main(["train", "--resume", str(folder)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and what in err[0] and f"sweep --resume {sweep}" in err[0], err
