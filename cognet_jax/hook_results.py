"""What a search's record hooks return, checked before it goes into results.json
(``Search.history_record``, ``exact_record``, ``settings_record``, ``finish_record``,
``write_plots``): a search of one's own (``--import``) that returns something else is named
with its hook, in one line, instead of failing deep in the driver or replacing the fields the
driver writes (the honest value, the seed)."""

from __future__ import annotations

from pathlib import Path

from cognet_jax.atomic_files import json_text
from cognet_jax.errors import UsageError

#: the fields every run's results.json holds, written by the driver: no hook may set them
RUN_RECORD_FIELDS = frozenset(
    (
        "schema experiment algorithm seed setting grid config resolved iterations "
        "runs_in_program jax_version backend status iteration resumed_from_iteration "
        "final_value finish wall_s compile_s loop_s eval_s peak_rss_bytes in_loop_best "
        "simulated_agent_steps values_per_iteration in_loop_best_per_iteration probes "
        "policy_sha256 run_files"
    ).split()
)
#: the fields of the honest value: ``exact_record`` adds beside them, never over them
FINAL_VALUE_FIELDS = frozenset(("mean", "stderr", "rollouts"))


def checked_record(search, hook: str, value, reserved=frozenset()) -> dict:
    """``value`` as returned by ``search``'s ``hook``: a dict (``None``: empty) with string
    keys, none of ``reserved``, and values JSON can write; ``UsageError`` naming the hook
    otherwise."""
    where = f"{type(search).__name__}.{hook}() (the search's code)"
    if value is None:
        return {}
    if not isinstance(value, dict) or not all(isinstance(k, str) for k in value):
        raise UsageError(f"{where} returned {type(value).__name__}: expected a dict of fields")
    taken = sorted(set(value) & set(reserved))
    if taken:
        raise UsageError(
            f"{where} returned {', '.join(taken)}: fields results.json's own writer sets"
        )
    try:
        json_text(value)  # NaN is written as null, NumPy scalars as numbers
    except (TypeError, ValueError) as err:
        raise UsageError(f"{where} returned a value JSON cannot write ({err})") from None
    return value


def checked_paths(search, hook: str, value) -> list[Path]:
    """``value`` as returned by ``search``'s ``write_plots``: paths (``None``: none)."""
    if value is None:
        return []
    if isinstance(value, str | Path) or not hasattr(value, "__iter__"):
        raise UsageError(
            f"{type(search).__name__}.{hook}() (the search's code) returned "
            f"{type(value).__name__}: expected a list of the paths written"
        )
    if not all(isinstance(p, str | Path) for p in value):
        raise UsageError(
            f"{type(search).__name__}.{hook}() (the search's code) returned "
            f"{[type(p).__name__ for p in value][:4]}: expected a list of the paths written"
        )
    return [Path(p) for p in value]
