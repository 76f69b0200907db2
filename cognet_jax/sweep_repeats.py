"""Settings of a sweep that repeat another setting's runs: a grid over a field the search never
reads (or one its other settings switch off) runs one search again under another name. Found
from the runs' numbers (``same_runs``), said in one warning line per setting as soon as a group
repeats one (``sweep.run_sweep``) and noted in summary.md."""

from __future__ import annotations

import json
import warnings

from cognet_jax.errors import OneLineWarning


def setting_label(values: dict) -> str:
    """A setting's grid values as ``field=value, ...`` (``(base config)`` without a grid)."""
    return ", ".join(f"{k}={v}" for k, v in values.items()) or "(base config)"


def _run_signature(row: dict) -> tuple:
    """What tells a run's numbers apart: its honest value and standard error, the in-loop best
    and the value of every iteration."""
    fv = row["final_value"]
    return (
        fv["mean"],
        fv["stderr"],
        row["in_loop_best"],
        tuple(row.get("values_per_iteration") or ()),
    )


def same_runs(rows: list[dict]) -> list[tuple[int, int]]:
    """``[(setting, earlier setting)]``: settings whose runs gave an earlier setting's numbers
    run for run (every seed's ``_run_signature`` equal): a grid over a field the search never
    reads runs one search again under another name."""
    by_setting: dict[int, dict] = {}
    for r in rows:
        by_setting.setdefault(r["setting"], {})[r["seed"]] = _run_signature(r)
    pairs, seen = [], {}
    for index in sorted(by_setting):
        runs = by_setting[index]
        key = json.dumps(sorted(runs.items()), default=repr)
        if key in seen:
            pairs.append((index, seen[key]))
        else:
            seen[key] = index
    return pairs


def same_runs_lines(rows: list[dict], settings: list[dict]) -> list[str]:
    """One line per setting that repeats an earlier one's runs (``same_runs``), naming the
    grid fields the two differ in."""
    lines = []
    for index, earlier in same_runs(rows):
        fields = [k for k in settings[index] if settings[index][k] != settings[earlier].get(k)]
        lines.append(
            f"setting {index} ({setting_label(settings[index])}) gave the numbers of setting "
            f"{earlier} ({setting_label(settings[earlier])}) run for run: "
            f"{', '.join(fields) or 'its grid fields'} changed nothing this search computes "
            "(a field it does not read, or one its other settings switch off)"
        )
    return lines


def warn_new(lines: list[str], said: set) -> set:
    """Warn each of ``lines`` not in ``said``; returns the lines warned."""
    new = {line for line in lines if line not in said}
    for line in lines:
        if line in new:
            warnings.warn(line, OneLineWarning, stacklevel=3)
    return new
