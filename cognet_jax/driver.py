"""The one driver: runs a group of searches from the command line -- compile once
(``program.Program``), iterate with a progress bar and checkpoints (``loop.iterate``), stop
cleanly on signals, run the algorithm's ``finish``, evaluate every best policy honestly, write
each run's folder (``records.write_run``). ``train`` is a group of one run; a sweep
(``cognet_jax.sweep``) runs one group per set of settings that differ only in dynamic fields.

Signals (``cognet_jax.signals``): SIGINT, SIGTERM and SIGHUP during the iterations stop the
group after the current iteration (``signals.deferred_stop``); its checkpoint and every run's
best policy so far are written and ``Interrupted`` is raised (the CLI exits with ``128 +
signal``). Checkpoints are written every ``run.checkpoint_every`` iterations and every
``run.checkpoint_seconds`` seconds of search (atomic, ``checkpoint.save_checkpoint``);
``resume`` continues from one bit for bit. Reading run folders back: ``saved_runs``.
"""

from __future__ import annotations

import dataclasses
import signal
import sys
import time
from pathlib import Path
from typing import Any

from cognet_jax.after_search import Finished, Probes, finish_and_evaluate
from cognet_jax.api import Built
from cognet_jax.atomic_files import plain
from cognet_jax.budget import FASTEST_RATE, LONG_SECONDS
from cognet_jax.checkpoint import (
    CHECKPOINT_NAME,
    stack_history,
)
from cognet_jax.compiled import rollout_mesh
from cognet_jax.config import Config
from cognet_jax.loop import STOP_GRACE_S, Checkpointing, iterate
from cognet_jax.memory import MemoryOverBudget, peak_rss_bytes
from cognet_jax.program import Program, Run
from cognet_jax.records import (
    check_finite_values,
    draw_figures,
    history_fields,
    own_run_files,
    restore_group,
    restored_history,
    run_record,
    save_group,
    write_run,
)
from cognet_jax.run_folder import replacing
from cognet_jax.signals import Stopped, deferred_stop, in_background


class Interrupted(Exception):
    """A group stopped by a signal after writing its checkpoint and every run's best policy, or
    (``busy``) with an iteration still computing, which any read of the state would wait for:
    then nothing is written (``kept``: an earlier checkpoint is there to resume). ``signum`` is
    the signal (the CLI exits with ``128 + signum``)."""

    def __init__(
        self,
        out_dir: Path,
        iteration: int,
        iterations: int,
        signum: int = 2,
        busy=False,
        kept: bool = True,
        kept_old: bool = False,
    ):
        self.out_dir, self.iteration, self.signum = Path(out_dir), iteration, int(signum)
        name = signal.Signals(self.signum).name
        if busy:  # an iteration still computing: any read of the state would wait for it
            earlier = (
                f"an earlier checkpoint there continues with --resume {out_dir}"
                if kept
                else "no checkpoint had been written yet"
            )
            message = (
                f"interrupted during iteration {iteration + 1}/{iterations} ({name}), still "
                f"computing {STOP_GRACE_S:g} s after the signal: nothing new written to "
                f"{out_dir} ({earlier})"
            )
        elif kept_old:  # --overwrite stopped: the replaced run stays readable
            message = (
                f"interrupted at iteration {iteration}/{iterations} ({name}): checkpoint "
                f"written to {out_dir}, beside the results of the run it replaces, which stay "
                f"until it finishes; continue with --resume {out_dir}"
            )
        else:
            message = (
                f"interrupted at iteration {iteration}/{iterations} ({name}): best policy and "
                f"checkpoint written to {out_dir}; continue with --resume {out_dir}"
            )
        super().__init__(message)


@dataclasses.dataclass
class GroupOptions:
    """How ``run_group`` drives a group: ``checkpoint`` file (``None``: none), ``resume`` from
    it, ``progress`` bar (``None``: ``run.progress``), ``log`` for lines a person reads, ``desc``
    of the bar, ``resume_dir`` named by ``Interrupted``, ``announce``: a run of its own
    (``train``), which logs its result and draws its plots (``run.plots``); a sweep's runs do
    neither (the sweep writes its tables); ``built``: the first run's ``api.build``, when the
    caller made it (else the group builds it); ``lanes``: the runs side by side at least (a
    sweep's last batch is padded to its other batches' size, ``batches``: one program)."""

    checkpoint: Path | None = None
    resume: bool = False
    progress: bool | None = None
    log: Any = print
    desc: str | None = None
    resume_dir: Path | None = None
    announce: bool = False
    built: Built | None = None
    lanes: int = 0


def _stop(program: Program, state, iteration: int, opts: GroupOptions, signum):
    """Keep what a stopped group has (checkpoint, every run's best policy) and raise
    ``Interrupted``."""
    kept_old = False
    with deferred_stop():  # what was found is written even if the signal comes again
        best = program.best_policies(state)
        for r, run in enumerate(program.runs):
            if run.folder is not None and replacing(run.folder):
                kept_old = True  # --overwrite: the replaced run's results stay until the end
                continue
            record = run_record(run, program, status="interrupted", iteration=iteration)
            write_run(run, dict(record, final_value=None), best[r], program.algorithm)
    raise Interrupted(
        _stop_dir(opts), iteration, program.config.algorithm.iterations, signum, kept_old=kept_old
    )


def _stop_dir(opts: GroupOptions) -> Path:
    """The folder a stopped group names for ``--resume``."""
    return opts.resume_dir or (opts.checkpoint.parent if opts.checkpoint else Path("."))


def run_group(runs: list[Run], opts: GroupOptions | None = None) -> tuple[list[dict], dict]:
    """Run every run of ``runs`` (one compiled program; see the module docstring) and write
    their folders; returns ``(records, timing)``, one results.json record per run.

    ``opts.checkpoint`` is written every ``run.checkpoint_every`` iterations, every
    ``run.checkpoint_seconds`` seconds, at the end of the search and on a stop signal (then
    ``Interrupted`` is raised, naming ``opts.resume_dir``); ``opts.resume`` continues from it
    bit for bit."""
    opts = opts or GroupOptions()
    config = runs[0].config
    if opts.progress is None:
        opts = dataclasses.replace(opts, progress=config.run.progress)
    with rollout_mesh(config):
        return _run(runs, opts, time.perf_counter())


@dataclasses.dataclass
class _Searched:
    """A group's search, done: its final state, per-iteration metrics, the iteration it
    started from, and timings (seconds; ``t_start``, ``t_loop`` and ``t_searched``, the end of
    the loop before its checkpoint is written: ``time.perf_counter``)."""

    state: Any
    history: list
    start: int
    compile_s: float
    t_start: float
    t_loop: float
    t_searched: float
    probes: Any = None


def _prepare(runs: list[Run], opts: GroupOptions):
    """``(program, state, history, start, step, compile_s)``: the group's program built, its
    state initialised or restored from ``opts.checkpoint``, one iteration compiled;
    ``compile_s``: the initial state's and the iteration's programs, compiled or loaded. Run in a
    worker thread (``signals.in_background``): a stop signal ends the command at once, leaving
    the folder as it was (no iteration has finished)."""
    config = runs[0].config
    what = f"{config.experiment.name}" + (f" ({len(runs)} runs)" if len(runs) > 1 else "")

    def announce():  # once the iteration passed the memory check: a refusal is the only line
        print(f"compiling {what} ...", file=sys.stderr, flush=True)

    def prepare():
        with rollout_mesh(config):
            program = Program(runs, opts.built, opts.lanes)  # built and checked once
            _warn_if_long(program, len(runs))
            t0 = time.perf_counter()
            state, raw, start = _before_search(program.init), None, 0
            init_s = time.perf_counter() - t0  # its compilation (the run is dispatched)
            if opts.resume and opts.checkpoint is not None and opts.checkpoint.exists():
                state, raw, start = restore_group(program, state, opts.checkpoint)
                total = config.algorithm.iterations
                opts.log(f"resuming {config.experiment.name} at iteration {start}/{total}")
            step, step_s = _before_search(program.compile_step, state, announce)
            t1 = time.perf_counter()
            _before_search(program.compile_finish, state)  # its memory checked before the search
            compile_s = init_s + step_s + time.perf_counter() - t1
            print(f"compiled {what} in {compile_s:.1f} s", file=sys.stderr, flush=True)
            history = [] if raw is None else restored_history(step, raw, opts.checkpoint)
        return program, state, history, start, step, compile_s

    return in_background(prepare)


def _before_search(compile_fn, *args):
    """``compile_fn(*args)``, a group's initial state or iteration compiled: a program over
    the memory budget is marked ``before_search`` (fewer runs side by side would fit it,
    ``batches``; nothing of the group has run)."""
    try:
        return compile_fn(*args)
    except MemoryOverBudget as err:
        err.before_search = True
        raise


def _warn_if_long(program: Program, runs: int) -> None:
    """One line before compiling when the group's runs take over ``LONG_SECONDS`` even at the
    fastest rate measured (``budget.check_budget``'s estimate, made when it was built)."""
    seconds = program.built.seconds * runs
    if seconds > LONG_SECONDS:
        print(
            f"warning: {program.config.experiment.name}: {runs} run(s) of at least "
            f"{seconds / 3600:.1f} h of simulation (agent-steps at {FASTEST_RATE:.0e}/s, the "
            "fastest rate measured; the progress bar shows this machine's)",
            file=sys.stderr,
        )


def _search(runs, opts: GroupOptions, t_start: float):
    """``(program, _Searched)``: every iteration of the group, from its start or its
    checkpoint; on a stop signal (also one during the last iteration) the checkpoint and the
    best policies so far are written and ``Interrupted`` is raised."""
    program, state, history, start, step, compile_s = _prepare(runs, opts)
    config = program.config
    run = config.run
    checkpointing = Checkpointing(opts.checkpoint, run.checkpoint_every, run.checkpoint_seconds)

    def save(i, state, history):
        save_group(program, opts.checkpoint, i, state, history)

    t_loop = time.perf_counter()
    probes = Probes(program, run.probe_seconds, t_start)
    state, signum, in_flight = iterate(
        step,
        state,
        start=start,
        iterations=config.algorithm.iterations,
        history=history,
        checkpointing=checkpointing,
        save=save,
        progress=opts.progress,
        desc=opts.desc or config.experiment.name,
        probe=probes if run.probe_seconds > 0 else None,
    )
    t_searched = time.perf_counter()
    if signum is not None and in_flight:
        kept = opts.checkpoint is not None and opts.checkpoint.is_file()
        raise Interrupted(
            _stop_dir(opts), len(history), config.algorithm.iterations, signum, True, kept
        )
    if opts.checkpoint is not None:
        with deferred_stop() as flag:  # a signal now stops the group once this is written
            save(len(history), state, history)
        signum = signum if signum is not None else flag["signum"]
    if signum is not None:
        _stop(program, state, len(history), opts, signum)
    searched = _Searched(state, history, start, compile_s, t_start, t_loop, t_searched, probes)
    return program, searched


def _run(runs, opts: GroupOptions, t_start: float):
    """``(records, timing)`` of the group: search, its finish, the honest evaluation of
    every run's best policy, its folder. A stop signal after the search keeps the search's best
    policies (``_stop``); one while the folders are written lets them be finished first."""
    program, done = _search(runs, opts, t_start)
    iterations = program.config.algorithm.iterations
    stacked = stack_history(done.history)  # on the host: a jnp.stack of 500 arrays compiles
    check_finite_values(stacked, program)
    t_end = time.perf_counter()
    try:
        finished = finish_and_evaluate(program, done.state, opts.progress, done.probes)
    except Stopped as stop:
        _stop(program, done.state, iterations, opts, stop.signum)
    timing = {
        "compile_s": done.compile_s,
        "loop_s": done.t_searched - done.t_loop + finished.seconds,
        "eval_s": time.perf_counter() - t_end - finished.seconds,
        "runs": len(runs),
        "resumed_from_iteration": done.start or None,
    }
    try:  # the search's own hooks (history_record, settings_record, run_files) run here,
        # where a stop still stops them, not in the deferred section that writes the folders
        records = _records(program, done, stacked, opts, timing, finished)
        files = own_run_files(program.algorithm)
    except Stopped as stop:
        _stop(program, done.state, iterations, opts, stop.signum)
    with deferred_stop() as flag:
        for r, run in enumerate(program.runs):
            write_run(run, records[r], finished.best[r], program.algorithm, files)
    drawn = [False] * len(records)
    if flag["signum"] is None:
        try:  # a stop here ends the figures at once: the results are written
            drawn = [
                opts.announce
                and run.config.run.plots
                and draw_figures(run, records[r], finished.best[r], program.algorithm)
                for r, run in enumerate(program.runs)
            ]
        except Stopped as stop:
            flag["signum"] = stop.signum
    if opts.announce:
        _log_run(records[0], runs[0], program.algorithm, opts.log, drawn[0])
    if flag["signum"] is not None:
        raise Stopped(flag["signum"], after="the results were written")
    return records, timing


def _records(program, done, stacked, opts, timing, finished: Finished) -> list:
    """Every run's record (results.json)."""
    iterations = program.config.algorithm.iterations
    records = []
    for r, run in enumerate(program.runs):
        history = history_fields(
            stacked, r if program.batched else None, iterations, program.algorithm
        )
        record = run_record(
            run,
            program,
            status="complete",
            iteration=iterations,
            resumed_from_iteration=done.start if opts.resume else None,
            final_value=finished.finals[r],
            finish=finished.records[r],
            wall_s=time.perf_counter() - done.t_start,
            **{k: timing[k] for k in ("compile_s", "loop_s", "eval_s")},
            peak_rss_bytes=peak_rss_bytes(),
            **history,
        )
        if finished.probed[r] is not None:
            record["probes"] = finished.probed[r]
        records.append(plain(record))  # as results.json holds it: one record, file or not
    return records


def _log_run(record: dict, run: Run, algorithm, log, drawn: bool) -> None:
    final = record["final_value"]
    line = algorithm.finish_line(record["finish"]) if record["finish"] is not None else None
    if line:  # the search's code: one line of its own, never one that looks like ours
        log(" ".join(str(line).split()))
    exact = f" (exact {final['exact']:.6f})" if "exact" in final else ""
    log(
        f"{record['experiment']} seed {record['seed']}: honest value {final['mean']:.3f} "
        f"+- {final['stderr']:.3f} ({final['rollouts']} rollouts){exact}; in-loop best "
        f"{record['in_loop_best']:.3f}; wall {record['wall_s']:.1f} s (compile "
        f"{record['compile_s']:.1f} s)"
    )
    if run.folder is not None:
        plots = " and plots" if drawn else ""
        log(f"wrote {run.folder}/results.json, policy.msgpack{plots}")


def train(
    config: Config | Built, seed: int, out_dir, progress=None, log=print, resume=False
) -> dict:
    """Run the search of ``config`` (or of a ``api.build`` of it, used as built) with ``seed``
    and write its folder ``out_dir``: the group of one run (``run_group``), checkpointed to
    ``out_dir/checkpoint.msgpack``; ``resume`` continues from that checkpoint. Returns the
    run's results.json record."""
    built = config if isinstance(config, Built) else None
    config = built.config if built else config
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    opts = GroupOptions(
        out / CHECKPOINT_NAME, resume, progress, log, resume_dir=out, announce=True, built=built
    )
    records, _ = run_group([Run(config, seed, out)], opts)
    return records[0]
