"""What follows a group's search: the algorithm's ``finish`` with its progress line, every
run's honest evaluation (``finish_and_evaluate``, in a worker thread so a stop signal is obeyed
at once), and the snapshots of the anytime best taken during the search (``Probes``: the time
to a value, evaluated only now, so the search's time is not spent on them)."""

from __future__ import annotations

import dataclasses
import math
import sys
import time

import jax
from tqdm.auto import tqdm

from cognet_jax.budget import evaluation_line
from cognet_jax.compiled import rollout_mesh
from cognet_jax.hook_results import FINAL_VALUE_FIELDS, checked_record
from cognet_jax.program import Program, same_tree, take
from cognet_jax.signals import Stopped, in_background


class Probes:
    """Snapshots of every run's anytime best, looked at each ``seconds`` of the run (from its
    start, compile included) and kept when it changed: ``(iteration, wall seconds, best
    policies)``. ``evaluated`` gives each
    its honest evaluation once the search is over (the search's time is not spent on them)."""

    def __init__(self, program: Program, seconds: float, t_start: float):
        self.program, self.seconds, self.t_start = program, seconds, t_start
        self.kept: list = []
        self.last = -math.inf

    def __call__(self, iteration: int, state) -> None:
        now = time.perf_counter()
        if now - self.last >= self.seconds:
            self.last = now
            best = jax.device_get(self.program.best_policies(state))
            if not self.kept or not same_tree(best, self.kept[-1][2]):  # a new best only
                self.kept.append((iteration, now - self.t_start, best))

    def evaluated(self, r: int) -> list[dict]:
        """Run ``r``'s probes with their honest values."""
        out = []
        for iteration, wall, best in self.kept:
            value = self.program.final_value(r, best[r])
            out.append({"iteration": iteration, "wall_s": wall, "value": value["mean"]})
        return out


@dataclasses.dataclass
class Finished:
    """What ``finish_and_evaluate`` returns: every run's ``finish`` record (the search's
    ``finish_record``), honest value (with the search's ``exact_record``), best policy and
    evaluated probes, and the seconds ``finish`` took."""

    records: list
    finals: list
    best: list
    probed: list
    seconds: float


def finish_and_evaluate(program: Program, state, progress: bool, probes=None) -> Finished:
    """The algorithm's ``finish`` (with a progress line when ``progress``), every run's honest
    evaluation and that of its probes (``Probes``), in a worker thread
    (``signals.in_background``), so a stop signal is obeyed at once."""
    algorithm = program.algorithm
    line = FinishLine(progress, algorithm)

    def work():
        t_finish = time.perf_counter()
        try:
            finished, info = jax.block_until_ready(program.finish(state, line.report))
        finally:
            line.close_finish()
        seconds = time.perf_counter() - t_finish
        runs = range(len(program.runs))
        if info is not None:
            info = jax.device_get(info)
        infos = [take(info, r) if program.batched and info is not None else info for r in runs]
        records = [
            checked_record(algorithm, "finish_record", algorithm.finish_record(i, seconds)) or None
            for i in infos
        ]
        best = program.best_policies(finished)
        what = "the best policy" if len(best) == 1 else f"{len(best)} best policies"
        big = evaluation_line(program.config, program.built.env, what)
        if big is not None:
            print(big, file=sys.stderr, flush=True)
        finals = []
        line.evaluating(len(program.runs))
        for r, run in enumerate(program.runs):
            final = program.final_value(r, best[r])
            exact = algorithm.exact_record(run.config, best[r])
            final.update(checked_record(algorithm, "exact_record", exact, FINAL_VALUE_FIELDS))
            finals.append(final)
            line.evaluated()
        line.close()
        probing = probes is not None and probes.seconds > 0
        kept = [probes.evaluated(r) if probing else None for r in runs]
        return Finished(records, finals, best, kept, seconds)

    with rollout_mesh(program.config):
        try:
            return in_background(work)
        except Stopped:
            line.close()  # the stop's line starts on a line of its own
            raise


class FinishLine:
    """The progress lines after the search (shown with ``progress``): ``finish``'s, from its
    first step (the steps, the time and the search's own fields, ``finish_status``), then the
    honest evaluation's, runs evaluated, when there are several runs."""

    def __init__(self, progress: bool, algorithm):
        self.progress, self.bar, self.algorithm = progress, None, algorithm
        self.evaluation = None

    def report(self, work) -> None:
        if not self.progress:
            return
        if self.bar is None:
            self.bar = tqdm(desc="finish", unit="step", dynamic_ncols=True)
        self.bar.update(1)
        status = self.algorithm.finish_status(work)
        if status:
            self.bar.set_postfix(**status)

    def close_finish(self) -> None:
        bar, self.bar = self.bar, None
        if bar is not None:
            bar.close()

    def evaluating(self, runs: int) -> None:
        if self.progress and runs > 1:
            self.evaluation = tqdm(
                total=runs, desc="honest evaluation", unit="run", dynamic_ncols=True
            )

    def evaluated(self) -> None:
        bar = self.evaluation
        if bar is not None:
            bar.update(1)

    def close(self) -> None:
        """Both lines closed, and no new one after this (on a stop the worker may go on)."""
        self.progress = False
        self.close_finish()
        bar, self.evaluation = self.evaluation, None
        if bar is not None:
            bar.close()
