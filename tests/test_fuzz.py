"""A fuzz suite through the real ``cognet-jax`` entry point (``cli.main``, in this process):
generated bad inputs -- mutated ``.dpomdp`` files, config values (types, signs, NaN / inf, huge
sizes), flag combinations, corrupted run folders. Every one must end with exit status 2 and one
line on stderr naming what is wrong, or succeed (exit 0) where the input is valid; never an
internal error, a traceback or a hang. The counts per kind are asserted, so the suite keeps
its size (>= 1000 inputs per run)."""

from __future__ import annotations

import functools
import json
import random
import shutil
from pathlib import Path

import pytest
from shared_files import DPOMDP_DIR, dpomdp_file

from cognet_jax.cli import main
from cognet_jax.registry import load_config

#: inputs each kind must try (they add up to more than 1000)
COUNTS = {
    "models": 400,
    "values": 0,  # 0: every field of the experiments once (137 fields)
    "flags": 260,
    "folders": 48,
    "check-train": 100,
    "modules": 60,
    "simulators": 15,
    "cache": 30,
    "writers": 8,
}


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


@functools.cache
def _value_cases() -> tuple[tuple[str, list[str], str], ...]:
    """(experiment, its ``--set`` base, ``section.field``) for every field of every kind of
    section the experiments hold, in the first experiment holding it: a field's checks belong
    to its section's class (``[run]`` and ``[evaluation]`` are the same in all five, ``[env]``
    the same tagging section in four), so trying it again in another experiment repeats them
    (137 fields; 302 with the repeats took 88 s of the suite's time)."""
    cases, seen = [], set()
    for experiment, base in _experiments().items():
        config = load_config(experiment, base)
        for section, values in config.to_dict().items():
            kind = type(getattr(config, section)).__name__
            fields = [key for key in values if (kind, key) not in seen]
            seen.update((kind, key) for key in fields)
            cases += [(experiment, base, f"{section}.{key}") for key in fields]
    return tuple(cases)


def test_config_values(capsys):
    """Every field of the experiments' sections, a value from ``BAD_VALUES`` each: ``cognet-jax
    check`` (all that ``train`` validates before it compiles) accepts it or refuses it in one
    line naming the field."""
    rnd = random.Random(11)
    cases = list(_value_cases())
    rnd.shuffle(cases)
    refused = 0
    count = COUNTS["values"] or len(cases)
    for k in range(count):
        experiment, base, field = cases[k % len(cases)]
        value = rnd.choice(BAD_VALUES)
        argv = ["check", experiment, *(x for s in base for x in ("--set", s))]
        argv += ["--set", f"{field}={value}"]
        code, err = _outcome(capsys, argv)
        _clean(code, err, argv)
        refused += code == 2
    assert refused > count // 2, refused


class _Admitted(Exception):
    """Raised where ``train`` would compile its first program: it admitted the run."""


def test_check_and_train_refuse_the_same_values(capsys, tmp_path, monkeypatch):
    """Values of the value family through ``check`` and through ``train`` (both stopped where
    they would compile, after every check before it): the two refuse the same ones, with the
    same line."""
    from cognet_jax import compiled, traced

    def admit(fn, args, key, check, check_compiled=None):  # the memory check, then stop
        jitted, leaves, _ = traced._flat(fn, args)
        check(jitted, leaves)
        raise _Admitted

    monkeypatch.setattr(compiled, "compile_kept", admit)
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
        if "_Admitted" in check_err[-1]:  # admitted: both get to their first compile
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


# ------------------------------------------------------------------------------- user modules
#: what a user's ``--import`` module may do at import: each must end in one line naming the
#: module (exit 2) or be harmless (exit 0)
MODULE_FAULTS = [
    "raise RuntimeError('broken')",
    "raise SystemExit(7)",
    "import sys\nsys.exit('no')",
    "import os\nos._exit(4)",
    "def f(:\n    pass",
    "import no_such_module_here",
    "1 / 0",
    "import cognet_jax\ncognet_jax.register_env('x')",
    "import cognet_jax\ncognet_jax.register_env(3, None, None)",
    "import cognet_jax\ncognet_jax.register_algorithm('y', None, None)",
    "import cognet_jax\ncognet_jax.register_env('tagging', object, lambda s, c: None)",
    "import time\nwhile True:\n    time.sleep(0.01)",
    "x = 1",
    "print('a module that talks')",
    "raise KeyboardInterrupt",
]


def test_failing_user_modules(capsys, tmp_path, monkeypatch):
    """``--import`` of modules that raise, exit, hang, break the registry or do nothing, with
    commands that read no simulator and one that does: one line naming the module, or exit 0."""
    monkeypatch.setenv("COGNET_JAX_IMPORT_TIMEOUT", "0.3")
    rnd = random.Random(3)
    commands = [["list"], ["inspect", str(dpomdp_file("dectiger"))], ["check", "tagging-thesis-n3"]]
    refused = 0
    for k in range(COUNTS["modules"]):
        fault = MODULE_FAULTS[k % len(MODULE_FAULTS)]
        module = tmp_path / f"user_{k}.py"
        module.write_text(fault + "\n")
        argv = ["--import", str(module), *rnd.choice(commands)]
        code, err = _outcome(capsys, argv)
        if code == 130:  # KeyboardInterrupt at import: the one-line interrupt
            assert err == ["error: interrupted"], err
            continue
        _clean(code, err, argv)
        if code == 2:
            assert module.name in err[0], (err, fault)
            refused += 1
    assert refused >= COUNTS["modules"] // 2, refused


# ------------------------------------------------------------------------------- user simulators
#: edits of the README's simulator (experiments/readme_seek.py) that break what it declares or
#: returns: ``(text, replacement, what the refusal names)``
SIMULATOR_FAULTS = [
    ("horizon: int = 20", "horizon: int = 0", "horizon"),
    ("horizon: int = 20", "horizon: int = -5", "horizon"),
    ("horizon: int = 20", "horizon: int = 20.5", "horizon"),
    ("horizon: int = 20", "horizon: int = 10**9", "horizon"),
    ("num_actions: int = 3", "num_actions: int = 2", "num_actions"),
    ("action_counts: tuple = (3, 3)", "action_counts: tuple = (3,)", "action_counts"),
    ("return state.at[:2].set(pos), obs, reward", "return state.at[:2].set(pos), obs", "return"),
    (
        "return state.at[:2].set(pos), obs, reward",
        "return state.at[:2].set(pos), obs, obs",
        "reward",
    ),
    ("obs_shape: tuple = ()", "obs_shape: tuple = (2,)", "observation"),
    (
        "return state.at[:2].set(pos), obs, reward",
        "return state.at[:2].set(pos), obs, reward * 1e38",
        "infinite return",
    ),
    (
        "    def step(self, u, state, actions, params):",
        "    def stepp(self, u, state, actions, params):",
        "missing step",
    ),
    ("obs_range: tuple = (-10.0, 10.0)", "obs_range: tuple = (10.0, -10.0)", "obs_range"),
    ("obs_range: tuple = (-10.0, 10.0)", "obs_range: tuple = (-10.0, float('inf'))", "obs_range"),
    ("obs_range: tuple = (-10.0, 10.0)", "obs_range: tuple = 'wide'", "obs_range"),
    ("return 10.0 * u", "return (10.0 * u).astype(jnp.int32)", "cannot safely cast"),
]


def test_broken_user_simulators_are_named_before_anything_runs(capsys, tmp_path):
    """``check`` with the defaults (whose noise pilot runs the simulator to size the search)
    on simulators whose sizes or returns are wrong: one line naming the simulator and what is
    wrong, exit 2, before the pilot runs it."""
    source = (Path(__file__).parents[1] / "experiments" / "readme_seek.py").read_text()
    for k in range(COUNTS["simulators"]):
        old, new, named = SIMULATOR_FAULTS[k % len(SIMULATOR_FAULTS)]
        assert old in source
        module = tmp_path / f"user_sim_{k}.py"
        text = source.replace(old, new).replace('register_env("seek"', f'register_env("seek{k}"')
        module.write_text(text)
        toml = tmp_path / f"seek{k}.toml"
        toml.write_text(f'[experiment]\nalgorithm = "cognet-dice"\n[env]\nname = "seek{k}"\n')
        argv = ["--import", str(module), "check", str(toml)]
        code, err = _outcome(capsys, argv)
        _clean(code, err, argv)
        assert code == 2 and f"seek{k}" in err[0] and named in err[0], (new, err)


# ------------------------------------------------------------------------------- kept programs
def _damage(rnd: random.Random, path: Path, other: Path) -> str:
    """One random damage to the kept program file ``path`` (``other``: another one)."""
    data = bytearray(path.read_bytes())
    kind = rnd.choice(["flip", "cut", "empty", "swap", "append", "zeros", "other-head", "gone"])
    if kind == "flip":
        for _ in range(rnd.randint(1, 16)):
            data[rnd.randrange(len(data))] ^= 1 << rnd.randrange(8)
        path.write_bytes(bytes(data))
    elif kind == "cut":
        path.write_bytes(bytes(data[: rnd.randrange(len(data))]))
    elif kind == "empty":
        path.write_bytes(b"")
    elif kind == "swap":
        path.write_bytes(other.read_bytes())
    elif kind == "append":
        path.write_bytes(bytes(data) + rnd.randbytes(rnd.randint(1, 64)))
    elif kind == "zeros":
        path.write_bytes(bytes(len(data)))
    elif kind == "other-head":
        head = other.read_bytes()[:64]
        path.write_bytes(head + bytes(data[len(head) :]))
    else:
        path.unlink()
    return kind


def test_damaged_kept_programs(capsys, tmp_path, monkeypatch):
    """Kept program files damaged at random (bytes flipped, cut, emptied, swapped between
    keys, extended, zeroed, deleted): the program is traced afresh and gives the numbers of a
    fresh trace, with at most one line said."""
    from collections import OrderedDict

    import jax
    import jax.numpy as jnp
    import numpy as np

    from cognet_jax import traced

    folder = tmp_path / "xla-traced"
    monkeypatch.setattr(traced, "trace_cache_dir", lambda: folder)
    monkeypatch.setattr(traced, "_COMPILED", OrderedDict())
    from cognet_jax import compile_cache

    monkeypatch.setattr(compile_cache, "_CACHE_TOLD", [])

    def program(scale):
        return lambda key, x: jnp.cumsum(x * scale + jax.random.normal(key, x.shape))

    def no_check(jitted, args):
        return None

    rnd = random.Random(17)
    kinds = set()
    for k in range(COUNTS["cache"]):
        args = (jax.random.key(k), jnp.linspace(0.0, 1.0, 8 + k % 3))
        other_args = (jax.random.key(k), jnp.ones(5))
        key = traced.program_key("fuzz", {"k": k}, jnp.float32(2.0), args)
        other = traced.program_key("fuzz", {"k": -k - 1}, jnp.float32(3.0), other_args)
        traced.compile_kept(program(2.0), args, key, no_check)
        traced.compile_kept(program(3.0), other_args, other, no_check)
        kinds.add(_damage(rnd, folder / f"{key}.bin", folder / f"{other}.bin"))
        traced._COMPILED.clear()
        compile_cache._CACHE_TOLD.clear()
        capsys.readouterr()
        out = traced.compile_kept(program(2.0), args, key, no_check)(*args)
        np.testing.assert_array_equal(np.asarray(out), np.asarray(jax.jit(program(2.0))(*args)))
        err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
        assert len(err) <= 1 and "Traceback" not in "".join(err), err
    assert len(kinds) >= 6, kinds


# ------------------------------------------------------------------------------- writers
def test_concurrent_writers(capsys, tmp_path, trained):
    """A folder another process is writing (its lock held by a live process): every command
    that would write it -- train, train --resume, --overwrite, sweep -- fails at once with one
    line naming the holder (or, without --resume / --overwrite, the run it holds), and the
    folder is left as it was."""
    import subprocess
    import sys
    import time

    rnd = random.Random(23)
    tiny = [x for s in TINY for x in ("--set", s)]
    for k in range(COUNTS["writers"]):
        out = tmp_path / f"w{k}"
        shutil.copytree(trained, out)
        holder = subprocess.Popen(
            [
                sys.executable,
                "-c",
                "import fcntl, os, sys, time\n"
                "fd = os.open(sys.argv[1], os.O_RDWR | os.O_CREAT)\n"
                "fcntl.flock(fd, fcntl.LOCK_EX)\nos.ftruncate(fd, 0)\n"
                "os.write(fd, f'{os.getpid()}\\n'.encode())\n"  # as run_folder.claim does
                "print('held', flush=True)\ntime.sleep(60)",
                str(out / ".lock"),
            ],
            stdout=subprocess.PIPE,
            text=True,
        )
        try:
            assert holder.stdout.readline().strip() == "held"
            before = (out / "results.json").read_bytes()
            argv = rnd.choice(
                [
                    ["train", "--out", str(out), *tiny],
                    ["train", "--resume", str(out)],
                    ["train", "--out", str(out), "--overwrite", *tiny],
                    ["sweep", "--seeds", "2", "--out", str(out), "--overwrite", *tiny],
                ]
            )
            t0 = time.monotonic()
            code, err = _outcome(capsys, argv)
            assert time.monotonic() - t0 < 30, argv  # at once, not after a search
            _clean(code, err, argv)
            named = str(holder.pid) in err[0] or "already holds a run" in err[0]
            assert code == 2 and named, (argv, err)
            assert (out / "results.json").read_bytes() == before
        finally:
            holder.kill()
            holder.wait()


def test_the_suite_tries_over_a_thousand_inputs():
    """The inputs the tests above try, "values" counted as the fields it tries when it is 0."""
    tried = sum(COUNTS.values()) + (COUNTS["values"] or len(_value_cases()))
    assert tried >= 1000, tried
