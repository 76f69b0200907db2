"""The headline ratio measured in paired rounds: JAX and the torch references timed back to back.

This VM runs in phases: for seconds at a time a process runs up to 2.5x slower, JAX and torch
alike (a fixed Python loop takes 0.83-1.78 s; the same compiled 6-node rollouts took 5.3 ms a
call in one block and 13.1 ms in a later block of the same process; torch.compile's 3-node
rollouts 33.0 and 48.5 ms). Timed one after the other, seconds apart, the two may meet
different phases: four such measurements in one process gave the 6-node ratio as 19.6, 17.9,
6.4 and 6.1x (benchmarks/NOTES.md, tenth pass).
Here every round runs each implementation in turn: calls for ``SETTLE_S`` untimed, then
``CALLS_PER_ROUND`` timed calls, so the ratio of a round compares the implementations in the
same phase; the ratio reported is the median over the rounds, with the lowest and highest
round beside it. The untimed calls let the previous implementation's threads stop first: right
after a torch call JAX's next one or two calls took 5-6 ms instead of 3.4-3.5 (torch's OpenMP
workers keep spinning for a few milliseconds after their work; with ``OMP_WAIT_POLICY=PASSIVE``
they did not), and after 40 ms of idle cores JAX's calls stayed slow for longer.
"""

from __future__ import annotations

import statistics

from benchmarks.timing import time_calls, warm_up

#: timed calls of each implementation per round, and rounds
CALLS_PER_ROUND = 3
ROUNDS = 11
#: seconds of untimed calls before an implementation's timed calls in a round
SETTLE_S = 0.05


def paired_rounds(calls: dict, rounds: int = ROUNDS, per_round: int = CALLS_PER_ROUND) -> dict:
    """``{name: [seconds per call, one per round]}``: ``calls`` (name -> ``call()``, each
    warmed up first) timed in turn in every round, the median of ``per_round`` calls each
    after ``SETTLE_S`` seconds (at least one call) of untimed ones."""
    for call in calls.values():
        warm_up(call)
    seconds: dict = {name: [] for name in calls}
    for _ in range(rounds):
        for name, call in calls.items():
            warm_up(call, calls=1, seconds=SETTLE_S)
            seconds[name].append(time_calls(call, runs=per_round, warmup=0).median_s)
    return seconds


def round_ratios(seconds: dict, mine: str, others: list[str]) -> list[float]:
    """Per round: the fastest of ``others`` (seconds per call) over ``mine``'s."""
    rounds = len(seconds[mine])
    return [min(seconds[o][i] for o in others) / seconds[mine][i] for i in range(rounds)]


def summary(seconds: dict, mine: str, others: list[str]) -> dict:
    """``mine`` against the fastest of ``others`` round by round: the median, lowest and
    highest ratio, and every implementation's median seconds per call."""
    ratios = round_ratios(seconds, mine, others)
    return dict(
        ratio=statistics.median(ratios),
        ratio_min=min(ratios),
        ratio_max=max(ratios),
        ratios=ratios,
        median_s={name: statistics.median(s) for name, s in seconds.items()},
    )
