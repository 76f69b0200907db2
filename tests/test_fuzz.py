"""A fuzz suite through the real ``cognet-jax`` entry point (``cli.main``, in this process):
generated bad inputs -- mutated ``.dpomdp`` files, config values (types, signs, NaN / inf, huge
sizes), flag combinations, corrupted run folders. Every one must end with exit status 2 and one
line on stderr naming what is wrong, or succeed (exit 0) where the input is valid; never an
internal error, a traceback or a hang. The counts per kind are asserted, so the suite keeps
its size (>= 1000 inputs per run)."""

from __future__ import annotations

import json
import random
import shutil
from pathlib import Path

import pytest
from shared_files import DPOMDP_DIR, dpomdp_file

from cognet_jax.cli import main
from cognet_jax.registry import load_config

#: inputs each kind must try (the four add up to more than 1000)
COUNTS = {"models": 400, "values": 520, "flags": 260, "folders": 48, "check-train": 100}


def _outcome(capsys, argv: list[str]) -> tuple[int, list[str]]:
    capsys.readouterr()
    code = main(argv)
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    return code, err


def _clean(code: int, err: list[str], argv) -> None:
    """Exit 0, or exit 2 with exactly one ``error:`` line; never an internal error."""
    assert code in (0, 2), (code, err, argv)
    text = "\n".join(err)
    assert "internal error" not in text and "Traceback" not in text, (text, argv)
    if code == 2:
        assert len(err) == 1 and err[0].startswith("error: "), (err, argv)


# ------------------------------------------------------------------------------- models
def _mutate_model(text: str, rnd: random.Random) -> str:
    lines = text.splitlines()
    for _ in range(rnd.randint(1, 3)):
        i = rnd.randrange(len(lines))
        op = rnd.randrange(7)
        if op == 0:
            del lines[i]
        elif op == 1:
            lines.insert(i, rnd.choice(["T: * :", "O: * : * :", "R:", "agents: 0", "start:"]))
        elif op == 2:
            lines[i] = lines[i][: rnd.randrange(len(lines[i]) + 1)]
        elif op == 3:
            toks = lines[i].split()
            if toks:
                toks[rnd.randrange(len(toks))] = rnd.choice(
                    ["-1", "1e308", "nan", "inf", "0.5", "x", ":", "*", "999999999", "uniform"]
                )
            lines[i] = " ".join(toks)
        elif op == 4:
            lines = lines[:i]  # cut short
        elif op == 5:
            lines[i] = lines[i] + rnd.choice([" 0.1", " :", " extra", "\x00", "é"])
        else:
            lines.insert(i, lines[rnd.randrange(len(lines))])
    ending = "\n" if rnd.random() < 0.8 else ""
    return "\n".join(lines) + ending


def test_mutated_models(capsys, tmp_path):
    if not DPOMDP_DIR.is_dir():
        pytest.skip("../shared/dpomdp not found")
    rnd = random.Random(7)
    texts = [p.read_text() for p in sorted(DPOMDP_DIR.glob("*.dpomdp"))]
    codes = []
    for k in range(COUNTS["models"]):
        path = tmp_path / f"m{k % 7}.dpomdp"
        path.write_text(_mutate_model(rnd.choice(texts), rnd))
        code, err = _outcome(capsys, ["inspect", str(path)])
        _clean(code, err, path.read_text()[:200])
        codes.append(code)
    assert codes.count(2) > COUNTS["models"] // 2 and codes.count(0) > 20, codes.count(2)


# ------------------------------------------------------------------------------- values
def _experiments():
    dectiger = f"problem.path={json.dumps(str(dpomdp_file('dectiger')))}"
    return {
        "tagging-thesis-n3": [],
        "tagging-thesis-spec-n3": [],
        "tagging-thesis-cogdice-n3": [],
        "tagging-paper-gdice-d1": [],
        "gdice-dpomdp": [dectiger],
    }


BAD_VALUES = [
    "-1",
    "0",
    "2147483648",
    "9223372036854775807",
    "1e308",
    "-1e308",
    "nan",
    "inf",
    "-inf",
    "0.5",
    "1.5",
    "true",
    '"x"',
    '""',
    "[1, 2]",
    "{a = 1}",
    '"../../escape"',
    "1e-300",
    "3",
    "100000",
]


def test_config_values(capsys):
    """Every field of the experiments' sections, a value from ``BAD_VALUES`` each: ``cognet-jax
    check`` (all that ``train`` validates before it compiles) accepts it or refuses it in one
    line naming the field."""
    from cognet_jax.registry import load_config

    rnd = random.Random(11)
    cases = []
    for experiment, base in _experiments().items():
        config = load_config(experiment, base)
        for section, values in config.to_dict().items():
            cases += [(experiment, base, f"{section}.{key}") for key in values]
    rnd.shuffle(cases)
    refused = 0
    for k in range(COUNTS["values"]):
        experiment, base, field = cases[k % len(cases)]
        value = rnd.choice(BAD_VALUES)
        argv = ["check", experiment, *(x for s in base for x in ("--set", s))]
        argv += ["--set", f"{field}={value}"]
        code, err = _outcome(capsys, argv)
        _clean(code, err, argv)
        refused += code == 2
    assert refused > COUNTS["values"] // 2, refused


class _Admitted(Exception):
    """Raised where ``train`` would compile its first program: it admitted the run."""


def test_check_and_train_refuse_the_same_values(capsys, tmp_path, monkeypatch):
    """Values of the value family through ``check`` and through ``train`` (stopped where it
    would compile, after every check it makes): the two refuse the same ones, with the same
    line."""
    from cognet_jax import program, traced

    def admit(fn, args, key, check):  # the memory check, then stop before compiling
        jitted, leaves, _ = traced._flat(fn, args)
        check(jitted, leaves)
        raise _Admitted

    monkeypatch.setattr(program, "compile_kept", admit)
    rnd = random.Random(5)
    base = [x for s in TINY for x in ("--set", s)]
    config = load_config("tagging-thesis-n3")
    fields = [f"{sec}.{key}" for sec, values in config.to_dict().items() for key in values]
    refused = 0
    for k in range(COUNTS["check-train"]):
        value = rnd.choice(BAD_VALUES)
        case = ["tagging-thesis-n3", *base, "--set", f"{rnd.choice(fields)}={value}"]
        checked, check_err = _outcome(capsys, ["check", *case])
        out = ["--out", str(tmp_path / f"r{k}")]
        trained, train_err = _outcome(capsys, ["train", *case, *out])
        if checked == 0:  # admitted by check: train gets to its first compile
            assert trained == 1 and "_Admitted" in train_err[-1], (case, train_err)
        else:
            assert (trained, train_err) == (checked, check_err), (case[-1], train_err, check_err)
            refused += 1
    assert 0 < refused < COUNTS["check-train"]


# ------------------------------------------------------------------------------- flags
def _flag_argv(rnd: random.Random, folder: Path) -> list[str]:
    command = rnd.choice(["train", "sweep", "evaluate", "check", "inspect", "list", "vae"])
    pool = {
        "train": ["--seed", "-3", "--out", str(folder), "--resume", str(folder), "--seeds", "2"],
        "sweep": ["--seeds", "0", "--grid", "algorithm.alpha=0.1,,0.2", "--first-seed", "-1"],
        "evaluate": ["--rollouts", "1", "--seed", "x", str(folder / "missing")],
        "check": ["--seed", "4294967296", "nosuch.toml", "--set", "algorithm"],
        "inspect": [str(folder), "/dev/null"],
        "list": ["--import", "", "--import", ".rel"],
        "vae": ["train", "--seed", "-1", "--epochs", "0", "--latent", "0"],
    }
    extra = ["--set", "algorithm.iterations=0", "--no-progress", "--debugx", "--import"]
    words = pool[command] + extra
    argv = [command] + [rnd.choice(words) for _ in range(rnd.randint(0, 5))]
    if command in ("train", "sweep"):
        argv += ["--set", "algorithm.iterations=0"]  # never a real run
    if rnd.random() < 0.3:
        argv = [
            rnd.choice(["--import", "--debug"]),
            *(["x.py"] if rnd.random() < 0.5 else []),
        ] + argv
    return argv


def test_flag_combinations(capsys, tmp_path):
    rnd = random.Random(5)
    codes = []
    for _ in range(COUNTS["flags"]):
        argv = _flag_argv(rnd, tmp_path)
        if argv[0] == "--debug" or "--debug" in argv:
            continue  # --debug shows tracebacks on purpose
        code, err = _outcome(capsys, argv)
        _clean(code, err, argv)
        codes.append(code)
    assert len(codes) > COUNTS["flags"] * 2 // 3 and codes.count(2) > len(codes) // 2


# ------------------------------------------------------------------------------- folders
TINY = [
    "algorithm.iterations=3",
    "algorithm.candidates=10",
    "algorithm.elites=3",
    "algorithm.eval_rollouts=10",
    "algorithm.best_rollouts=10",
    "evaluation.rollouts=100",
    "evaluation.batch=100",
    "run.plots=false",
]


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    out = tmp_path_factory.mktemp("fuzz-run") / "run"
    argv = ["train", "--out", str(out), "--no-progress", *(x for s in TINY for x in ("--set", s))]
    assert main(argv) == 0
    return out


def _corrupt(folder: Path, rnd: random.Random) -> tuple[str, int]:
    """One file of ``folder`` truncated (op 0), with bytes changed (1), deleted (2), with a
    field of results.json replaced (3) or replaced by random bytes (4); returns the file's name
    and the op."""
    name = rnd.choice(["results.json", "policy.msgpack", "checkpoint.msgpack"])
    path = folder / name
    data = bytearray(path.read_bytes())
    op = rnd.randrange(5)
    if op == 0:
        path.write_bytes(bytes(data[: rnd.randrange(len(data))]))
    elif op == 1:
        for _ in range(rnd.randint(1, 8)):
            data[rnd.randrange(len(data))] = rnd.randrange(256)
        path.write_bytes(bytes(data))
    elif op == 2:
        path.unlink()
    elif op == 3 and name == "results.json":
        record = json.loads(data)
        key = rnd.choice(["config", "seed", "final_value", "experiment"])
        record[key] = rnd.choice([None, 7, "x", [], {"algorithm": 3}, -1])
        path.write_text(json.dumps(record))
    else:
        op = 4
        path.write_bytes(bytes(rnd.randrange(256) for _ in range(rnd.randint(0, 64))))
    return name, op


#: the files each command reads (``train --resume`` continues from the checkpoint and writes
#: results.json and policy.msgpack anew)
READS = {"evaluate": ("results.json", "policy.msgpack"), "train": ("checkpoint.msgpack",)}


def test_corrupted_run_folders(capsys, tmp_path, trained):
    """``evaluate DIR`` and ``train --resume DIR`` on a folder with one file damaged: a clean
    exit always, and a refusal whenever the damaged file is one the command reads -- except
    where the damage can leave a valid file (bytes changed in, or a field replaced of, the
    unchecksummed results.json)."""
    rnd = random.Random(3)
    refused = 0
    for k in range(COUNTS["folders"]):
        folder = tmp_path / f"run{k}"
        shutil.copytree(trained, folder)
        name, op = _corrupt(folder, rnd)
        command = ["evaluate", str(folder)] if k % 4 else ["train", "--resume", str(folder)]
        code, err = _outcome(capsys, [*command, "--no-progress"] if k % 4 == 0 else command)
        _clean(code, err, command)
        may_stay_valid = name == "results.json" and op in (1, 3)
        if name in READS[command[0]] and not may_stay_valid:
            assert code == 2 and name in err[0], (name, op, command, err)
            refused += 1
        shutil.rmtree(folder, ignore_errors=True)
    assert refused >= COUNTS["folders"] // 5


def test_the_suite_tries_over_a_thousand_inputs():
    assert sum(COUNTS.values()) >= 1000
