"""Bad input through the CLI: every case prints one line ``error: ...`` naming the field or the
file, exits with status 2, and shows no traceback (``--debug`` shows it)."""

import json
import shutil

import pytest

from cognet_jax.cli import main

TINY = [
    "algorithm.iterations=2",
    "algorithm.candidates=6",
    "algorithm.elites=2",
    "algorithm.eval_rollouts=8",
    "algorithm.best_rollouts=16",
    "evaluation.rollouts=50",
]
BAD_DPOMDP = """agents: 2
discount: 1
values: reward
states: 2
start:
uniform
actions:
2
2
observations:
2
2
T: * : 0 : 0 : 1.5
"""


def sets(*overrides):
    return [x for o in overrides for x in ("--set", o)]


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("cli") / "run"
    assert main(["train", "--out", str(out), "--no-progress", *sets(*TINY)]) == 0
    return out


def damaged_copy(run_dir, tmp_path, name, keep_bytes):
    copy = tmp_path / "copy"
    shutil.copytree(run_dir, copy)
    data = (copy / name).read_bytes()
    (copy / name).write_bytes(data[:keep_bytes])
    return copy


def one_line_error(capsys, argv, *expected, status=2):
    code = main(argv)
    err = capsys.readouterr().err.strip()
    assert code == status, (argv, err)
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    assert "Traceback" not in err
    for text in expected:
        assert text in lines[0], (text, lines[0])
    return lines[0]


@pytest.mark.parametrize(
    "overrides,field",
    [
        (["env.obs_noise=inf"], "env.obs_noise"),
        (["env.motion_noise=inf"], "env.motion_noise"),
        (["algorithm.alpha=nan"], "algorithm.alpha"),
        (["algorithm.nodes=0"], "algorithm.nodes"),
        (["algorithm.no_such_field=1"], "algorithm.no_such_field"),
        (["algorithm.nodes=x"], "algorithm.nodes"),
        (["env.obs_signal=2"], "env.obs_signal"),
    ],
)
def test_bad_config_values_name_the_field(capsys, tmp_path, overrides, field):
    out = tmp_path / "never"
    one_line_error(capsys, ["train", "--out", str(out), *sets(*overrides)], field)
    assert not out.exists()


def test_heatmap_noise_inf_and_gdice_negative_entropy_std(capsys, tmp_path):
    one_line_error(
        capsys, ["train", "heatmap-2d-n4", *sets("env.obs_noise_std=inf")], "env.obs_noise_std"
    )
    problem = tmp_path / "p.dpomdp"
    problem.write_text(BAD_DPOMDP)
    argv = ["train", "gdice-dpomdp", *sets(f'problem.path="{problem}"')]
    one_line_error(capsys, [*argv, *sets("algorithm.entropy_std=-5")], "algorithm.entropy_std")


def test_parse_error_names_file_and_line_and_leaves_no_folder(capsys, tmp_path):
    problem = tmp_path / "bad.dpomdp"
    problem.write_text(BAD_DPOMDP)
    out = tmp_path / "out"
    argv = ["train", "gdice-dpomdp", "--out", str(out), *sets(f'problem.path="{problem}"')]
    line = one_line_error(capsys, argv, f"{problem}:")
    assert ":13:" in line or ":14:" in line, line  # the T line
    assert not out.exists()
    with pytest.raises(ValueError):  # --debug: the exception itself
        main([*argv, "--debug"])


def test_directory_as_experiment_and_file_as_out(capsys, tmp_path):
    one_line_error(capsys, ["train", str(tmp_path) + "/"], str(tmp_path))
    blocker = tmp_path / "file"
    blocker.write_text("x")
    one_line_error(capsys, ["train", "--out", str(blocker), *sets(*TINY)], str(blocker))


def test_evaluate_refuses_bad_rollouts_and_mismatched_settings(capsys, run_dir):
    one_line_error(capsys, ["evaluate", str(run_dir), "--rollouts", "0"], "--rollouts")
    one_line_error(capsys, ["evaluate", str(run_dir), "--rollouts", "-3"], "--rollouts")
    one_line_error(
        capsys,
        ["evaluate", str(run_dir), *sets("algorithm.nodes=6")],
        "policy.msgpack",
        "other settings",
    )
    one_line_error(
        capsys, ["evaluate", str(run_dir), *sets('problem.path="other.dpomdp"')], "problem.path"
    )
    one_line_error(capsys, ["evaluate", str(run_dir.parent / "missing")], "missing")


@pytest.mark.parametrize("name,keep", [("policy.msgpack", 40), ("results.json", 30)])
def test_evaluate_reports_corrupt_files(capsys, run_dir, tmp_path, name, keep):
    copy = damaged_copy(run_dir, tmp_path, name, keep)
    one_line_error(capsys, ["evaluate", str(copy)], f"{copy / name}", "corrupt")


def test_resume_reports_a_corrupt_checkpoint(capsys, run_dir, tmp_path):
    copy = damaged_copy(run_dir, tmp_path, "checkpoint.msgpack", 100)
    one_line_error(capsys, ["train", "--resume", str(copy)], "checkpoint.msgpack", "corrupt")
    (copy / "checkpoint.msgpack").write_bytes(b"\x93\x01\x02\x03")  # valid msgpack, not ours
    one_line_error(capsys, ["train", "--resume", str(copy)], "checkpoint format")


def test_vae_arguments(capsys, tmp_path):
    one_line_error(capsys, ["vae", "train", "--epochs", "0", "--out", str(tmp_path)], "--epochs")
    one_line_error(
        capsys, ["vae", "train", "--kl-weight", "nan", "--out", str(tmp_path)], "--kl-weight"
    )


# -------------------------------------------------------------------------- models and policies
def test_cli_fuzz_of_mutated_model_files(capsys, tmp_path):
    """2,000 mutated copies of the benchmark files through ``cognet-jax inspect``: each either
    parses (exit 0) or prints exactly one ``error:`` line naming the file, exit 2."""
    import random
    from pathlib import Path

    from test_dpomdp_parser import _mutate

    folder = Path(__file__).resolve().parents[2] / "shared" / "dpomdp"
    names = ["dectiger", "broadcastChannel", "recycling", "GridSmall"]
    if not all((folder / f"{n}.dpomdp").is_file() for n in names):
        pytest.skip(f"benchmark files not found in {folder}")
    texts = {n: (folder / f"{n}.dpomdp").read_text() for n in names}
    rnd = random.Random(77)
    path = tmp_path / "m.dpomdp"
    outcomes = {0: 0, 2: 0}
    for i in range(2000):
        path.write_bytes(_mutate(texts[names[i % 4]], rnd).encode())
        code = main(["inspect", str(path)])
        out, err = capsys.readouterr()
        assert code in (0, 2), (code, err)
        outcomes[code] += 1
        errors = [line for line in err.splitlines() if not line.startswith("warning: ")]
        if code == 2:
            assert len(errors) == 1 and errors[0].startswith(f"error: {path}"), err
        else:
            assert errors == [] and out.startswith(str(path)), (out, err)
    assert outcomes[2] > 500 and outcomes[0] > 100, outcomes


@pytest.mark.parametrize("name", ["x.pgmx", "twoCorridors_2.toi-dpomdp.base"])
def test_other_madp_formats_are_refused(capsys, tmp_path, name):
    path = tmp_path / name
    path.write_text("<pgmx/>\n")
    one_line_error(capsys, ["inspect", str(path)], str(path), "not supported")


def test_model_defaults_that_would_decide_silently_are_errors(capsys, tmp_path):
    """No R: lines (every reward 0) and a file cut short before its rewards are written are
    one-line errors naming the file (and the last line), not warnings."""
    path = tmp_path / "w.dpomdp"
    path.write_text(
        BAD_DPOMDP.replace("T: * : 0 : 0 : 1.5\n", "T: * :\nuniform\nO: * :\nuniform\n")
    )
    one_line_error(capsys, ["inspect", str(path)], str(path), "no R: lines")
    text = path.read_text() + "R: 0 0 : 0 : * : * : 3"  # cut short: no final newline
    path.write_text(text)
    one_line_error(capsys, ["inspect", str(path)], str(path), "cut short", "7 of 8 rewards")


def test_policy_file_checksum_version_and_old_format(capsys, run_dir, tmp_path):
    import shutil

    from flax import serialization

    copy = tmp_path / "copy"
    shutil.copytree(run_dir, copy)
    policy = copy / "policy.msgpack"
    raw = serialization.msgpack_restore(policy.read_bytes())
    assert raw["format"] == "cognet-jax policy" and raw["version"] == 1
    body = bytearray(raw["policy"])
    body[len(body) // 2] ^= 0xFF  # a flipped bit inside, same length
    policy.write_bytes(serialization.msgpack_serialize({**raw, "policy": bytes(body)}))
    one_line_error(capsys, ["evaluate", str(copy)], "checksum")
    policy.write_bytes(serialization.msgpack_serialize({**raw, "version": 9}))
    one_line_error(capsys, ["evaluate", str(copy)], "version 9")
    policy.write_bytes(raw["policy"])  # written before the header existed: still read
    results = json.loads((copy / "results.json").read_text())
    del results["policy_sha256"]  # nor did its results.json hold the file's digest
    (copy / "results.json").write_text(json.dumps(results))
    assert main(["evaluate", str(copy), "--rollouts", "100"]) == 0


def test_second_hostile_round_refusals(capsys, tmp_path):
    """Inputs of the second hostile round: each one line naming what to fix, and a sweep
    refused after claiming its folder leaves no folder behind."""
    one_line_error(
        capsys,
        ["check", "tagging-thesis-n3", "--set", "algorithm.vote_first=true"],
        "algorithm.vote_first",
        "vote_alternate",
    )
    one_line_error(
        capsys,
        ["check", "tagging-thesis-n3", "--set", "algorithm.budget_minutes=0.5"],
        "algorithm.budget_minutes",
        "every size is given",
    )
    grid = ["--grid", "run.prng_impl=threefry2x32,rbg"]
    one_line_error(
        capsys, ["sweep", "tagging-thesis-n3", *grid, "--out", str(tmp_path / "g")], "run.prng_impl"
    )
    one_line_error(capsys, ["sweep", "tagging-thesis-n3", "--first-seed", "-1"], "--first-seed")
    for command in ("train", "sweep"):  # a run continued is never replaced at the same time
        resumed = [command, "--resume", str(tmp_path), "--overwrite"]
        one_line_error(capsys, resumed, "--overwrite cannot be given with --resume")
    out = tmp_path / "alpha"
    bad = ["--grid", "algorithm.alpha=0.1,2.0", "--out", str(out)]
    one_line_error(capsys, ["sweep", "tagging-thesis-n3", *bad], "algorithm.alpha")
    assert not out.exists()
    # more runs than a sweep prepares: refused before any per-run list exists (2**31 seeds
    # took 23 GB before), naming the seeds, or the grid when it is the grid that is large
    huge = ["--seeds", str(2**31), "--out", str(out)]
    one_line_error(capsys, ["sweep", "tagging-thesis-n3", *huge], "'seeds'")
    wide = ["--grid", "algorithm.alpha=" + ",".join(f"0.{k:03d}" for k in range(1, 501))]
    one_line_error(capsys, ["sweep", "tagging-thesis-n3", "--seeds", "201", *wide], "'grid'")
    assert not out.exists()


def test_a_closed_standard_output_is_an_error_not_silence():
    """``cognet-jax list >&-``: nothing can be shown, so exit 2 with one line on stderr."""
    import subprocess
    import sys

    done = subprocess.run(
        f"{sys.executable} -m cognet_jax list >&-",
        shell=True,
        capture_output=False,
        stderr=subprocess.PIPE,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2
    assert done.stderr.strip() == "error: standard output is closed: results could not be shown"


def test_vae_train_is_sized_and_never_replaces_a_vae_or_a_run(capsys, tmp_path):
    """``vae train``: ``--latent`` and ``--epochs`` bounded, ``--out ''`` refused, a folder
    holding a VAE needs ``--overwrite``, a run's folder is never written (its VAE belongs to
    the run)."""
    vae = tmp_path / "vae"
    vae.mkdir()
    (vae / "vae.msgpack").write_bytes(b"x")
    run = tmp_path / "run"
    run.mkdir()
    (run / "results.json").write_text("{}")
    for argv, expected in (
        (["--latent", "100000000"], "--latent must be in 1 .. 16"),
        (["--epochs", "10000000000000"], "--epochs must be in 1 .. 100000"),
        (["--out", ""], "--out ''"),
        (["--out", str(vae)], "--overwrite"),
        (["--out", str(run)], "belongs to that run"),
    ):
        one_line_error(capsys, ["vae", "train", "--no-progress", *argv], expected)
    assert (vae / "vae.msgpack").read_bytes() == b"x"


def test_jax_settings_the_programs_cannot_run_under_are_named(capsys, monkeypatch):
    """``JAX_DISABLE_JIT`` and ``JAX_NUMPY_RANK_PROMOTION=raise`` are refused in one line
    naming the variable (they were internal errors after compiling)."""
    import jax

    for name, value, expected in (
        ("jax_disable_jit", True, "JAX_DISABLE_JIT"),
        ("jax_numpy_rank_promotion", "raise", "JAX_NUMPY_RANK_PROMOTION=raise"),
    ):
        before = getattr(jax.config, name)
        jax.config.update(name, value)
        try:
            one_line_error(capsys, ["check", "tagging-thesis-n3"], expected)
        finally:
            jax.config.update(name, before)
    monkeypatch.setenv("JAX_TRANSFER_GUARD_DEVICE_TO_HOST", "disallow")  # was an internal error
    one_line_error(capsys, ["check", "tagging-thesis-n3"], "JAX_TRANSFER_GUARD_DEVICE_TO_HOST")


def test_a_bad_import_timeout_names_the_variable(capsys, monkeypatch, tmp_path):
    module = tmp_path / "harmless.py"
    module.write_text("X = 1\n")
    for value in ("abc", "-1", "nan"):
        monkeypatch.setenv("COGNET_JAX_IMPORT_TIMEOUT", value)
        one_line_error(capsys, ["--import", str(module), "list"], "COGNET_JAX_IMPORT_TIMEOUT")


def test_a_budget_that_sizes_nothing_is_a_warning(capsys):
    """``algorithm.budget`` with every size given changes nothing: one ``warning:`` line."""
    assert main(["check", "tagging-thesis-n3", "--set", "algorithm.budget=1000"]) == 0
    err = capsys.readouterr().err
    assert "warning: algorithm.budget sizes nothing" in err


def test_a_failed_command_keeps_only_what_can_be_continued(tmp_path):
    """A sweep's spec alone (written before it compiles) is not worth keeping; a group's
    checkpoint, a finished group or run, results or a checkpoint are."""
    from cognet_jax.run_folder import worth_keeping as _worth_keeping

    out = tmp_path / "sweep"
    (out / "sweep-state").mkdir(parents=True)
    (out / "sweep-state" / "sweep.json").write_text("{}")
    assert not _worth_keeping(out)
    for name in ("sweep-state/group0-p0.checkpoint.msgpack", "sweep-state/group0-p0.rows.json"):
        (out / name).write_text("")
        assert _worth_keeping(out)
        (out / name).unlink()
    (out / "runs" / "setting0-seed0").mkdir(parents=True)
    assert not _worth_keeping(out)
    (out / "runs" / "setting0-seed0" / "results.json").write_text("{}")
    assert _worth_keeping(out)


def test_xla_flags_xla_refuses_are_one_line_not_an_abort():
    """An unknown flag in ``XLA_FLAGS`` makes XLA abort the process that starts a backend:
    the command says so in one line (exit 2) instead."""
    import os
    import subprocess
    import sys

    env = {**os.environ, "XLA_FLAGS": "--xla_no_such_flag=1"}
    done = subprocess.run(
        [sys.executable, "-m", "cognet_jax", "check", "tagging-thesis-n3"],
        capture_output=True,
        text=True,
        timeout=300,
        env=env,
    )
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: XLA_FLAGS='--xla_no_such_flag=1'")
    assert "xla_no_such_flag" in lines[0].split("refuses it")[1]


def test_a_generator_edited_in_results_json_is_refused_and_a_set_one_warned(
    capsys, run_dir, tmp_path
):
    """results.json's run.prng_impl edited by hand: evaluate refuses, naming the field and
    both generators (it gave another number without a word); --set run.prng_impl evaluates
    with another generator on purpose, with a warning."""
    copy = tmp_path / "copy"
    shutil.copytree(run_dir, copy)
    results = json.loads((copy / "results.json").read_text())
    results["config"]["run"]["prng_impl"] = "rbg"
    (copy / "results.json").write_text(json.dumps(results))
    one_line_error(
        capsys, ["evaluate", str(copy)], "run.prng_impl: trained 'threefry2x32', now 'rbg'"
    )
    assert main(["evaluate", str(run_dir), "--set", "run.prng_impl=rbg"]) == 0
    assert "warning: run.prng_impl rbg where the run had threefry2x32" in capsys.readouterr().err
