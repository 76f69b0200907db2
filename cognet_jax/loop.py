"""The search loop of a group (``iterate``): iterations dispatched ahead of the one waited for,
a progress bar, checkpoints by count and by time, and a stop signal obeyed between
iterations (``signals.deferred_stop``)."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import jax
import numpy as np
from tqdm.auto import tqdm

from cognet_jax.signals import deferred_stop, wait_for


@dataclasses.dataclass
class Checkpointing:
    """When a group saves its state: ``path`` of the checkpoint file (``None``: never),
    every ``every`` iterations and every ``seconds`` seconds of search (0: not by that)."""

    path: Path | None
    every: int = 0
    seconds: float = 0.0

    def due(self, iteration: int, since_last: float) -> bool:
        """Whether a checkpoint is due after ``iteration``, ``since_last`` seconds after the
        last one."""
        if self.path is None:
            return False
        by_count = self.every > 0 and iteration % self.every == 0
        return by_count or (self.seconds > 0 and since_last >= self.seconds)


#: seconds a stopped loop waits for the iteration in flight before it keeps the last finished one
STOP_GRACE_S = 5.0


#: the loop dispatches iterations ahead of the one it waits for, about this many seconds of
#: them (at least 2; at most ``AHEAD_MAX`` and ``AHEAD_BYTES`` of search states)
AHEAD_S = 0.1
#: iterations longer than this are dispatched one at a time: the host's gap between two is
#: then under 1% of one, and a stop waits for one iteration, not two (a second one queued
#: kept a stopped paper-setting run writing its checkpoint 4.6 s after the first had ended)
ONE_AHEAD_S = 0.5


AHEAD_MAX = 256


AHEAD_BYTES = 256 * 2**20


def wait_ready(tree, flag=None, timeout: float | None = None) -> bool:
    """Wait until every array of ``tree`` is computed; ``False`` when ``flag["signum"]`` is
    set (a stop signal) or ``timeout`` seconds pass first. The blocking wait runs in a waiter
    thread (``signals.wait_for``), so the main thread stays free for signal handlers."""
    leaves = [x for x in jax.tree.leaves(tree) if isinstance(x, jax.Array)]
    pause = 1e-4
    while pause < 0.01:  # a short wait polls (cheaper than waking a thread)
        if all(x.is_ready() for x in leaves):
            return True
        time.sleep(pause)
        pause *= 2
    return wait_for(jax.block_until_ready, leaves, flag, timeout)


class Ahead:
    """How many iterations the loop keeps dispatched: about ``AHEAD_S`` seconds of them, from
    the mean time between finished iterations, so short iterations queue up (the dispatch
    overhead hides behind the computation) while long ones stay two deep, and those longer
    than ``ONE_AHEAD_S`` one deep (the first one alone, until its time is known); bounded by
    ``AHEAD_MAX`` and by ``AHEAD_BYTES`` of search states in flight."""

    def __init__(self, state):
        size = sum(x.nbytes for x in jax.tree.leaves(state) if hasattr(x, "nbytes"))
        self.cap = int(max(2, min(AHEAD_MAX, AHEAD_BYTES // max(size, 1))))
        self.depth, self.count, self.t0 = 1, 0, time.perf_counter()

    def finished(self) -> None:
        self.count += 1
        mean = (time.perf_counter() - self.t0) / self.count
        if mean > ONE_AHEAD_S:
            self.depth = 1
        else:
            self.depth = int(max(2, min(self.cap, AHEAD_S / max(mean, 1e-6))))


def iterate(
    step, state, *, start, iterations, history, checkpointing, save, progress, desc, probe=None
):
    """``state, metrics = step(state)`` from iteration ``start`` to ``iterations``, each
    finished iteration's metrics appended to ``history``; returns ``(state, signum,
    in_flight)``: the state after the last finished iteration (``len(history)``), the stop
    signal that came during the loop (``None`` when none did), and whether an iteration was
    still computing ``STOP_GRACE_S`` after it (then reading any array waits for that
    iteration: nothing more can be written promptly).

    Iterations are dispatched ahead of the one waited for (``Ahead``: about 0.1 s of them, at least
    2, one at a time when each takes over ``ONE_AHEAD_S``); the loop waits on an event
    (``wait_ready``), so a stop signal is seen at once. It then waits at most ``STOP_GRACE_S`` for
    the oldest iteration in flight and keeps the last finished state.
    ``save(i, state, history)`` writes a checkpoint (``checkpointing``); ``probe(i, state)``
    is called after every finished iteration (``Probes``)."""
    last_save = time.perf_counter()
    bar = tqdm(total=iterations, disable=not progress, desc=desc, unit="it", dynamic_ncols=True)
    done, flight = state, []  # the last finished state; (state, metrics) dispatched, oldest first
    ahead = Ahead(state)
    with deferred_stop() as flag, bar:
        bar.update(start)
        while len(history) < iterations:
            while len(flight) < ahead.depth and len(history) + len(flight) < iterations:
                if flag["signum"] is not None:
                    break
                flight.append(step(flight[-1][0] if flight else done))
            if not flight:
                break
            state, metrics = flight.pop(0)
            if not wait_ready(metrics, flag) and not wait_ready(metrics, timeout=STOP_GRACE_S):
                flag["in_flight"] = True  # XLA still runs it: reading any state waits for it
                break
            ahead.finished()
            done = state
            history.append(metrics)
            i = len(history)
            if flag["signum"] is not None:
                break
            if probe is not None:
                probe(i, done)
            if i < iterations and checkpointing.due(i, time.perf_counter() - last_save):
                save(i, done, history)
                last_save = time.perf_counter()
            if progress and (i % 10 == 0 or i == iterations):
                bar.set_postfix(**_postfix(jax.device_get(metrics)))
                bar.update(i - bar.n)
    return done, flag["signum"], bool(flag.get("in_flight"))


def _postfix(metrics) -> dict:
    value, best = np.asarray(metrics.value), np.asarray(metrics.in_loop_best)
    return {"value": f"{float(value.mean()):.2f}", "best": f"{float(best.max()):.2f}"}
