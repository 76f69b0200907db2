"""A sweep's size before anything is built for its runs: refused when its runs together
would simulate for longer than ``budget.ABSURD_SECONDS``, announced with its estimate when it
is large (the command line's ``sweep``)."""

from __future__ import annotations

import sys

from cognet_jax.api import build_env
from cognet_jax.budget import ABSURD_SECONDS, LONG_SECONDS, check_budget, estimated_seconds
from cognet_jax.config import ConfigError
from cognet_jax.registry import load_config

#: a sweep of more runs than this is announced with its estimate before it is prepared
MANY_RUNS = 1000


def _duration(seconds: float) -> str:
    """``seconds`` in the unit that reads best: s, min or h."""
    if seconds < 60:
        return f"{seconds:.1f} s"
    if seconds < 3600:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.1f} h"


def size_sweep(experiment: str, overrides: list[str], seeds: int, total: int) -> None:
    """Refuse, before anything is built for each run, a sweep whose runs together take more
    than ``budget.ABSURD_SECONDS`` of simulation (the first setting's estimate times the runs);
    announce a large one (over ``MANY_RUNS`` runs, or over ``budget.LONG_SECONDS``)."""
    config = load_config(experiment, overrides)
    env = build_env(config)[0]
    seconds = estimated_seconds(config, env) * total
    settings = total // max(seeds, 1)
    what = f"{total} runs ({settings} settings x {seeds} seeds)"
    if seconds > ABSURD_SECONDS:
        check_budget(config, env)  # one run alone too long: refused naming its own field
        field = "seeds" if seeds >= settings else "grid"
        raise ConfigError(
            field,
            f"the sweep's {what} simulate at least {seconds / 86400:.0f} days together, over "
            f"the limit of {ABSURD_SECONDS / 86400:.0f} days",
        )
    if total > MANY_RUNS or seconds > LONG_SECONDS:
        print(
            f"sweep: {what}, at least {_duration(seconds)} of simulation; preparing them ...",
            file=sys.stderr,
            flush=True,
        )
