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
import gc
import logging
import math
import os
import select
import shutil
import signal
import sys
import threading
import time
import warnings
from pathlib import Path

from cognet_jax import status
from cognet_jax.atomic_files import json_text
from cognet_jax.cli_parser import DEFAULT_EXPERIMENT, merge_common, parser
from cognet_jax.compile_cache import use_compile_cache
from cognet_jax.config import ConfigError, builtin_experiments, parse_override, read_experiment
from cognet_jax.errors import InputError, OneLineWarning, UsageError, callback_failure
from cognet_jax.hosts import (
    backend_error,
    check_jax_settings,
    check_xla_flags,
    init_distributed,
    set_cpu_devices,
)
from cognet_jax.io.dpomdp import parse_dpomdp
from cognet_jax.plugins import import_plugin, one_line, user_code_error
from cognet_jax.registry import begin_command, load_config
from cognet_jax.run_folder import check_out, claim, reading, worth_keeping
from cognet_jax.signals import (
    Stopped,
    arm_stop_deadline,
    exit_on_stop,
    in_background,
    install_stop_handlers,
    restore_stop_handlers,
    stop_received,
)


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
        if not existed and out.is_dir() and not worth_keeping(out):
            shutil.rmtree(out, ignore_errors=True)
        raise


def _refuse_with_resume(args, flags: dict) -> None:
    """``UsageError`` naming the first of ``flags`` (flag -> value given, ``None`` or ``[]``
    when not given) that ``--resume`` contradicts: the run continues as it was started, and
    nothing of it is replaced (``--overwrite``)."""
    if getattr(args, "overwrite", False):
        raise UsageError(
            f"--overwrite cannot be given with --resume: {args.resume} is continued, not "
            "replaced (to replace it, give --out with --overwrite)"
        )
    for flag, value in flags.items():
        if value not in (None, []):
            raise UsageError(
                f"{flag} cannot be given with --resume: {args.resume} continues with the "
                "settings it was started with (only --set run.* fields may change)"
            )


def _train(args) -> int:
    from cognet_jax.driver import Interrupted, train
    from cognet_jax.saved_runs import finished_value, resume_target

    try:
        if args.resume:
            flags = {"EXPERIMENT": args.experiment, "--seed": args.seed, "--out": args.out}
            _refuse_with_resume(args, flags)
            config, seed = resume_target(args.resume, args.overrides + _run_overrides(args))
            with claim(Path(args.resume), resume=True):  # no other writer replaces it now
                done = finished_value(args.resume, config)
                if done is not None:
                    print(
                        f"{args.resume}: the run is complete ({config.algorithm.iterations} "
                        f"iterations, honest value {done['mean']:.3f}); nothing to resume, "
                        f"nothing written (`cognet-jax evaluate {args.resume}` values its "
                        "policy again)"
                    )
                    return 0
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
        if any(parse_override(o)[0] == ["run", "prng_impl"] for o in args.overrides):
            raise UsageError(  # its groups not yet run would draw with another generator
                "--set run.prng_impl cannot be given with --resume: the sweep's runs keep the "
                "generator it started with"
            )
        spec = read_spec(args.resume)
        experiment, seeds, grid = spec["experiment"], spec["seeds"], spec["grid"]
        overrides, out = spec["overrides"], Path(args.resume)
        run_sets = args.overrides + run_sets
        if len(seeds) * math.prod(len(v) for v in grid.values()) > MAX_RUNS:  # edited by hand
            raise UsageError(
                f"{args.resume}: its sweep.json holds more than {MAX_RUNS} runs (settings x "
                "seeds), more than a sweep may have"
            )
    else:
        n = 1 if args.seeds is None else args.seeds
        if n < 1:
            raise ConfigError("seeds", f"--seeds must be >= 1, got {n}")
        experiment = args.experiment or DEFAULT_EXPERIMENT
        grid = parse_grid(args.grid, args.overrides)
        overrides = args.overrides
        first = 0 if args.first_seed is None else args.first_seed
        if not 0 <= first <= first + n - 1 < 2**31:
            raise ConfigError(
                "first-seed",
                f"--first-seed {first} with --seeds {n}: seeds must be in 0 .. "
                f"2147483647, got {first} .. {first + n - 1}",
            )
        runs = n * math.prod(len(v) for v in grid.values())
        if runs > MAX_RUNS:  # before any list of them is made
            raise ConfigError(
                "seeds" if n >= runs // n else "grid",  # the larger factor
                f"the sweep has {runs} runs (settings x seeds); a sweep prepares each run in "
                f"Python (config, keys, folder) and holds at most {MAX_RUNS}: split it "
                "(--first-seed, fewer --grid values)",
            )
        seeds = list(range(first, first + n))
        check_out(args.out)
        out = Path(args.out or f"runs/sweep-{Path(experiment).stem}")
    processes = args.num_processes or 1
    total = len(seeds) * math.prod(len(v) for v in grid.values())
    if not args.resume:
        from cognet_jax.sweep_size import size_sweep

        size_sweep(experiment, overrides, len(seeds), total)
    set_cpu_devices(args.cpu_devices, -(-total // processes))
    init_distributed(args)
    import jax

    main_process = jax.process_index() == 0
    held = (
        claim(out, resume=bool(args.resume), overwrite=args.overwrite, kind="sweep")
        if main_process
        else contextlib.nullcontext()
    )
    removed = _removed_on_failure(out) if main_process else contextlib.nullcontext()
    try:
        with removed, held:
            return _sweep_claimed(
                args, experiment, seeds, grid, overrides, out, run_sets, main_process
            )
    except Interrupted as err:
        _STOPPED["signum"] = err.signum
        print(f"error: {err}", file=sys.stderr)
        return 128 + err.signum
    except Stopped as err:
        if not err.after:
            raise
        _STOPPED["signum"] = err.signum  # a group's runs written, the sweep's tables not
        print(
            f"error: stopped by {signal.Signals(err.signum).name} after a group's runs were "
            f"written, before the sweep's tables; continue with --resume {out}",
            file=sys.stderr,
        )
        return 128 + err.signum


#: a sweep of more runs than this is refused before it is prepared: each run is prepared in
#: Python (its config, keys and folder), about a millisecond each
MAX_RUNS = 100_000


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
        names = ", ".join(p.name for p in write_outputs(result, out))
        print((out / "summary.md").read_text())
        print(f"wrote {names} in {out}; each run's policy in")
        print(f"  {out}/runs/setting{{k}}-seed{{s}}/ (cognet-jax evaluate works on it)")
    return 0


def _evaluate(args) -> int:
    from cognet_jax.saved_runs import evaluate_run

    if args.rollouts is not None and not 2 <= args.rollouts < 2**31:
        raise UsageError(f"--rollouts must be in 2 .. 2147483647, got {args.rollouts}")
    if args.seed is not None and not 0 <= args.seed < 2**31:  # before seconds of loading
        raise UsageError(f"--seed must be in 0 .. 2147483647, got {args.seed}")
    if args.rollouts is not None and any(
        parse_override(o)[0] == ["evaluation", "rollouts"] for o in args.overrides
    ):
        raise UsageError("--rollouts and --set evaluation.rollouts both set the rollouts; give one")
    with reading(Path(args.run_dir)):  # no writer replaces the run while it is evaluated
        # in a worker thread: a stop signal ends the command at once, not after the evaluation
        value = in_background(
            lambda: evaluate_run(args.run_dir, args.rollouts, args.seed, args.overrides, status.say)
        )
        quiet = value.get("no_effect", [])
        own = [o for o in quiet if o in value.get("own_values", [])]
        if own:
            print(
                f"warning: --set {' '.join(own)} gives the run's own value: nothing changed",
                file=sys.stderr,
            )
        if len(own) < len(quiet):
            print(
                f"warning: --set {' '.join(o for o in quiet if o not in own)} changes nothing "
                "an evaluation reads (a field of the search or of the run, not of the "
                "simulator, the controller or the evaluation): the value is the run's own "
                "setting's",
                file=sys.stderr,
            )
        shown = [o for o in args.overrides if o not in quiet]
        print(
            f"value {value['mean']:.3f} +- {value['stderr']:.3f} ({value['rollouts']} rollouts, "
            f"seed {value['seed']}{', ' + ' '.join(shown) if shown else ''})"
        )
        log = Path(args.run_dir) / "evaluations.jsonl"
        try:
            with log.open("a") as f:
                f.write(json_text(value) + "\n")
        except OSError as err:  # the value stands; only its log could not be kept
            print(f"warning: not appended to {log}: {err.strerror}", file=sys.stderr)
            return 0
    print(f"appended to {log}")
    return 0


def _vae(args) -> int:
    from cognet_jax.cli_vae import vae_command

    return vae_command(args)


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
    print(f"{config.experiment.name}: valid; at least {seconds:.3g} s of search and evaluation")
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


#: set when a command ended on a stop signal: ``run`` then exits without waiting for work a
#: signal left running in a worker thread (a compile, a compiled call)
_STOPPED = {"signum": None}


#: glibc's ``mallopt`` parameter number of ``M_ARENA_MAX``
_M_ARENA_MAX = -8


#: Python's garbage-collector thresholds for the executable (the first is 700 by default):
#: tracing and lowering make many short-lived objects, and the collector then walks the
#: tracer's large live graph again and again, so fewer collections trace faster
#: (benchmarks/NOTES.md, "Measurements behind code choices"); the test suite
#: (tests/conftest.py) uses them too. No number changes.
GC_THRESHOLDS = (50_000, 20, 20)


def limit_malloc_arenas() -> None:
    """At most one malloc arena per CPU (glibc's default is 8 per CPU): XLA's threads then
    reuse freed memory instead of each holding its own: a lower peak at the same speed
    (benchmarks/NOTES.md, "Measurements behind code choices"). Nothing happens where the
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
    up by ``set_up_process``. After a stop signal, with a non-daemon thread still running (one
    an ``--import`` module started), or after any ``--import`` (whose ``atexit`` handlers may
    block), the process ends with ``os._exit`` (the output flushed first): the interpreter's
    shutdown would otherwise wait for that thread or handler, or tear down under a computation
    still running in XLA (a segmentation fault)."""
    set_up_process()
    arm_stop_deadline()  # a stop swallowed where Python ignores exceptions still ends it
    code = main()
    exit_on_stop()  # the work is done: a late stop signal ends the process without a traceback
    lingering = [
        t
        for t in threading.enumerate()
        if t is not threading.main_thread() and not t.daemon and t.is_alive()
    ]
    if lingering:  # e.g. started by an --import module: the command is done, do not wait
        names = ", ".join(sorted({t.name for t in lingering}))
        print(f"warning: not waiting for thread(s) still running: {names}", file=sys.stderr)
    if _STOPPED["signum"] is not None or lingering or _IMPORTED:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError):  # a closed pipe: nothing more to say
                pass
        os._exit(code)
    sys.exit(code)


def _stdout_gone() -> bool:
    """Whether the standard output is a pipe whose reader went away (``poll`` reports an
    error on its write end); if so, further output goes nowhere instead of raising again at
    exit."""
    try:
        fd = sys.stdout.fileno()
        poller = select.poll()
        poller.register(fd, select.POLLOUT)
        gone = any(ev & (select.POLLERR | select.POLLHUP) for _, ev in poller.poll(0))
        if gone:
            os.dup2(os.open(os.devnull, os.O_WRONLY), fd)
        return gone
    except (OSError, ValueError, AttributeError):  # no descriptor (a captured stdout)
        return False


def _one_line_warnings() -> None:
    """A ``OneLineWarning`` (simulator, config) is printed as one ``warning:`` line (not
    Python's two-line form naming this package's source)."""
    shown = warnings.showwarning
    if getattr(shown, "one_line", False):
        return

    def show(message, category, filename, lineno, file=None, line=None):
        if issubclass(category, OneLineWarning):
            print(f"warning: {one_line(message)}", file=sys.stderr)
            return None
        return shown(message, category, filename, lineno, file, line)

    show.one_line = True
    warnings.showwarning = show


def _after_imports(names: list[str]) -> None:
    """What ``--import`` modules may have changed in the process, put back or refused: the
    stop signals' handlers (restored, with a warning), a closed standard output or error (refused:
    the results or the errors would not be shown).
    Their ``atexit`` handlers are not run (``run`` ends the process with ``os._exit``)."""
    modules = ", ".join(names)
    changed = restore_stop_handlers()
    if changed:
        print(
            f"warning: --import {modules} replaced the handling of {', '.join(changed)}; "
            "cognet-jax's stop handling is back in place",
            file=sys.stderr,
        )
    if sys.stdout is None or sys.stdout.closed:
        raise UsageError(f"--import {modules} closed the standard output")
    for fd, stream in ((1, sys.stdout), (2, sys.stderr)):
        try:  # closed beneath Python's file object (``os.close(1)``): results never shown
            ours = stream is not None and stream.fileno() == fd
        except (OSError, ValueError):  # replaced by an object of no descriptor (a test's capture)
            ours = False
        if ours and not _fd_open(fd):
            if fd == 2:
                raise SystemExit(2)  # nowhere left to say it
            raise UsageError(f"--import {modules} closed the standard output (file descriptor 1)")
    _IMPORTED.extend(names)


def _fd_open(fd: int) -> bool:
    try:
        os.fstat(fd)
    except OSError:
        return False
    return True


#: the ``--import`` modules of this command (``run`` then ends without their exit handlers)
_IMPORTED: list[str] = []


def _stopped(err: Stopped) -> int:
    _STOPPED["signum"] = err.signum
    print(f"error: stopped by {err}", file=sys.stderr)
    return 128 + err.signum


def main(argv: list[str] | None = None) -> int:
    install_stop_handlers()
    _one_line_warnings()
    status.listener = lambda line: print(line, file=sys.stderr, flush=True)
    argv = sys.argv[1:] if argv is None else list(argv)
    args = argparse.Namespace(debug="--debug" in argv)
    if sys.stdout is None:  # started with its standard output closed (``>&-``)
        if sys.stderr is not None:
            print("error: standard output is closed: results could not be shown", file=sys.stderr)
        return 2
    try:
        args = merge_common(parser().parse_args(argv))
        if not args.debug:  # a callback's error is reported in one line (``callback_failure``)
            logging.getLogger("jax._src.callback").setLevel(logging.CRITICAL)
        begin_command()  # a name two of this command's --import modules register is named
        for name in args.imports:
            import_plugin(name)
        if args.imports:
            _after_imports(args.imports)
        if args.command not in ("list", "inspect"):
            check_jax_settings()
            check_xla_flags()
        if args.command in ("train", "sweep", "evaluate", "check"):
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
    except BrokenPipeError as err:
        if args.debug or not _stdout_gone():
            print(f"error: {one_line(err)}", file=sys.stderr)
            return 2
        return 128 + signal.SIGPIPE  # the reader went away (``cognet-jax list | head``)
    except (InputError, OSError) as err:  # config, parse, corrupt-file and usage errors
        if args.debug:
            raise
        print(f"error: {one_line(err)}", file=sys.stderr)
        return 2
    except Stopped as err:
        return _stopped(err)
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return 130
    except Exception as err:  # a bug, not a bad input: one line, the traceback with --debug
        if stop_received() is not None:  # the stop, raised inside a compiled call (JAX wraps it)
            return _stopped(Stopped(stop_received()))
        if args.debug:
            raise
        failed = callback_failure(err)
        mine = user_code_error(err) or backend_error(err)
        if mine is None and failed:
            mine = f"a Python callback raised at {failed}"
        if mine is not None:  # a user's --import module (theirs to fix), or no JAX backend
            print(f"error: {mine}", file=sys.stderr)
            return 2
        print(
            f"error: internal error {type(err).__name__}: {one_line(err)} "
            "(run again with --debug for the traceback)",
            file=sys.stderr,
        )
        return 1


if __name__ == "__main__":
    run()
