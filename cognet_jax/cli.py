"""The ``cognet-jax`` command.

cognet-jax train [EXPERIMENT] [--seed N] [--out DIR [--overwrite]] [--set section.key=value ...]
                 [--checkpoint-every K] [--resume DIR]
cognet-jax sweep [EXPERIMENT] --seeds N [--grid section.key=v1,v2,...]... [--out DIR [--overwrite]]
                 [--set section.key=value ...] [--checkpoint-every K] [--resume DIR]
                 [--coordinator HOST:PORT --num-processes P --process-id I | --cluster]
cognet-jax evaluate DIR [--rollouts N] [--seed N] [--set section.key=value ...]
cognet-jax vae train [--out DIR] [--seed N] [--epochs N] [--latent N] [--kl-weight W]
cognet-jax check [EXPERIMENT] [--set section.key=value ...]
cognet-jax inspect FILE.dpomdp
cognet-jax list

A run folder that holds a run is never replaced without ``--overwrite``, and one process at a
time writes it (``cognet_jax.run_folder``).

Every user-facing failure (bad config field, unreadable or corrupt file, a policy that does not
fit the model, ...) prints one line ``error: ...`` naming the file and line or the field, and
exits with status 2; ``--debug`` (any subcommand) shows the traceback instead. SIGINT, SIGTERM
and SIGHUP stop a search after its current iteration with a checkpoint and the best policy
written (``cognet_jax.signals``, ``cognet_jax.driver``); every command ends on them with one
line and status ``128 + signal``.

Commands import the driver (and JAX) only when they run, so ``--help``, ``list`` and
``inspect`` start without JAX.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import gc
import importlib
import importlib.util
import json
import math
import os
import shutil
import signal
import sys
import threading
import time
import traceback
from pathlib import Path

from tqdm.auto import tqdm

from cognet_jax.config import ConfigError, builtin_experiments, read_experiment
from cognet_jax.errors import InputError, UsageError
from cognet_jax.io.dpomdp import parse_dpomdp
from cognet_jax.registry import load_config, note_foreign_code
from cognet_jax.run_folder import check_out, claim
from cognet_jax.signals import Stopped, install_stop_handlers

DEFAULT_EXPERIMENT = "tagging-thesis-n3"


def _add_experiment(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "experiment",
        nargs="?",
        default=None,
        help=f"built-in experiment name or TOML file (default {DEFAULT_EXPERIMENT})",
    )


def _add_overrides(parser: argparse.ArgumentParser, help_text: str) -> None:
    """``--set SECTION.KEY=V`` (repeatable) and ``--no-progress``."""
    parser.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="SECTION.KEY=V",
        help=help_text,
    )
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")


def _add_checkpoints(parser: argparse.ArgumentParser, resumed: str) -> None:
    """``--checkpoint-every K`` and ``--resume DIR`` (continue ``resumed``)."""
    parser.add_argument(
        "--checkpoint-every",
        type=int,
        default=None,
        metavar="K",
        help="also write the search state every K iterations (run.checkpoint_every; "
        "run.checkpoint_seconds writes it every 60 s of search by default)",
    )
    parser.add_argument("--resume", metavar="DIR", default=None, help=f"continue {resumed}")


def _common(suffix: str = "") -> argparse.ArgumentParser:
    """The options every command takes, before or after its name: ``--debug`` and
    ``--import`` (``suffix`` tells the top-level parser's apart, ``_merge_common``)."""
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument(
        "--debug",
        dest=f"debug{suffix}",
        action="store_true",
        help="show the Python traceback of an error",
    )
    common.add_argument(
        "--import",
        dest=f"imports{suffix}",
        action="append",
        default=[],
        metavar="MODULE",
        help="import a module or .py file first, e.g. one that registers your own simulator "
        "(cognet_jax.register_env); repeatable",
    )
    common.add_argument(
        "--no-compile-cache",
        dest=f"no_compile_cache{suffix}",
        action="store_true",
        help=f"compile every program afresh (default: cache them in ${CACHE_VARIABLE}, "
        "~/.cache/cognet-jax/xla)",
    )
    return common


#: the environment variable naming the compilation cache folder ("off" turns it off)
CACHE_VARIABLE = "COGNET_JAX_CACHE"
#: the cache may hold this many bytes; JAX evicts the least recently used programs above it
#: (with the ``filelock`` package, which torch brings; without it the folder is not bounded)
CACHE_MAX_BYTES = 2 * 10**9


def compile_cache_dir() -> Path | None:
    """Where the command line keeps compiled programs (JAX's persistent compilation cache):
    ``$COGNET_JAX_CACHE``, else ``$XDG_CACHE_HOME/cognet-jax/xla``, else
    ``~/.cache/cognet-jax/xla``; ``None`` when ``COGNET_JAX_CACHE=off``."""
    chosen = os.environ.get(CACHE_VARIABLE, "")
    if chosen.lower() in ("off", "0", "false", "none"):
        return None
    if chosen:
        return Path(chosen).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "cognet-jax" / "xla"


def use_compile_cache(args) -> None:
    """Keep every compiled program in ``compile_cache_dir()`` (unless ``--no-compile-cache``,
    or a cache folder was already chosen, e.g. by ``JAX_COMPILATION_CACHE_DIR``): a repeated run
    loads its programs instead of compiling them. The cache key holds JAX's and XLA's versions
    and the machine's devices, so another version or machine compiles afresh (and adds its own
    entries)."""
    import jax

    folder = None if args.no_compile_cache else compile_cache_dir()
    if folder is None or jax.config.jax_compilation_cache_dir:
        return
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    _one_cache_warning(folder)
    if importlib.util.find_spec("filelock") is not None:  # JAX's eviction needs it
        repair_cache_folder(folder)
        jax.config.update("jax_compilation_cache_max_size", CACHE_MAX_BYTES)


def repair_cache_folder(folder: Path) -> None:
    """Make ``folder`` one JAX's size-bounded cache can use: every ``NAME-cache`` entry gets the
    ``NAME-atime`` file JAX's eviction reads (time 0: evicted first), and access-time files
    without an entry are removed. A folder filled by runs without the bound lacks them, and
    JAX then warns at every write and never stores a new entry."""
    try:
        names = {p.name for p in folder.iterdir()}
    except OSError:  # not there yet, or unreadable: JAX reports what it cannot do
        return
    for name in names:
        try:
            if name.endswith("-cache") and name[: -len("-cache")] + "-atime" not in names:
                (folder / (name[: -len("-cache")] + "-atime")).write_bytes(bytes(8))
            elif name.endswith("-atime") and name[: -len("-atime")] + "-cache" not in names:
                (folder / name).unlink()
        except OSError:
            pass


def _one_cache_warning(folder: Path) -> None:
    """JAX's warnings about its compilation cache (an entry it cannot read or write) become
    one line per process: the first, shortened; the program is compiled all the same."""
    import warnings

    shown = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None):
        text = " ".join(str(message).split())
        if "compilation cache" not in text:
            return shown(message, category, filename, lineno, file, line)
        if not _CACHE_TOLD:
            _CACHE_TOLD.append(text)
            print(f"note: compilation cache {folder}: {text[:160]}", file=sys.stderr)

    warnings.showwarning = show


#: the compilation cache's first warning of this process (``_one_cache_warning``)
_CACHE_TOLD: list[str] = []


def _merge_common(args) -> argparse.Namespace:
    """``--debug`` and ``--import`` given before the command name count as after it."""
    args.debug = args.debug or args.debug_top
    args.imports = args.imports_top + args.imports
    args.no_compile_cache = args.no_compile_cache or args.no_compile_cache_top
    return args


def _add_train(sub) -> None:
    t = sub.add_parser("train", help="run a policy search and write results, policy and plots")
    _add_experiment(t)
    t.add_argument("--seed", type=int, default=None, help="default 0")
    t.add_argument("--out", default=None, help="output folder (default runs/EXPERIMENT-seedN)")
    _add_overwrite(t)
    _add_overrides(t, "override a config field; repeatable")
    _add_checkpoints(t, "the interrupted run in DIR from its checkpoint (config and seed from it)")


def _add_overwrite(parser) -> None:
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="replace the run already in --out (without it such a folder is refused)",
    )


def _add_sweep(sub) -> None:
    w = sub.add_parser(
        "sweep",
        help="many seeds x settings in one compiled program; writes runs.csv/json, summary.md",
    )
    _add_experiment(w)
    w.add_argument("--seeds", type=int, default=None, help="number of seeds (default 1)")
    w.add_argument(
        "--first-seed", type=int, default=None, help="seeds are first .. first+N-1 (default 0)"
    )
    w.add_argument(
        "--grid",
        action="append",
        default=[],
        metavar="SECTION.KEY=V1,V2",
        help="values of one field to sweep; repeatable (cartesian product)",
    )
    w.add_argument("--out", default=None, help="output folder (default runs/sweep-EXPERIMENT)")
    _add_overwrite(w)
    _add_overrides(w, "override a config field for every run; repeatable")
    _add_checkpoints(w, "the interrupted sweep in DIR (experiment, seeds, grid from it)")
    w.add_argument(
        "--cpu-devices",
        type=int,
        default=None,
        metavar="N",
        help="split the CPU into N JAX devices the runs are sharded over (default: one per "
        "core, at most one per run; ignored when XLA_FLAGS sets the device count)",
    )
    w.add_argument("--coordinator", default=None, metavar="HOST:PORT", help="jax.distributed")
    w.add_argument("--num-processes", type=int, default=None, metavar="P")
    w.add_argument("--process-id", type=int, default=None, metavar="I")
    w.add_argument(
        "--cluster",
        action="store_true",
        help="initialise jax.distributed from the scheduler's environment (SLURM, ...)",
    )


def _add_evaluate(sub) -> None:
    e = sub.add_parser("evaluate", help="re-evaluate the saved best policy of a run folder")
    e.add_argument("run_dir")
    e.add_argument(
        "--rollouts", type=int, default=None, help="default: the run's evaluation.rollouts"
    )
    e.add_argument(
        "--seed",
        type=int,
        default=None,
        help="draw from this seed's evaluation key (default: the run's own seed, which "
        "reproduces its results.json final_value)",
    )
    e.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="SECTION.KEY=V",
        help="change the evaluation setting (e.g. env.obs_noise=0.1)",
    )


def _add_vae(sub) -> None:
    v = sub.add_parser("vae", help="patch VAE for heatmap observations (SPEC section 6)")
    vsub = v.add_subparsers(dest="vae_command", required=True)
    vt = vsub.add_parser(
        "train", help="train the patch VAE; writes vae.msgpack, vae.json, vae_mu.png"
    )
    vt.add_argument("--out", default="runs/vae", help="output folder (default runs/vae)")
    vt.add_argument("--seed", type=int, default=0)
    vt.add_argument("--epochs", type=int, default=60)
    vt.add_argument("--latent", type=int, default=1, help="latent dimensions (default 1)")
    vt.add_argument(
        "--kl-weight", type=float, default=1.0, help="weight of the KL term (default 1)"
    )
    vt.add_argument("--no-noise", action="store_true", help="train on the 144 clean patches only")
    vt.add_argument("--no-progress", action="store_true", help="hide the progress bar")


class _ArgumentParser(argparse.ArgumentParser):
    """An argument error is one line (``UsageError``, exit 2), not usage text and a line."""

    def error(self, message: str):
        raise UsageError(f"{self.prog}: {message} (see {self.prog} --help)")


@functools.cache
def _parser() -> argparse.ArgumentParser:
    """The command line's parser, built once (building it looks up argparse's translated
    messages: about 5 ms, as long as parsing a small model for ``inspect``)."""
    common = _common()
    p = _ArgumentParser(
        prog="cognet-jax", description=__doc__.split("\n\n")[0], parents=[_common("_top")]
    )
    sub = p.add_subparsers(dest="command", required=True)
    add_parser = sub.add_parser
    sub.add_parser = lambda *a, **kw: add_parser(*a, parents=[common], **kw)  # noqa: E731
    _add_train(sub)
    _add_sweep(sub)
    _add_evaluate(sub)
    c = sub.add_parser(
        "check", help="validate an experiment and its sizes without running it (exit 0 or 2)"
    )
    _add_experiment(c)
    c.add_argument("--seed", type=int, default=0)
    _add_overrides(c, "override a config field; repeatable")
    _add_vae(sub)
    sub.add_parser("list", help="list the built-in experiments")
    i = sub.add_parser(
        "inspect", help="parse a .dpomdp file and print its sizes (or the first error in it)"
    )
    i.add_argument("file", help="a MADP .dpomdp file (.gz allowed)")
    return p


def _run_overrides(args) -> list[str]:
    extra = []
    if args.no_progress:
        extra.append("run.progress=false")
    if args.checkpoint_every is not None:
        extra.append(f"run.checkpoint_every={args.checkpoint_every}")
    return extra


@contextlib.contextmanager
def _removed_on_failure(out: Path):
    """A folder this command creates is removed again if the command fails before anything
    worth keeping (results, a checkpoint) is in it; an existing folder is left alone."""
    existed = out.exists()
    try:
        yield
    except BaseException:
        keep = ("results.json", "checkpoint.msgpack")
        if not existed and out.is_dir() and not any((out / k).exists() for k in keep):
            shutil.rmtree(out, ignore_errors=True)
        raise


def _refuse_with_resume(args, flags: dict) -> None:
    """``UsageError`` naming the first of ``flags`` (flag -> value given, ``None`` or ``[]``
    when not given) that ``--resume`` contradicts: the run continues as it was started."""
    for flag, value in flags.items():
        if value not in (None, []):
            raise UsageError(
                f"{flag} cannot be given with --resume: {args.resume} continues with the "
                "settings it was started with (only --set run.* fields may change)"
            )


def _train(args) -> int:
    from cognet_jax.driver import Interrupted, train
    from cognet_jax.saved_runs import resume_target

    try:
        if args.resume:
            flags = {"EXPERIMENT": args.experiment, "--seed": args.seed, "--out": args.out}
            _refuse_with_resume(args, flags)
            config, seed = resume_target(args.resume, args.overrides + _run_overrides(args))
            with claim(Path(args.resume), resume=True):
                train(config, seed, Path(args.resume), resume=True)
            return 0
        check_out(args.out)
        seed = 0 if args.seed is None else args.seed
        overrides = args.overrides + _run_overrides(args)
        config = load_config(args.experiment or DEFAULT_EXPERIMENT, overrides)
        out = Path(args.out or f"runs/{config.experiment.name}-seed{seed}")
        with _removed_on_failure(out), claim(out, overwrite=args.overwrite):
            train(config, seed, out)
    except Interrupted as err:
        _STOPPED["signum"] = err.signum
        print(f"error: {err}", file=sys.stderr)
        return 128 + err.signum
    return 0


def init_distributed(args) -> None:
    """``jax.distributed.initialize`` from ``--coordinator/--num-processes/--process-id`` or,
    with ``--cluster``, from the cluster scheduler's environment variables."""
    import jax

    explicit = (args.coordinator, args.num_processes, args.process_id)
    if args.cluster:
        try:
            jax.distributed.initialize()
        except (RuntimeError, ValueError) as err:
            raise UsageError(f"--cluster: cannot start jax.distributed: {err}") from None
    elif any(v is not None for v in explicit):
        for name, v in zip(("--coordinator", "--num-processes", "--process-id"), explicit):
            if v is None:
                raise UsageError(f"{name} is needed for a multi-process sweep")
        if not 0 <= args.process_id < args.num_processes:
            raise UsageError(f"--process-id must be in 0 .. {args.num_processes - 1}")
        check_coordinator(args.coordinator, args.process_id)
        try:
            jax.distributed.initialize(
                args.coordinator,
                args.num_processes,
                args.process_id,
                initialization_timeout=COORDINATOR_TIMEOUT_S,
            )
        except (RuntimeError, ValueError) as err:
            raise UsageError(f"--coordinator {args.coordinator}: cannot start: {err}") from None


#: how long the processes of a multi-process sweep wait for each other
COORDINATOR_TIMEOUT_S = 120


def check_coordinator(address: str, process_id: int) -> None:
    """Refuse, in one line, what would make ``jax.distributed`` abort the process natively: an
    address that is not ``HOST:PORT``, a host that does not resolve, a port process 0 cannot
    listen on, and (other processes) a coordinator that does not answer within
    ``COORDINATOR_TIMEOUT_S``. (A peer process that never starts still ends JAX's own wait
    with an abort, after that timeout.)"""
    import socket

    host, _, port = address.rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise UsageError(f"--coordinator {address!r}: expected HOST:PORT (a port 1-65535)")
    try:
        socket.getaddrinfo(host.strip("[]"), int(port), type=socket.SOCK_STREAM)
    except OSError as err:
        raise UsageError(f"--coordinator {address}: unknown host {host!r} ({err})") from None
    if process_id == 0:  # the coordination service runs here and listens on PORT
        try:
            with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
                probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                probe.bind(("", int(port)))
        except OSError as err:
            raise UsageError(
                f"--coordinator {address}: process 0 cannot listen on port {port} ({err.strerror})"
            ) from None
        return
    deadline, told = time.monotonic() + COORDINATOR_TIMEOUT_S, False
    while True:
        try:
            socket.create_connection((host.strip("[]"), int(port)), timeout=2).close()
            return
        except OSError:
            if time.monotonic() > deadline:
                raise UsageError(
                    f"--coordinator {address}: no answer in {COORDINATOR_TIMEOUT_S} s (start "
                    "process 0 first, on that host)"
                ) from None
            if not told:
                print(f"waiting for the coordinator at {address} ...", file=sys.stderr)
                told = True
            time.sleep(0.5)


def set_cpu_devices(requested: int | None, runs: int) -> None:
    """Split the host CPU into ``requested`` JAX devices (default ``min(cores, runs)``) so the
    sharded ``[runs]`` axis keeps every core busy. Must run before JAX starts its backends;
    does nothing when ``XLA_FLAGS`` already sets the host device count."""
    import jax

    if requested is not None and requested < 1:
        raise ConfigError("cpu-devices", f"must be >= 1, got {requested}")
    if "xla_force_host_platform_device_count" in os.environ.get("XLA_FLAGS", ""):
        return
    n = requested if requested is not None else max(1, min(os.cpu_count() or 1, runs))
    try:
        jax.config.update("jax_num_cpu_devices", n)
    except RuntimeError:  # backends already started (e.g. called from a running program)
        pass


def _sweep(args) -> int:
    from cognet_jax.driver import Interrupted
    from cognet_jax.sweep import parse_grid, read_spec

    if args.checkpoint_every is not None and args.checkpoint_every < 0:
        raise ConfigError("checkpoint-every", f"must be >= 0, got {args.checkpoint_every}")
    run_sets = _run_overrides(args)
    if args.resume:
        flags = {"EXPERIMENT": args.experiment, "--seeds": args.seeds, "--out": args.out}
        flags.update({"--first-seed": args.first_seed, "--grid": args.grid})
        flags["--set"] = [o for o in args.overrides if not o.strip().startswith("run.")]
        _refuse_with_resume(args, flags)
        spec = read_spec(args.resume)
        experiment, seeds, grid = spec["experiment"], spec["seeds"], spec["grid"]
        overrides, out = spec["overrides"], Path(args.resume)
        run_sets = args.overrides + run_sets
    else:
        n = 1 if args.seeds is None else args.seeds
        if n < 1:
            raise ConfigError("seeds", f"--seeds must be >= 1, got {n}")
        experiment = args.experiment or DEFAULT_EXPERIMENT
        grid = parse_grid(args.grid, args.overrides)
        overrides = args.overrides
        first = 0 if args.first_seed is None else args.first_seed
        seeds = list(range(first, first + n))
        check_out(args.out)
        out = Path(args.out or f"runs/sweep-{Path(experiment).stem}")
    processes = args.num_processes or 1
    total = len(seeds) * math.prod(len(v) for v in grid.values())
    if not args.resume:
        _size_sweep(experiment, overrides, len(seeds), total)
    set_cpu_devices(args.cpu_devices, -(-total // processes))
    init_distributed(args)
    import jax

    main_process = jax.process_index() == 0
    held = (
        claim(out, resume=bool(args.resume), overwrite=args.overwrite)
        if main_process
        else contextlib.nullcontext()
    )
    try:
        with held:
            return _sweep_claimed(
                args, experiment, seeds, grid, overrides, out, run_sets, main_process
            )
    except Interrupted as err:
        _STOPPED["signum"] = err.signum
        print(f"error: {err}", file=sys.stderr)
        return 128 + err.signum


#: a sweep of more runs than this is announced with its estimate before it is prepared
MANY_RUNS = 1000


def _size_sweep(experiment: str, overrides: list[str], seeds: int, total: int) -> None:
    """Refuse, before anything is built for each run, a sweep whose runs together take more
    than ``api.ABSURD_SECONDS`` of simulation (the first setting's estimate times the runs);
    announce a large one (over ``MANY_RUNS`` runs, or over ``api.LONG_SECONDS``)."""
    from cognet_jax.api import ABSURD_SECONDS, LONG_SECONDS, build_env, estimated_seconds

    config = load_config(experiment, overrides)
    seconds = estimated_seconds(config, build_env(config)[0]) * total
    settings = total // max(seeds, 1)
    what = f"{total} runs ({settings} settings x {seeds} seeds)"
    if seconds > ABSURD_SECONDS:
        field = "seeds" if seeds >= settings else "grid"
        raise ConfigError(
            field,
            f"the sweep's {what} simulate at least {seconds / 86400:.0f} days together, over "
            f"the limit of {ABSURD_SECONDS / 86400:.0f} days",
        )
    if total > MANY_RUNS or seconds > LONG_SECONDS:
        print(
            f"sweep: {what}, at least {seconds / 3600:.2f} h of simulation; preparing them ...",
            file=sys.stderr,
            flush=True,
        )


def _sweep_claimed(args, experiment, seeds, grid, overrides, out, run_sets, main_process) -> int:
    """The sweep of ``_sweep`` once its folder is claimed (``run_folder.claim``)."""
    from cognet_jax.sweep import run_sweep, write_outputs

    result = run_sweep(
        experiment,
        seeds,
        grid,
        overrides,
        progress=not args.no_progress and main_process,
        log=print if main_process else (lambda *a: None),
        out=out,
        resume=bool(args.resume),
        run_overrides=run_sets,
    )
    if main_process:
        write_outputs(result, out)
        print((out / "summary.md").read_text())
        print(f"wrote {out}/runs.csv, runs.json, summary.md, values.png; each run's policy in")
        print(f"  {out}/runs/setting{{k}}-seed{{s}}/ (cognet-jax evaluate works on it)")
    return 0


def _evaluate(args) -> int:
    from cognet_jax.saved_runs import evaluate_run

    if args.rollouts is not None and not 2 <= args.rollouts < 2**31:
        raise UsageError(f"--rollouts must be in 2 .. 2147483647, got {args.rollouts}")
    value = evaluate_run(args.run_dir, args.rollouts, args.seed, args.overrides)
    print(
        f"value {value['mean']:.3f} +- {value['stderr']:.3f} ({value['rollouts']} rollouts, "
        f"seed {value['seed']}{', ' + ' '.join(args.overrides) if args.overrides else ''})"
    )
    log = Path(args.run_dir) / "evaluations.jsonl"
    with log.open("a") as f:
        f.write(json.dumps(value) + "\n")
    print(f"appended to {log}")
    return 0


def _vae(args) -> int:
    from cognet_jax.reporting import plot_vae_mu
    from cognet_jax.vae import diagnostics, save_vae, train_vae

    if args.epochs < 1:
        raise UsageError("--epochs must be >= 1")
    if args.seed < 0:
        raise UsageError(f"--seed must be >= 0, got {args.seed}")
    if args.latent < 1:
        raise UsageError("--latent must be >= 1")
    if not (args.kl_weight > 0 and math.isfinite(args.kl_weight)):
        raise UsageError("--kl-weight must be a finite number > 0")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    with tqdm(total=args.epochs, disable=args.no_progress, desc="vae", unit="epoch") as bar:

        def progress(epoch, loss):
            bar.set_postfix(loss=f"{loss:.3f}")
            bar.update(1)

        vae, losses = train_vae(
            seed=args.seed,
            epochs=args.epochs,
            noisy=not args.no_noise,
            progress=progress,
            latent=args.latent,
            kl_weight=args.kl_weight,
        )
    info = diagnostics(vae)
    info.update(
        seed=args.seed,
        epochs=args.epochs,
        latent=args.latent,
        kl_weight=args.kl_weight,
        noisy=not args.no_noise,
        losses=losses.tolist(),
        wall_s=time.perf_counter() - t0,
    )
    save_vae(out / "vae.msgpack", vae)
    (out / "vae.json").write_text(json.dumps(info, indent=1))
    plot_vae_mu(vae, out / "vae_mu.png")
    print(
        f"vae: final loss {losses[-1]:.3f}; Spearman(mu, distance) "
        f"{info['spearman_mu_distance']:.4f}; mu {info['mu_source_corner']:.2f} at (2, 2) .. "
        f"{info['mu_far_corner']:.2f} at (13, 13); reconstruction MAE {info['recon_mae']:.4f}"
    )
    print(f"wrote {out}/vae.msgpack, vae.json, vae_mu.png")
    return 0


def _check(args) -> int:
    """Everything ``train`` checks before it compiles: the config, the model file, the sizes
    (memory and time), the seed, the search it builds and the memory of its programs (traced,
    not compiled); nothing runs."""
    from cognet_jax.api import build, seed_key
    from cognet_jax.program import Program, Run

    config = load_config(args.experiment or DEFAULT_EXPERIMENT, args.overrides)
    seed_key(config, args.seed)
    built = build(config)
    Program([Run(config, args.seed)], built).check_memory()
    seconds = built.seconds
    print(f"{config.experiment.name}: valid; at least {seconds:.3g} s of simulation")
    return 0


def _list(args) -> int:
    for name in builtin_experiments():
        desc = read_experiment(name).get("experiment", {}).get("description", "")
        print(f"{name:28s} {desc}")
    return 0


def _inspect(args) -> int:
    """Sizes of a model and how long it took to parse (or the first error in it)."""
    t0 = time.perf_counter()
    model = parse_dpomdp(args.file)
    wall = time.perf_counter() - t0
    print(
        f"{args.file}: {model.num_agents} agents, {model.num_states} states, actions "
        f"{model.action_counts}, observations {model.obs_counts}, discount {model.discount:g}; "
        f"parsed in {wall:.2f} s"
    )
    return 0


def _one_line(err: BaseException) -> str:
    """The message of a user-facing error on one line."""
    if isinstance(err, OSError) and err.strerror:
        where = err.filename if err.filename is not None else ""
        text = f"{where}: {err.strerror}" if where else err.strerror
    else:
        text = str(err) or type(err).__name__
    return " ".join(text.split())


def _where(err: BaseException, path: str | None) -> str:
    """``file:line`` of the user module's line that raised ``err`` (the last frame in
    ``path``, or the last frame at all)."""
    if isinstance(err, SyntaxError):
        return f"{err.filename}:{err.lineno}"
    frames = traceback.extract_tb(err.__traceback__)
    own = [f for f in frames if path and Path(f.filename).resolve() == Path(path).resolve()]
    frame = (own or frames or [None])[-1]
    return f"{frame.filename}:{frame.lineno}" if frame else "?"


#: seconds an ``--import`` module may take to import (``COGNET_JAX_IMPORT_TIMEOUT`` sets
#: another); a module still importing then is reported as hanging
IMPORT_TIMEOUT_S = 120.0


class _ImportEnded(Exception):
    """Raised inside an ``--import`` module's import: it called ``os._exit`` or ran out of
    time (``IMPORT_TIMEOUT_S``)."""


@contextlib.contextmanager
def _guarded_import(name: str):
    """While a module imports: ``os._exit(n)`` raises instead of ending the process, and an
    alarm ends an import that takes longer than ``IMPORT_TIMEOUT_S`` (main thread only)."""
    timeout = float(os.environ.get("COGNET_JAX_IMPORT_TIMEOUT", IMPORT_TIMEOUT_S))
    real_exit = os._exit

    def exit_instead(code=0):
        raise _ImportEnded(f"--import {name} exited with status {code}")

    def out_of_time(signum, frame):
        raise _ImportEnded(f"--import {name}: still importing after {timeout:g} s (a hang?)")

    main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGALRM, out_of_time) if main else None
    os._exit = exit_instead
    try:
        if main:
            signal.setitimer(signal.ITIMER_REAL, timeout)
        yield
    finally:
        if main:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, previous)
        os._exit = real_exit


def import_plugin(name: str) -> None:
    """Import a module by name, or a ``.py`` file by path (``--import``); an error of the
    module itself is a ``UsageError`` naming its file and line, and so is a module that exits
    (``sys.exit``, ``os._exit``) or hangs at import (``_guarded_import``)."""
    if not name or name.startswith("."):
        raise UsageError(f"--import {name!r}: give a module name or a .py file")
    path = Path(name)
    origin = str(path) if name.endswith(".py") else None
    try:
        with _guarded_import(name):
            _import(name, path, origin)
        note_foreign_code(name, origin if origin else importlib.util.find_spec(name).origin)
    except UsageError:
        raise
    except _ImportEnded as err:
        raise UsageError(str(err)) from None
    except SystemExit as err:  # sys.exit() in the module's top level
        raise UsageError(f"--import {name} exited with status {err.code}") from None
    except (ModuleNotFoundError, ValueError) as err:
        raise UsageError(f"--import {name}: {err}") from None
    except Exception as err:  # the module's own error: where, what
        raise UsageError(
            f"--import {name}: {_where(err, origin)}: {type(err).__name__}: {_one_line(err)}"
        ) from None


def _import(name: str, path: Path, origin: str | None) -> None:
    """Import the module ``name`` (a ``.py`` file when ``origin`` is its path)."""
    if origin is not None:
        if not path.is_file():
            raise UsageError(f"--import {name}: no such file")
        spec = importlib.util.spec_from_file_location(path.stem, path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[path.stem] = module
        spec.loader.exec_module(module)
    else:
        if importlib.util.find_spec(name) is None:
            raise UsageError(f"--import {name}: no module of that name")
        importlib.import_module(name)


#: set when a command ended on a stop signal: ``run`` then exits without waiting for work a
#: signal left running in a worker thread (a compile, a compiled call)
_STOPPED = {"signum": None}


#: glibc's ``mallopt`` parameter number of ``M_ARENA_MAX``
_M_ARENA_MAX = -8
#: Python's garbage-collector thresholds for the executable (the first is 700 by default):
#: tracing and lowering make many short-lived objects, and the collector then walks the
#: tracer's large live graph again and again. Tracing and lowering two COGNet-DICE
#: ``make_train`` programs three times took 3.3-3.8 s instead of 3.6-4.4 s; the test suite
#: (tests/conftest.py) uses them too. No number changes.
GC_THRESHOLDS = (50_000, 20, 20)


def limit_malloc_arenas() -> None:
    """At most one malloc arena per CPU (glibc's default is 8 per CPU): XLA's threads then
    reuse freed memory instead of each holding its own. The 2025-state fire fighting run of
    issue 33 peaks at 0.95 GB instead of 1.05 GB, at the same speed. Nothing happens where the
    C library is not glibc or ``MALLOC_ARENA_MAX`` is set."""
    if os.environ.get("MALLOC_ARENA_MAX") or not sys.platform.startswith("linux"):
        return
    try:
        import ctypes

        libc = ctypes.CDLL("libc.so.6")
        libc.mallopt(_M_ARENA_MAX, max(2, os.cpu_count() or 2))
    except (OSError, AttributeError):  # not glibc
        pass


def set_up_process() -> None:
    """What the executable sets in its process before ``main``: malloc's arenas
    (``limit_malloc_arenas``) and the garbage collector's thresholds (``GC_THRESHOLDS``)."""
    limit_malloc_arenas()
    gc.set_threshold(*GC_THRESHOLDS)


def run() -> None:
    """The ``cognet-jax`` executable: ``main`` with the process's arguments, in a process set
    up by ``set_up_process``. After a stop signal, or with a non-daemon thread still running
    (one an ``--import`` module started), the process ends with ``os._exit`` (the output
    flushed first): the interpreter's shutdown would otherwise wait for that thread, or tear
    down under a computation still running in XLA (a segmentation fault)."""
    set_up_process()
    code = main()
    lingering = [
        t
        for t in threading.enumerate()
        if t is not threading.main_thread() and not t.daemon and t.is_alive()
    ]
    if lingering:  # e.g. started by an --import module: the command is done, do not wait
        names = ", ".join(sorted({t.name for t in lingering}))
        print(f"warning: not waiting for thread(s) still running: {names}", file=sys.stderr)
    if _STOPPED["signum"] is not None or lingering:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    sys.exit(code)


def main(argv: list[str] | None = None) -> int:
    install_stop_handlers()
    argv = sys.argv[1:] if argv is None else list(argv)
    args = argparse.Namespace(debug="--debug" in argv)
    try:
        args = _merge_common(_parser().parse_args(argv))
        for name in args.imports:
            import_plugin(name)
        if args.command in ("train", "sweep", "evaluate"):
            use_compile_cache(args)
        return {
            "train": _train,
            "sweep": _sweep,
            "evaluate": _evaluate,
            "check": _check,
            "vae": _vae,
            "list": _list,
            "inspect": _inspect,
        }[args.command](args)
    except (InputError, OSError) as err:  # config, parse, corrupt-file and usage errors
        if args.debug:
            raise
        print(f"error: {_one_line(err)}", file=sys.stderr)
        return 2
    except Stopped as err:
        _STOPPED["signum"] = err.signum
        print(f"error: stopped by {err}", file=sys.stderr)
        return 128 + err.signum
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return 130
    except Exception as err:  # a bug, not a bad input: one line, the traceback with --debug
        if args.debug:
            raise
        print(
            f"error: internal error {type(err).__name__}: {_one_line(err)} "
            "(run again with --debug for the traceback)",
            file=sys.stderr,
        )
        return 1


if __name__ == "__main__":
    run()
