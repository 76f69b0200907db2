"""Sweeps: one compiled program for seeds x numeric settings, equal to the single runs; grouping
of shape-changing settings; outputs; the same table on 2 devices and from 2 processes."""

import csv
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import jax
import numpy as np
import pytest
from flax.serialization import msgpack_restore
from shared_files import compile_cache_env

from cognet_jax.checkpoint import read_checkpoint
from cognet_jax.cli import main
from cognet_jax.config import ConfigError
from cognet_jax.driver import train as run_training
from cognet_jax.registry import load_config
from cognet_jax.sweep import assign_runs, parse_grid, plan
from cognet_jax.sweep_repeats import same_runs, same_runs_lines

ROOT = Path(__file__).parents[1]
SMALL = [
    "algorithm.iterations=4",
    "algorithm.rollouts=200",
    "algorithm.top=20",
    "algorithm.keep=5",
    "algorithm.eval_rollouts=20",
    "network.train_steps=5",
    "evaluation.rollouts=300",
    "env.obs_noise=0.3",  # shared env params stay constants of the program
]
GRID = ["--grid", "algorithm.alpha=0.1,0.4"]


def _sweep_args(out, seeds=3):
    args = ["sweep", "tagging-thesis-spec-n3", "--seeds", str(seeds), *GRID, "--out", str(out)]
    args += [a for s in SMALL for a in ("--set", s)] + ["--no-progress"]
    return args + ["--cpu-devices", "1"]  # (ignored where XLA_FLAGS sets the count)


@pytest.fixture(scope="module")
def one_process(tmp_path_factory):
    out = tmp_path_factory.mktemp("sweep1")
    assert main(_sweep_args(out)) == 0
    return out, json.loads((out / "runs.json").read_text())


def _table(result):
    """The comparable part of every row: setting, seed, honest value, per-iteration values."""
    return [
        (
            r["setting"],
            r["seed"],
            r["final_value"]["mean"],
            r["final_value"]["stderr"],
            r["in_loop_best"],
            tuple(r["values_per_iteration"]),
        )
        for r in result["rows"]
    ]


def test_sweep_equals_single_runs_exactly(one_process, tmp_path):
    """Each run of the sweep is the single run with its seed and alpha, number for number.

    Exact (not to a tolerance): a run's computation inside ``vmap`` is the same sequence of
    float32 operations on the same keys as the single run, and on this problem (rewards -1, -20,
    +50, gamma 1) every return and every mean over rollouts is exact in float32, so no
    reduction-order difference can show; on other problems allow float tolerance."""
    out, result = one_process
    rows = result["rows"]
    assert [(r["setting"], r["seed"]) for r in rows] == [(a, s) for a in (0, 1) for s in (0, 1, 2)]
    assert result["settings"] == [{"algorithm.alpha": 0.1}, {"algorithm.alpha": 0.4}]
    assert len(result["groups"]) == 1  # one compiled program for all six runs
    for row in rows:
        alpha = result["settings"][row["setting"]]["algorithm.alpha"]
        config = load_config(
            "tagging-thesis-spec-n3",
            SMALL + [f"algorithm.alpha={alpha}", "run.plots=false", "run.progress=false"],
        )
        single_dir = tmp_path / f"{alpha}-{row['seed']}"
        single = run_training(config, row["seed"], single_dir, log=print)
        assert row["final_value"] == single["final_value"]
        # the run's own folder holds the same best policy (network weights to float32
        # rounding: batched training may sum gradients in another order)
        folder = out / "runs" / f"setting{row['setting']}-seed{row['seed']}"
        # policy files: a header (format, version, checksum) around the policy's own msgpack
        swept = msgpack_restore(msgpack_restore((folder / "policy.msgpack").read_bytes())["policy"])
        alone = msgpack_restore(
            msgpack_restore((single_dir / "policy.msgpack").read_bytes())["policy"]
        )
        assert jax.tree.structure(swept) == jax.tree.structure(alone)
        for a, b in zip(jax.tree.leaves(swept), jax.tree.leaves(alone)):
            np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6)
        stored = json.loads((folder / "results.json").read_text())
        assert stored["status"] == "complete" and stored["final_value"] == single["final_value"]
        assert row["values_per_iteration"] == single["values_per_iteration"]
        assert row["in_loop_best_per_iteration"] == single["in_loop_best_per_iteration"]
        assert row["in_loop_best"] == single["in_loop_best"]
    # the settings really differ (alpha reaches the compiled program as data)
    assert rows[0]["values_per_iteration"] != rows[3]["values_per_iteration"]


def test_sweep_outputs(one_process):
    out, result = one_process
    with (out / "runs.csv").open() as f:
        table = list(csv.DictReader(f))
    assert len(table) == 6
    assert [float(r["algorithm.alpha"]) for r in table] == [0.1] * 3 + [0.4] * 3
    assert float(table[4]["final_mean"]) == result["rows"][4]["final_value"]["mean"]
    summary = (out / "summary.md").read_text()
    finals = [r["final_value"]["mean"] for r in result["rows"][:3]]
    se = np.std(finals, ddof=1) / np.sqrt(3)
    assert f"| algorithm.alpha=0.1 | 3 | {np.mean(finals):.3f} +- {se:.3f} |" in summary
    assert (out / "values.png").stat().st_size > 1000
    assert "Note:" not in summary  # alpha changes the numbers: no setting repeats another
    # every run's folder works with `cognet-jax evaluate` (here under observation noise)
    run_dir = out / "runs" / "setting1-seed2"
    args = ["evaluate", str(run_dir), "--rollouts", "50", "--set", "env.obs_noise=0.5"]
    assert main(args) == 0
    logged = json.loads((run_dir / "evaluations.jsonl").read_text().splitlines()[-1])
    assert logged["rollouts"] == 50 and np.isfinite(logged["mean"])


def test_plan_groups_shape_changing_settings():
    grid = parse_grid(["algorithm.nodes=2,3", "algorithm.alpha=0.1,0.2", "env.obs_noise=0,0.5"])
    groups = plan("tagging-thesis-spec-n3", grid, ["algorithm.iterations=2"])
    assert len(groups) == 2  # nodes changes shapes; alpha and noise are data
    assert [len(g.settings) for g in groups] == [4, 4]
    assert {g.settings[0].config.algorithm.nodes for g in groups} == {2, 3}
    total = assign_runs(groups, [0, 1, 2], process=1, processes=2)
    assert total == 24
    assert sum(len(g.runs) for g in groups) == 12


def test_grid_errors_name_the_field():
    with pytest.raises(ConfigError, match="algorithm.alpha"):
        parse_grid(["algorithm.alpha=0.1", "algorithm.alpha=0.2"])
    with pytest.raises(ConfigError, match="algorithm.alpha"):
        plan("tagging-thesis-spec-n3", parse_grid(["algorithm.alpha=0.1,7"]), [])
    with pytest.raises(ConfigError, match="algorithm.nodez"):
        plan("tagging-thesis-spec-n3", parse_grid(["algorithm.nodez=2"]), [])
    assert main(["sweep", "--seeds", "0"]) == 2


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _env(devices: int = 1) -> dict:
    env = dict(os.environ, PYTHONPATH=str(ROOT), JAX_PLATFORMS="cpu")
    flags = f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count={devices}"
    env["XLA_FLAGS"] = flags.strip()  # (the suite's JAX settings kept: conftest.py)
    return env


def _on_devices(devices: int, args: list[str]) -> subprocess.CompletedProcess:
    """``python ARGS`` in a process whose CPU is split into ``devices`` JAX devices."""
    return subprocess.run(
        [sys.executable, *args], env=_env(devices), capture_output=True, text=True, timeout=600
    )


def test_two_devices_same_table(one_process, tmp_path):
    """The 6 runs sharded over a 2-device mesh (NamedSharding): the same numbers."""
    _, result = one_process
    code = (
        "import sys, jax; assert jax.local_device_count() == 2; "
        "from cognet_jax.cli import main, set_up_process; set_up_process(); "
        "sys.exit(main(sys.argv[1:]))"
    )
    out = tmp_path / "dev2"
    proc = _on_devices(2, ["-c", code, *_sweep_args(out)])
    assert proc.returncode == 0, proc.stderr[-3000:]
    sharded = json.loads((out / "runs.json").read_text())
    assert sharded["local_devices"] == 2
    assert _table(sharded) == _table(result)


def test_two_processes_same_table(one_process, tmp_path):
    """2 processes on localhost (jax.distributed, CPU collectives), each with 2 devices and 3
    of the 6 runs (padded to 4 on its mesh): process 0 gathers a table equal to the
    single-process one; process 1 writes no table."""
    _, result = one_process
    port = _free_port()
    outs = [tmp_path / f"p{i}" for i in range(2)]
    procs = [
        subprocess.Popen(
            [sys.executable, "-m", "cognet_jax", *_sweep_args(outs[i])]
            + ["--coordinator", f"127.0.0.1:{port}", "--num-processes", "2"]
            + ["--process-id", str(i)],
            env=_env(2),
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        for i in range(2)
    ]
    logs = [p.communicate(timeout=600)[0] for p in procs]
    assert [p.returncode for p in procs] == [0, 0], "\n".join(x[-3000:] for x in logs)
    gathered = json.loads((outs[0] / "runs.json").read_text())
    assert gathered["processes"] == 2 and gathered["local_devices"] == 2
    assert [g["runs"] for g in gathered["groups"]] == [3]  # process 0's share
    assert not (outs[1] / "runs.json").exists()  # process 1 keeps only its sweep-state
    assert _table(gathered) == _table(result)


def test_process_0_waiting_for_its_peers_obeys_a_stop(tmp_path):
    """Process 0 of a multi-process sweep whose peer never starts waits in
    ``jax.distributed.initialize`` (a native call that held SIGTERM until JAX's own timeout
    aborted the process two minutes later): a SIGTERM ends it at once, status 143."""
    port = _free_port()
    args = [sys.executable, "-m", "cognet_jax", *_sweep_args(tmp_path / "p0")]
    args += ["--coordinator", f"127.0.0.1:{port}", "--num-processes", "2", "--process-id", "0"]
    proc = subprocess.Popen(args, env=_env(2), stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 120
    while time.time() < deadline:  # the coordination service listens once it waits
        with socket.socket() as probe:
            if probe.connect_ex(("127.0.0.1", port)) == 0:
                break
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.1)
    time.sleep(1.0)
    t0 = time.time()
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert time.time() - t0 < 15, err[-2000:]
    assert proc.returncode == 128 + signal.SIGTERM, err[-2000:]


def test_a_cluster_process_waiting_for_its_coordinator_obeys_a_stop(tmp_path):
    """``--cluster`` under a SLURM job whose coordinator never starts: process 1 waits in
    ``jax.distributed.initialize``; a SIGTERM ends it at once, status 143 (it ran in the
    main thread, where the native wait held the signal)."""
    args = [sys.executable, "-m", "cognet_jax", *_sweep_args(tmp_path / "p1"), "--cluster"]
    slurm = {"SLURM_JOB_ID": "4242", "SLURM_NTASKS": "2", "SLURM_PROCID": "1"}
    slurm |= {"SLURM_LOCALID": "0", "SLURM_STEP_NODELIST": "localhost"}
    proc = subprocess.Popen(args, env={**_env(2), **slurm}, stderr=subprocess.PIPE, text=True)
    try:
        time.sleep(8.0)  # imports, then the wait
        assert proc.poll() is None, proc.communicate()
        t0 = time.time()
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert time.time() - t0 < 15, err[-2000:]
    assert proc.returncode == 128 + signal.SIGTERM, err[-2000:]


TINY = [
    "algorithm.iterations=300",
    "algorithm.rollouts=40",
    "algorithm.top=8",
    "algorithm.keep=3",
    "algorithm.eval_rollouts=8",
    "network.train_steps=2",
    "evaluation.rollouts=200",
]


def _tiny_args(out):
    args = ["sweep", "tagging-thesis-spec-n3", "--seeds", "2", "--grid", "algorithm.alpha=0.1,0.3"]
    args += [a for s in TINY for a in ("--set", s)] + ["--cpu-devices", "1"]
    return args + ["--out", str(out), "--no-progress"]


@pytest.fixture(scope="module")
def tiny_reference(tmp_path_factory):
    """The uninterrupted tiny sweep the interrupted ones are compared with."""
    out = tmp_path_factory.mktemp("tiny-reference")
    assert main(_tiny_args(out)) == 0
    return json.loads((out / "runs.json").read_text())


def _start_until_checkpoint(out, every):
    """Start a tiny sweep in a subprocess checkpointing every ``every`` iterations; return it
    and its checkpoint path once the first checkpoint exists."""
    env = _env(1)
    env.update(compile_cache_env())
    proc = subprocess.Popen(
        [sys.executable, "-m", "cognet_jax", *_tiny_args(out), "--checkpoint-every", str(every)],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    ckpt = out / "sweep-state" / "group0-p0.checkpoint.msgpack"
    t0 = time.time()
    while not ckpt.exists():
        assert proc.poll() is None, proc.communicate()
        assert time.time() - t0 < 300, "no checkpoint appeared"
        time.sleep(0.02)
    return proc, ckpt


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_signal_then_resume_is_identical(tiny_reference, tmp_path, sig):
    """Ctrl-C (or SIGTERM) mid-sweep leaves a checkpoint of every run's state and exits with
    128 + the signal, as ``train`` does; --resume finishes the sweep with exactly the numbers
    of an uninterrupted sweep."""
    out, reference = tmp_path / "cut", tiny_reference
    proc, ckpt = _start_until_checkpoint(out, 10)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 128 + sig, err
    assert "interrupted at iteration" in err and f"--resume {out}" in err
    raw = read_checkpoint(ckpt)
    assert 10 <= raw["iteration"] < 300
    assert np.asarray(raw["state"]["progress"]["iteration"]).tolist() == [raw["iteration"]] * 4
    assert not (out / "runs.json").exists()
    # the best policy so far of every run is written on Ctrl-C
    for setting in (0, 1):
        for seed in (0, 1):
            folder = out / "runs" / f"setting{setting}-seed{seed}"
            assert (folder / "policy.msgpack").stat().st_size > 0
            stored = json.loads((folder / "results.json").read_text())
            assert stored["status"] == "interrupted" and stored["iteration"] == raw["iteration"]
    assert main(["sweep", "--resume", str(out), "--no-progress"]) == 0
    resumed = json.loads((out / "runs.json").read_text())
    assert resumed["groups"][0]["resumed_from_iteration"] == raw["iteration"]
    assert _table(resumed) == _table(reference)


def test_sigkill_leaves_an_intact_checkpoint_then_resume_is_identical(tiny_reference, tmp_path):
    """A sweep killed without warning (SIGKILL) keeps its last checkpoint intact (atomic
    writes: it parses and its history is a prefix of the uninterrupted sweep's); --resume
    finishes with exactly the numbers of an uninterrupted sweep."""
    out, reference = tmp_path / "cut", tiny_reference
    proc, ckpt = _start_until_checkpoint(out, 5)
    t0 = time.time()
    first = read_checkpoint(ckpt)["iteration"]
    while read_checkpoint(ckpt)["iteration"] < first + 20 and time.time() - t0 < 300:
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.01)
    proc.kill()
    proc.wait(timeout=60)
    assert proc.returncode == -signal.SIGKILL
    raw = read_checkpoint(ckpt)
    n = raw["iteration"]
    assert n % 5 == 0 and first + 20 <= n < 300
    values = np.asarray(raw["history"]["value"]).T  # stored [iterations, runs]
    expected = [r["values_per_iteration"][:n] for r in reference["rows"]]
    assert np.array_equal(values, np.float32(expected))
    leftovers = [p.name for p in ckpt.parent.iterdir() if p.name.endswith(".tmp")]
    assert len(leftovers) <= 1  # at most the temp file the kill interrupted
    assert main(["sweep", "--resume", str(out), "--no-progress"]) == 0
    resumed = json.loads((out / "runs.json").read_text())
    assert resumed["groups"][0]["resumed_from_iteration"] == n
    assert _table(resumed) == _table(reference)


def test_env_params_grid_equals_single_runs(tmp_path):
    """A grid over an env param (noise 0 and 0.3) batches the env params as data: zero noise
    then runs through the select of ``scaled_normal``, and every run still equals its single
    run (noise 0.3's is a single run of the test above)."""
    sets = SMALL[:-1] + ["algorithm.alpha=0.1"]
    out = tmp_path / "sweep"
    args = ["sweep", "tagging-thesis-spec-n3", "--seeds", "1", "--grid", "env.obs_noise=0,0.3"]
    args += [a for x in sets for a in ("--set", x)] + ["--out", str(out), "--no-progress"]
    assert main(args + ["--cpu-devices", "1"]) == 0
    rows = json.loads((out / "runs.json").read_text())["rows"]
    for row, noise in zip(rows, (0, 0.3)):
        config = load_config(
            "tagging-thesis-spec-n3",
            sets + [f"env.obs_noise={noise}", "run.plots=false", "run.progress=false"],
        )
        single = run_training(config, 0, tmp_path / f"n{noise}", log=lambda *_: None)
        assert row["final_value"] == single["final_value"]
        assert row["values_per_iteration"] == single["values_per_iteration"]
    assert rows[0]["values_per_iteration"] != rows[1]["values_per_iteration"]


def test_summary_reports_exact_values_of_tabular_runs(tmp_path):
    """Sweeps of .dpomdp problems carry each best policy's exact value into runs.csv and
    summarise it per setting (mean, min, max over seeds)."""
    from cognet_jax.sweep import write_outputs

    def row(setting, seed, exact):
        return {
            "setting": setting,
            "seed": seed,
            "group": 0,
            "grid": {"algorithm.alpha": [0.1, 0.2][setting]},
            "final_value": {
                "mean": exact + 0.01,
                "stderr": 0.02,
                "rollouts": 100,
                "exact": exact - 0.001,
                "exact_infinite": exact,
            },
            "in_loop_best": exact + 0.5,
            "values_per_iteration": [exact, exact],
            "in_loop_best_per_iteration": [exact, exact],
        }

    result = {
        "experiment": "gdice-dpomdp",
        "seeds": [0, 1, 2],
        "groups": [[0, 1]],
        "wall_s": 1.0,
        "grid": {"algorithm.alpha": [0.1, 0.2]},
        "settings": [{"algorithm.alpha": 0.1}, {"algorithm.alpha": 0.2}],
        "rows": [row(0, 0, 31.0), row(0, 1, 32.0), row(0, 2, 33.5), row(1, 0, 5.0)]
        + [row(1, 1, 5.0), row(1, 2, 5.0)],
    }
    write_outputs(result, tmp_path)
    table = list(csv.DictReader((tmp_path / "runs.csv").open()))
    assert float(table[2]["final_exact_infinite"]) == 33.5
    assert float(table[2]["final_exact"]) == pytest.approx(33.499)
    summary = (tmp_path / "summary.md").read_text()
    # a column per field the search added (G-DICE's exact values), whatever their names
    assert "| in-loop best | exact | exact_infinite |" in summary
    assert "| 32.165667 [30.999000, 33.499000] | 32.166667 [31.000000, 33.500000] |" in summary
    assert "| 5.000000 [5.000000, 5.000000] |" in summary
    assert (tmp_path / "values.png").is_file()  # run.plots true where the config is silent
    plotless = tmp_path / "plotless"
    written = write_outputs({**result, "config": {"run": {"plots": False}}}, plotless)
    assert not (plotless / "values.png").exists() and written[-1].name == "summary.md"
    assert "(100 rollouts, the seed's eval key)" in summary
    result["rows"][3]["final_value"] = {**result["rows"][3]["final_value"], "rollouts": 1000}
    write_outputs(result, plotless)  # evaluation.rollouts in the grid: each setting its own
    assert "(100 to 1000 rollouts by setting" in (plotless / "summary.md").read_text()


def test_many_runs_are_stacked_in_chunks_to_the_same_arrays():
    """A sweep's per-run arrays (keys, hyper-parameters, simulator params) are stacked in
    chunks (``program._stacked``: one stack of thousands compiled for seconds): the same
    array, dtype and weak type as one ``jnp.stack``, typed PRNG keys included."""
    import jax.numpy as jnp

    from cognet_jax.program import STACK_CHUNK, _stacked

    n = STACK_CHUNK * 3 + 5
    for xs in (
        [jax.random.key(s) for s in range(n)],
        [0.1 * s for s in range(n)],
        [jnp.full((2, 3), s, jnp.int32) for s in range(n)],
    ):
        whole, chunked = jnp.stack([jnp.asarray(x) for x in xs]), _stacked(xs)
        assert chunked.dtype == whole.dtype and chunked.shape == whole.shape
        assert getattr(chunked, "weak_type", 0) == getattr(whole, "weak_type", 0)
        if jax.dtypes.issubdtype(whole.dtype, jax.dtypes.prng_key):
            whole, chunked = jax.random.key_data(whole), jax.random.key_data(chunked)
        np.testing.assert_array_equal(np.asarray(chunked), np.asarray(whole))


def test_a_sweep_is_sized_before_its_runs_are_prepared(capsys):
    """Over 1000 runs: one line with the estimate; runs that together simulate for over a
    week: refused naming the larger factor, before any run is built."""
    from cognet_jax.sweep_size import size_sweep

    size_sweep("tagging-thesis-n3", [], 2000, 2000)
    line = capsys.readouterr().err
    assert line.startswith("sweep: 2000 runs (1 settings x 2000 seeds), at least ")
    assert line.rstrip().endswith("of simulation; preparing them ...")
    size_sweep("tagging-thesis-n3", [], 4, 4)
    assert capsys.readouterr().err == ""
    with pytest.raises(ConfigError, match="'grid'.*10000 settings x 10 seeds.*days together"):
        size_sweep("tagging-thesis-n3", ["algorithm.iterations=100000"], 10, 100_000)


def test_the_honest_evaluation_of_several_runs_shows_its_progress(capsys):
    """``after_search.FinishLine``: a line of runs evaluated when there are several runs and
    progress is on; none for one run or without progress; none started after ``close``."""
    from cognet_jax.after_search import FinishLine

    line = FinishLine(True, algorithm=None)
    line.evaluating(3)
    for _ in range(3):
        line.evaluated()
    line.close()
    shown = capsys.readouterr().err.replace("\r", "\n")
    assert "honest evaluation" in shown and "3/3" in shown
    for progress, runs in ((True, 1), (False, 3)):
        quiet = FinishLine(progress, algorithm=None)
        quiet.evaluating(runs)
        quiet.evaluated()
        quiet.close()
    line.evaluating(3)  # closed: a worker left running after a stop starts no new line
    line.evaluated()
    assert "honest evaluation" not in capsys.readouterr().err


def test_a_damaged_sweep_state_is_named_not_published(tmp_path):
    """``sweep --resume`` of a sweep.json whose grid, seeds or overrides were edited into
    other types, or of a rows file with a NaN honest value or runs missing: the file is named
    (``CorruptFileError``), nothing is published and no internal error escapes."""
    from cognet_jax.errors import CorruptFileError
    from cognet_jax.sweep import _check_rows, _check_spec

    spec = {"experiment": "x", "grid": {"algorithm.alpha": [0.1]}, "seeds": [0, 1]}
    spec["overrides"] = []
    _check_spec(spec, tmp_path / "sweep.json")
    for field, value in (
        ("experiment", 5),
        ("experiment", ""),
        ("grid", {"algorithm.alpha": []}),
        ("grid", 5),
        ("grid", {"algorithm.alpha": 0.3}),
        ("seeds", [-1, 0]),
        ("seeds", []),
        ("overrides", "run.plots=false"),
    ):
        with pytest.raises(CorruptFileError, match=f"sweep.json.*{field}"):
            _check_spec({**spec, field: value}, tmp_path / "sweep.json")
    row = {"final_value": {"mean": 1.0, "stderr": 0.1, "rollouts": 10}}
    _check_rows([row, row], 2, tmp_path / "rows.json")
    nan = {"final_value": {"mean": float("nan"), "stderr": 0.1, "rollouts": 10}}
    for rows in ([row, nan], [row], [row, {"final_value": None}], [row, "x"]):
        with pytest.raises(CorruptFileError, match="rows.json"):
            _check_rows(rows, 2, tmp_path / "rows.json")


def test_a_resumed_sweep_writes_again_the_run_folders_deleted_since(tmp_path):
    """A finished sweep whose run folder was deleted by hand: ``--resume`` runs that group
    again from its checkpoint, to the same numbers, and the folder is back (it said before
    that the runs' policies were there)."""
    import shutil

    out = tmp_path / "sweep"
    args = ["sweep", "tagging-thesis-n3", "--seeds", "2", "--out", str(out), "--no-progress"]
    args += ["--set", "algorithm.iterations=3", "--set", "run.plots=false"]
    assert main(args) == 0
    first = json.loads((out / "runs.json").read_text())["rows"]
    folder = out / "runs" / "setting0-seed1"
    shutil.rmtree(folder)
    assert main(["sweep", "--resume", str(out), "--no-progress"]) == 0
    assert (folder / "results.json").is_file() and (folder / "policy.msgpack").is_file()
    again = json.loads((out / "runs.json").read_text())["rows"]
    assert [r["final_value"] for r in again] == [r["final_value"] for r in first]


def test_a_group_over_the_memory_budget_runs_in_batches_to_the_same_numbers(tmp_path, capsys):
    """Six runs whose iteration side by side needs more than ``run.memory_gb``: run in two
    batches of three (one line says so), to the numbers of the group run at once; a resumed
    sweep keeps the finished batch and runs the other again, without compiling the whole
    group (its batch size is stored)."""
    import shutil

    bigger = ["--set", "algorithm.rollouts=1000"]
    whole, batched = tmp_path / "whole", tmp_path / "batched"
    assert main(_sweep_args(whole) + bigger) == 0
    capsys.readouterr()
    assert main(_sweep_args(batched) + bigger + ["--set", "run.memory_gb=0.001"]) == 0
    said = "".join(capsys.readouterr())
    assert "over the memory budget of 0.001 GB (run.memory_gb): running them in 2 batches" in said
    reference = _table(json.loads((whole / "runs.json").read_text()))
    result = json.loads((batched / "runs.json").read_text())
    assert _table(result) == reference
    assert result["groups"][0]["batches"] == 2 and result["groups"][0]["runs"] == 6
    # the second batch's rows and one of its folders lost: --resume runs that batch only
    (batched / "sweep-state" / "group0-p0-b1of3.rows.json").unlink()
    shutil.rmtree(batched / "runs" / "setting1-seed2")
    assert main(["sweep", "--resume", str(batched), "--no-progress"]) == 0
    said = "".join(capsys.readouterr())
    assert "(6 runs)" not in said and "running them in" not in said
    assert _table(json.loads((batched / "runs.json").read_text())) == reference


def test_a_checkpoint_resumes_on_another_number_of_devices(tmp_path):
    """Three runs checkpointed on one device (3 lanes) resume on two (padded to 4 lanes): the
    padding is laid out again from the last run's state, to the same numbers (the resume was
    refused: state ... is float32[3, ...], the run's is float32[4, ...])."""
    import shutil

    out = tmp_path / "sweep"
    args = ["sweep", "tagging-thesis-spec-n3", "--seeds", "3", "--out", str(out)]
    args += [a for s in [*TINY, "algorithm.iterations=20"] for a in ("--set", s)]
    assert main([*args, "--no-progress", "--cpu-devices", "1"]) == 0
    first = _table(json.loads((out / "runs.json").read_text()))
    assert json.loads((out / "runs.json").read_text())["local_devices"] == 1
    (out / "sweep-state" / "group0-p0.rows.json").unlink()  # the search's final checkpoint stays
    shutil.rmtree(out / "runs" / "setting0-seed2")
    proc = _on_devices(2, ["-m", "cognet_jax", "sweep", "--resume", str(out), "--no-progress"])
    assert proc.returncode == 0, proc.stderr[-3000:]
    again = json.loads((out / "runs.json").read_text())
    assert again["local_devices"] == 2 and again["groups"][0]["resumed_from_iteration"] == 20
    assert _table(again) == first


def test_settings_that_repeat_another_settings_runs_are_named():
    def row(setting, seed, value):
        final = {"mean": value, "stderr": 0.1, "rollouts": 10}
        return {"setting": setting, "seed": seed, "final_value": final, "in_loop_best": value,
                "values_per_iteration": [value, value]}  # fmt: skip

    rows = [row(0, 0, 1.0), row(0, 1, 2.0), row(1, 0, 1.0), row(1, 1, 2.0)]
    rows += [row(2, 0, 1.0), row(2, 1, 2.5)]  # one seed differs: another search
    assert same_runs(rows) == [(1, 0)]
    settings = [{"algorithm.a": 1, "algorithm.b": 0}, {"algorithm.a": 2, "algorithm.b": 0}]
    (line,) = same_runs_lines(rows, [*settings, {"algorithm.a": 3, "algorithm.b": 0}])
    assert line.startswith("setting 1 (algorithm.a=2, algorithm.b=0) gave the numbers of setting 0")
    assert "algorithm.a changed nothing this search computes" in line


def test_a_grid_over_a_field_switched_off_warns_and_notes_it(tmp_path, capsys):
    args = ["sweep", "tagging-thesis-n3", "--seeds", "1", "--out", str(tmp_path / "s")]
    args += ["--set", "algorithm.iterations=2", "--set", "algorithm.polish_share=0"]
    args += ["--set", "run.plots=false", "--grid", "algorithm.polish_extend=1.0,2.0"]
    assert main([*args, "--no-progress", "--cpu-devices", "1"]) == 0
    err = capsys.readouterr().err
    said = "setting 1 (algorithm.polish_extend=2.0) gave the numbers of setting 0"
    assert err.count(said) == 1  # said once, when the second group ended
    assert said in (tmp_path / "s" / "summary.md").read_text()


def test_a_gdice_sweep_polishes_each_run_as_its_single_run_does(tmp_path):
    """G-DICE's polish branches between sweeps and best responses (``finish_per_run``): a
    sweep runs it one run after another, each run's own program (side by side, ``vmap`` made
    every step compute both branches: Mars rovers at h 5, 564 s for one step of two runs
    against 5 - 8 s for a run's whole polish), to the numbers of the single runs."""
    from shared_files import dpomdp_file

    model = dpomdp_file("dectiger")
    sets = [f"problem.path={model}", "problem.horizon=4", "algorithm.iterations=6"]
    sets += ["algorithm.samples=50", "run.plots=false"]
    args = [a for s in sets for a in ("--set", s)] + ["--no-progress"]
    out = tmp_path / "sweep"
    sweep = ["sweep", "gdice-dpomdp", "--seeds", "3", "--out", str(out), "--cpu-devices", "2"]
    assert main([*sweep, *args]) == 0  # (two devices where XLA_FLAGS leave the count open)
    rows = json.loads((out / "runs.json").read_text())["rows"]
    assert all(r["finish"] is not None for r in rows)  # the polish ran
    for seed in (0, 2):
        single = tmp_path / f"single{seed}"
        argv = ["train", "gdice-dpomdp", "--seed", str(seed), "--out", str(single), *args]
        assert main(argv) == 0
        alone = json.loads((single / "results.json").read_text())
        (row,) = [r for r in rows if r["seed"] == seed]
        assert row["final_value"] == alone["final_value"]
        assert row["finish"]["value_after"] == alone["finish"]["value_after"]
