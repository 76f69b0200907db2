"""Sweeps: many seeds and settings of one experiment in one compiled program.

A sweep is the cartesian product of ``grid`` values (``{"algorithm.alpha": [0.1, 0.2], ...}``)
times ``seeds``. Settings whose fields all live in the algorithm's hyper-parameter pytree or in
the environment's params pytree (``dynamic_fields``: alpha, entropy settings, learning rate, noise
levels, discount, respawn) share one compiled program: the search of every (seed, setting) pair
is ``vmap``-ed over a leading ``[runs]`` axis, the hyper-parameters and env params being stacked
along it. Any other field (nodes, rollouts, horizon, ...) changes shapes or the program, so
settings that differ in one form separate *groups*, compiled and run one after another.

Each group is run by the one driver (``driver.run_group``, which ``train`` runs with a group of
one): run r uses exactly the keys of ``train --seed s`` (``seed -> (init, run, eval)``,
iteration i with ``fold_in(run_key, i)``), and its honest final value is the one honest
evaluation (``api.final_returns``) of its best policy with its own params, compiled as
``train`` compiles it (one run after another, so ``eval_s`` grows with the runs). The search
itself runs ``vmap``-ed, its hyper-parameters as data: the same operations on the same keys as
the single run, which batching may round differently (equal to the last bit on tagging,
tests/test_sweep.py; larger networks can differ, docs/reference.md, "Sweeps"); a search that
measures its inputs (``standardize_inputs``) uses the group's first setting's statistics.

Devices: the ``[runs]`` axis is sharded over the local devices (``NamedSharding`` over a 1-D
mesh ``("runs",)``; padded to a multiple of the device count by repeating the last run); each device
runs the vmapped search on its block of runs (``shard_map``, no collectives). On CPU the CLI splits
the host into one device per core (``--cpu-devices``) so that every core works. A group whose runs
side by side exceed ``run.memory_gb`` runs them in batches, one after another
(``cognet_jax.batches``). Hosts: with ``jax.distributed`` initialised, process p runs the runs ``p,
p + P, ...`` and process 0 gathers every row (``process_allgather``) and writes the tables.

Outputs (``write_outputs``): ``runs.csv`` / ``runs.json`` (one row per run: the run's
results.json record, ``records.RESULTS_SCHEMA``, plus its group), ``summary.md`` (mean +- s.e.
over seeds per setting) and ``values.png`` (value per iteration per setting). With an output
folder (the CLI always has one) every run also gets its own training folder
``OUT/runs/setting{k}-seed{s}/`` (``policy.msgpack``, ``results.json``), written when its group
ends and on a stop signal, so ``cognet-jax evaluate`` works on any run of a sweep.
"""

from __future__ import annotations

import csv
import io
import itertools
import json
import math
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import jax
import numpy as np
from jax.experimental import multihost_utils
from tqdm.auto import tqdm

from cognet_jax.api import Built
from cognet_jax.atomic_files import atomic_write_json, atomic_write_text
from cognet_jax.batches import folders_whole, run_in_batches
from cognet_jax.compiled import DRIVING_FIELDS
from cognet_jax.config import Config, ConfigError, apply_overrides, parse_override
from cognet_jax.driver import GroupOptions
from cognet_jax.errors import (
    CorruptFileError,
    MismatchError,
    OneLineWarning,
    UsageError,
    read_json,
)
from cognet_jax.plots import plot_sweep_values
from cognet_jax.plugins import one_line
from cognet_jax.program import Run
from cognet_jax.registry import config_from_dict, dynamic_fields, load_config
from cognet_jax.sweep_repeats import same_runs_lines, setting_label, warn_new

#: The sweep's own arguments, written next to its checkpoints (read by ``--resume``).
SWEEP_SPEC = "sweep.json"
RUNS_DIR = "runs"  # OUT/runs/setting{k}-seed{s}/: each run's best policy and results.json
STATE_DIR = "sweep-state"  # OUT/sweep-state/: the spec, each group's checkpoint and rows


# ---------------------------------------------------------------------------------------------
# planning
# ---------------------------------------------------------------------------------------------
def parse_grid(texts: list[str], overrides: list[str] = ()) -> dict[str, list]:
    """``["section.key=v1,v2", ...]`` -> ``{"section.key": [v1, v2]}`` (values read as TOML
    literals, like ``--set``). An empty value, a value or a field given twice, or a field
    ``overrides`` (``--set``) also sets is a ``ConfigError`` naming it."""
    grid: dict[str, list] = {}
    fixed = {".".join(parse_override(o)[0]) for o in overrides}
    for text in texts:
        if "=" not in text:
            raise ConfigError(text, "a grid entry must look like section.key=v1,v2,...")
        name, raw = text.split("=", 1)
        name = name.strip()
        parts = raw.split(",")
        if not raw.strip() or any(not v.strip() for v in parts):
            raise ConfigError(name, f"empty value in the grid entry {text!r}")
        if name in grid:
            raise ConfigError(name, "appears twice in the grid")
        if name in fixed:
            raise ConfigError(name, "is set by both --grid and --set; give it in one of them")
        section, _, key = name.partition(".")
        if (section == "run" and key in DRIVING_FIELDS) or name in NAMING_FIELDS:
            raise ConfigError(
                name,
                "gives every group the same search and values (it drives or names the runs); "
                "give it with --set",
            )
        if name == "run.prng_impl" and len(set(parts)) > 1:
            raise ConfigError(
                name, "cannot vary within a sweep (its runs share one program of one key type)"
            )
        values = [parse_override(f"{name}={v}")[1] for v in parts]
        seen = [json.dumps(v, sort_keys=True) for v in values]  # 0.1 and 1e-1 are one value
        twice = next((v for k, v in enumerate(values) if seen[k] in seen[:k]), None)
        if twice is not None:
            raise ConfigError(name, f"the grid gives the value {twice!r} twice")
        grid[name] = values
    return grid


#: fields that name a run, not its search: a grid over them runs one search again and again
NAMING_FIELDS = ("experiment.name", "experiment.description")


@dataclass
class Setting:
    index: int
    values: dict  # grid field -> value
    config: Config


@dataclass
class Group:
    """Settings that share one compiled program (they differ only in ``dynamic_fields``)."""

    settings: list[Setting]
    runs: list[tuple[int, int]] = field(default_factory=list)  # (setting index, seed)


#: ``plan`` shows a progress bar from this many settings on
PLAN_BAR = 200


def plan(
    experiment: str | Config, grid: dict[str, list], overrides: list[str], progress: bool = True
) -> list[Group]:
    """Validated settings (every grid combination of ``experiment``: a built-in name, a TOML
    file or a ``Config``), grouped by their static fields; a bar for many settings unless
    ``progress`` is off."""
    names = list(grid)
    groups: dict[str, Group] = {}
    combos = itertools.product(*(grid[n] for n in names)) if names else [()]
    count = math.prod(len(grid[n]) for n in names)
    shown = tqdm(  # loading and validating a setting takes milliseconds: a bar for many
        combos,
        total=count,
        disable=not progress or count < PLAN_BAR,
        desc="preparing settings",
        leave=False,
    )
    for index, combo in enumerate(shown):
        values = dict(zip(names, combo, strict=True))
        sets = overrides + [f"{n}={_toml_literal(v)}" for n, v in values.items()]
        config = _setting_config(experiment, sets)
        d = config.to_dict()
        for n in dynamic_fields(config):
            section, key = n.split(".")
            if key in d.get(section, {}):
                d[section][key] = None
        d["run"] = None
        signature = json.dumps(d, sort_keys=True)
        groups.setdefault(signature, Group(settings=[])).settings.append(
            Setting(index=index, values=values, config=config)
        )
    return list(groups.values())


def _mean_se(mean: float, se: float) -> str:
    """``mean +- s.e.``; the mean alone where one seed gives no standard error."""
    return f"{mean:.3f}" + ("" if math.isnan(se) else f" +- {se:.3f}")


def _toml_literal(value) -> str:
    """``value`` (as ``parse_override`` read it) written back as the TOML literal it was:
    JSON's, except NaN and the infinities (``nan``, ``inf``, ``-inf``), which the setting's
    check then refuses as ``--set`` does."""
    if isinstance(value, float) and not math.isfinite(value):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")
    return json.dumps(value)


def _setting_config(experiment: str | Config, sets: list[str]) -> Config:
    """``experiment`` (a name, a TOML file or a ``Config``) with the ``section.key=value``
    settings ``sets`` applied and validated."""
    if isinstance(experiment, Config):
        return config_from_dict(apply_overrides(experiment.to_dict(), sets))
    return load_config(experiment, sets)


def assign_runs(groups: list[Group], seeds: list[int], process: int = 0, processes: int = 1):
    """Every (setting, seed) run, numbered in order; process p keeps runs ``p, p + P, ...``.
    Returns the total number of runs."""
    r = 0
    for g in groups:
        g.runs = []
        for s in g.settings:
            for seed in seeds:
                if r % processes == process:
                    g.runs.append((s.index, seed))
                r += 1
    return r


def run_folder_name(setting: int, seed: int) -> str:
    """``setting{k}-seed{s}``: the folder of one run under ``OUT/runs/``."""
    return f"setting{setting}-seed{seed}"


# ---------------------------------------------------------------------------------------------
# running
# ---------------------------------------------------------------------------------------------
def gather_rows(rows: list[dict]) -> list[dict]:
    """All processes' rows on every process (``process_allgather`` of JSON bytes)."""
    if jax.process_count() == 1:
        return rows
    data = np.frombuffer(json.dumps(rows).encode(), np.uint8)
    sizes = multihost_utils.process_allgather(np.array([data.size], np.int64))
    padded = np.zeros(int(sizes.max()), np.uint8)
    padded[: data.size] = data
    everything = multihost_utils.process_allgather(padded)
    out = []
    for p in range(everything.shape[0]):
        out.extend(json.loads(everything[p, : int(sizes[p, 0])].tobytes().decode()))
    return out


def _group_runs(group: Group, out: Path | None) -> list[Run]:
    by_index = {s.index: s for s in group.settings}
    return [
        Run(
            config=by_index[index].config,
            seed=seed,
            folder=None if out is None else out / RUNS_DIR / run_folder_name(index, seed),
            setting=index,
            grid=by_index[index].values,
        )
        for index, seed in group.runs
    ]


def _run_one_group(
    group: Group, g_index: int, out: Path | None, resume: bool, progress, log, desc, built=None
):
    """``(rows, timing)`` of one group: from its finished rows when a resumed sweep has them
    and its run folders are whole, else by the driver (checkpointed under
    ``OUT/sweep-state/``: a group whose run folders were deleted since is run again from its
    checkpoint, to the same numbers); ``built``: the group's ``api.build``, when the caller
    made it."""
    tag = f"group{g_index}-p{jax.process_index()}"
    state = None if out is None else out / STATE_DIR
    done = None if state is None else state / f"{tag}.rows.json"
    whole = out is None or folders_whole(_group_runs(group, out))
    if done is not None and resume and done.exists() and whole:
        stored = read_json(done, ("runs", "rows", "timing"))
        if stored["runs"] != [list(r) for r in group.runs]:
            raise MismatchError(
                f"{done} holds other runs than {state / SWEEP_SPEC} describes (settings x "
                "seeds): one of the two was edited, or copied from another sweep"
            )
        _check_rows(stored["rows"], len(group.runs), done)
        values = {setting.index: setting.values for setting in group.settings}
        for row in stored["rows"]:  # each row's grid values: the setting the spec gives it
            if row.get("grid") != values.get(row.get("setting")):
                raise MismatchError(
                    f"{done} holds a run of setting {row.get('setting')} with "
                    f"{row.get('grid')}, but {state / SWEEP_SPEC} gives that setting "
                    f"{values.get(row.get('setting'))}: one of the two was edited, or copied "
                    "from another sweep"
                )
        configs = {setting.index: setting.config.to_dict() for setting in group.settings}
        for row in stored["rows"]:  # and the config the spec gives it (its overrides)
            changed = _config_change(row.get("config"), configs.get(row.get("setting")))
            if changed:
                raise MismatchError(
                    f"{done} holds a run of setting {row.get('setting')} with {changed}: "
                    f"{state / SWEEP_SPEC} was edited since it ran (or the rows were copied "
                    "from another sweep); its tables would describe settings no run used"
                )
        return stored["rows"], stored["timing"]
    if not group.runs:
        return [], {"compile_s": 0.0, "loop_s": 0.0, "eval_s": 0.0, "runs": 0}
    checkpoint = None if state is None else state / f"{tag}.checkpoint.msgpack"
    opts = GroupOptions(checkpoint, resume, progress, log, desc, resume_dir=out, built=built)
    rows, timing = run_in_batches(_group_runs(group, out), tag, state, opts)
    if done is not None:
        atomic_write_json(done, {"runs": group.runs, "rows": rows, "timing": timing}, None)
    return rows, timing


def _config_change(ran: dict | None, now: dict | None) -> str:
    """``"section.key X (now Y)"`` for the first field of a finished run's config ``ran`` that
    the sweep's spec now sets otherwise (the run sections' fields that drive a run aside, and
    fields the run did not write: added to the library since); "" when none."""
    if not isinstance(ran, dict) or not isinstance(now, dict):
        return "" if ran == now else "a config of another form"
    for section, fields in ran.items():
        if not isinstance(fields, dict) or not isinstance(now.get(section), dict):
            continue
        for key, value in fields.items():
            if section == "run" and key != "prng_impl":  # memory, progress, checkpoints
                continue
            if key in now[section] and now[section][key] != value:
                return f"{section}.{key} = {value!r} (now {now[section][key]!r})"
    return ""


def run_sweep(
    experiment: str | Config | Built,
    seeds: list[int],
    grid: dict[str, list] | None = None,
    overrides: list[str] | None = None,
    progress: bool = False,
    log=print,
    out: Path | None = None,
    resume: bool = False,
    run_overrides: list[str] = (),
) -> dict:
    """Run the sweep: every group by the driver, each run's folder under ``out`` and the
    checkpoints under ``out/sweep-state`` (``out=None``: no files); with ``resume`` a finished
    group's rows are kept and a cut one continues from its checkpoint; ``run_overrides``
    (``run.*`` fields: progress, checkpoints) drive it without being part of the sweep's own
    settings (sweep.json, runs.json).

    ``experiment``: a built-in name or TOML file, a ``Config``, or a ``Built`` run
    (``api.build``), whose seeds then run as built (nothing is built again; give it no grid,
    no overrides; its memory share is the one it was built with, ``build(config,
    lanes=len(seeds))`` for seeds side by side). Returns ``{"rows":
    [...] (every process's, sorted by setting and seed), "groups": [...], "grid", "seeds",
    "wall_s", ...}``."""
    if not seeds:
        raise ConfigError("seeds", "a sweep needs at least one seed")
    t0 = time.perf_counter()
    grid = grid or {}
    built = experiment if isinstance(experiment, Built) else None
    if built is not None:
        if grid or overrides or run_overrides:
            raise UsageError(
                "a sweep of a Built run takes no grid and no overrides (its settings are built): "
                "pass its config, built.config, to sweep other settings"
            )
        experiment = built.config
    groups = plan(experiment, grid, [*(overrides or []), *run_overrides], progress)
    if built is not None:  # the one setting, exactly the config the run was built from
        groups[0].settings[0].config = built.config
    total = assign_runs(groups, seeds, jax.process_index(), jax.process_count())
    if len(groups) > 1:  # said before the first compiles: each group is a program of its own
        log(
            f"sweep: {sum(len(g.settings) for g in groups)} settings in {len(groups)} compiled "
            "groups (settings whose fields change shapes compile a program each, one group "
            "after another)"
        )
    name = experiment if isinstance(experiment, str) else experiment.experiment.name
    if out is not None:
        spec = {"experiment": name, "seeds": seeds, "grid": grid, "overrides": overrides}
        if isinstance(experiment, Config):  # --resume rebuilds from it, not from the name
            spec["config"] = experiment.to_dict()
        atomic_write_text(Path(out) / STATE_DIR / SWEEP_SPEC, json.dumps(spec, indent=1))
    settings = {s.index: s.values for g in groups for s in g.settings}
    settings_list = [settings[i] for i in sorted(settings)]
    rows, timings, said = [], [], set()
    for g_index, g in enumerate(groups):
        desc = f"group {g_index + 1}/{len(groups)}"
        g_rows, timing = _run_one_group(g, g_index, out, resume, progress, log, desc, built)
        for row in g_rows:
            row["group"] = g_index
        rows.extend(g_rows)
        timing.update(group=g_index, settings=[s.index for s in g.settings])
        timings.append(timing)
        if jax.process_count() == 1:  # said as soon as a group repeats one: Ctrl-C saves time
            said |= warn_new(same_runs_lines(rows, settings_list), said)
    rows = sorted(gather_rows(rows), key=lambda r: (r["setting"], r["seed"]))
    if len(rows) != total:  # pragma: no cover - a lost process
        raise RuntimeError(f"gathered {len(rows)} runs, expected {total}")
    warn_new(same_runs_lines(rows, settings_list), said)
    wall_s = time.perf_counter() - t0
    log(
        f"sweep {name}: {total} runs in {len(groups)} compiled group(s), "
        f"{jax.process_count()} process(es) x {jax.local_device_count()} device(s), "
        f"wall {wall_s:.1f} s"
    )
    return {
        "experiment": name,
        "overrides": overrides or [],
        "grid": grid,
        "seeds": seeds,
        "settings": [settings[i] for i in sorted(settings)],
        "config": groups[0].settings[0].config.to_dict(),
        "rows": rows,
        "groups": timings,
        "wall_s": wall_s,
        "processes": jax.process_count(),
        "local_devices": jax.local_device_count(),
        "jax_version": jax.__version__,
        "backend": jax.default_backend(),
    }


def _check_rows(rows, count: int, path: Path) -> None:
    """``CorruptFileError`` naming ``path`` unless ``rows`` are ``count`` runs' records, each
    with a finite honest value (a rows file edited or damaged by hand is never published)."""
    if not isinstance(rows, list) or len(rows) != count:
        raise CorruptFileError(path, f"expected the records of {count} runs")
    for k, row in enumerate(rows):
        final = row.get("final_value") if isinstance(row, dict) else None
        numbers = [final.get(f) for f in ("mean", "stderr")] if isinstance(final, dict) else []
        if len(numbers) != 2 or not all(
            isinstance(x, int | float) and math.isfinite(x) for x in numbers
        ):
            raise CorruptFileError(path, f"run {k} has no finite honest value")


def _check_spec(spec: dict, path: Path) -> None:
    """``CorruptFileError`` naming ``path`` unless its experiment is a name or path (or its
    ``config`` a table), its grid a table of non-empty lists, its seeds a non-empty list of
    seeds and its overrides a list of strings."""
    grid, seeds, overrides = spec["grid"], spec["seeds"], spec["overrides"]
    if "config" in spec:
        if not isinstance(spec["config"], dict):
            raise CorruptFileError(path, "config is not a table of config sections")
    elif not isinstance(spec["experiment"], str) or not spec["experiment"]:
        raise CorruptFileError(path, "experiment is not an experiment name or TOML path")
    if not isinstance(grid, dict) or not all(
        isinstance(v, list) and v and isinstance(k, str) for k, v in grid.items()
    ):
        raise CorruptFileError(path, "grid is not a table of non-empty lists")
    if (
        not isinstance(seeds, list)
        or not seeds
        or not all(isinstance(x, int) and not isinstance(x, bool) and 0 <= x < 2**31 for x in seeds)
    ):
        raise CorruptFileError(path, "seeds is not a list of seeds in 0 .. 2147483647")
    if overrides is None:  # a sweep of a ``Config``: none
        return
    if not isinstance(overrides, list) or not all(isinstance(o, str) for o in overrides):
        raise CorruptFileError(path, "overrides is not a list of section.key=value strings")


def read_spec(out) -> dict:
    """The arguments of the sweep in ``out`` (``--resume``); ``experiment`` is the ``Config``
    the sweep was given, when it was given one (its ``config``), else its name."""
    path = Path(out) / STATE_DIR / SWEEP_SPEC
    if not path.is_file():
        raise FileNotFoundError(f"{path} not found: is {out} a sweep folder?")
    spec = read_json(path, ("experiment", "seeds", "grid", "overrides"))
    _check_spec(spec, path)
    if "config" in spec:
        spec["experiment"] = config_from_dict(spec.pop("config"))
    return spec


# ---------------------------------------------------------------------------------------------
# outputs
# ---------------------------------------------------------------------------------------------
def _stderr(x: np.ndarray) -> float:
    return float(x.std(ddof=1) / np.sqrt(x.size)) if x.size > 1 else float("nan")


#: the fields of every run's ``final_value``; any other is one the search's ``exact_record``
#: added (e.g. exact values of the best policy), summarised per setting as it comes
FINAL_VALUE_FIELDS = ("mean", "stderr", "rollouts")


def added_fields(rows: list[dict]) -> list[str]:
    """The numeric fields the search added to the ``final_value`` of every run of ``rows``
    (``exact_record``), in the order of the first run's."""
    first = rows[0]["final_value"] if rows else {}
    return [
        k
        for k in first
        if k not in FINAL_VALUE_FIELDS
        and all(
            isinstance(r["final_value"].get(k), (int, float))
            and not isinstance(r["final_value"].get(k), bool)
            for r in rows
        )
    ]


def summarize(result: dict) -> list[dict]:
    """Per setting: mean +- s.e. over seeds of the honest final value and the in-loop best,
    and of each field the search added to the final values (``added_fields``) the mean,
    minimum and maximum over seeds (``{field: [mean, min, max]}`` under ``added``)."""
    out = []
    for index, values in enumerate(result["settings"]):
        rows = [r for r in result["rows"] if r["setting"] == index]
        finals = np.array([r["final_value"]["mean"] for r in rows])
        best = np.array([r["in_loop_best"] for r in rows])
        added = {}
        for k in added_fields(rows):
            v = [float(r["final_value"][k]) for r in rows]
            added[k] = [float(np.mean(v)), min(v), max(v)]
        out.append(
            {
                "setting": index,
                "grid": values,
                "seeds": finals.size,
                "final_mean": float(finals.mean()),
                "final_se": _stderr(finals),
                "in_loop_best_mean": float(best.mean()),
                "in_loop_best_se": _stderr(best),
                "added": added,
            }
        )
    return out


def write_outputs(result: dict, out_dir: str | Path) -> list[Path]:
    """``runs.csv``, ``runs.json``, ``summary.md`` and, unless the sweep's ``run.plots`` is
    false, ``values.png`` in ``out_dir``; returns the paths written. A figure that cannot be
    written (a full disk) is a warning: the tables stand."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    names = list(result["grid"])
    # the fields the search added to the final values (``exact_record``), a column each
    added_keys = added_fields(result["rows"])
    table = io.StringIO(newline="")  # written whole, atomically: a failed write keeps the old one
    w = csv.writer(table)
    w.writerow(
        ["setting", "group", "seed", *names, "final_mean", "final_stderr", "final_rollouts"]
        + ["in_loop_best"]
        + [f"final_{k}" for k in added_keys]
    )
    for r in result["rows"]:
        fv = r["final_value"]
        w.writerow(
            [r["setting"], r["group"], r["seed"], *(r["grid"][n] for n in names)]
            + [repr(fv["mean"]), repr(fv["stderr"]), fv["rollouts"], repr(r["in_loop_best"])]
            + [repr(fv.get(k)) for k in added_keys]
        )
    atomic_write_text(out / "runs.csv", table.getvalue())
    atomic_write_json(out / "runs.json", result)
    summary = summarize(result)
    counts = sorted({r["final_value"]["rollouts"] for r in result["rows"]})
    rollouts = (
        f"{counts[0]} rollouts"
        if len(counts) == 1
        else f"{counts[0]} to {counts[-1]} rollouts by setting: runs.csv's final_rollouts"
    )
    lines = [
        f"# Sweep of {result['experiment']}",
        "",
        f"{len(result['seeds'])} seeds ({result['seeds'][0]}..{result['seeds'][-1]}), "
        f"{len(summary)} setting(s), {len(result['groups'])} compiled group(s); wall "
        f"{result['wall_s']:.1f} s. Honest value: mean over seeds of each run's fresh "
        f"evaluation of its best policy ({rollouts}, the seed's eval key); +- is the standard "
        "error over seeds.",
    ]
    added = [k for k in added_keys if all(k in s["added"] for s in summary)]
    if added:
        lines[-1] += (
            " " + ", ".join(added) + ": fields the search adds to each run's final value"
            " (its ``exact_record``), mean over seeds and [min, max]."
        )
    lines += [
        "",
        "| setting | seeds | honest value | in-loop best |" + "".join(f" {k} |" for k in added),
        "|---|---|---|---|" + "---|" * len(added),
    ]
    for s in summary:
        row = (
            f"| {setting_label(s['grid'])} | {s['seeds']} | "
            f"{_mean_se(s['final_mean'], s['final_se'])} | "
            f"{_mean_se(s['in_loop_best_mean'], s['in_loop_best_se'])} |"
        )
        for k in added:
            mean, lo, hi = s["added"][k]
            row += f" {mean:.6f} [{lo:.6f}, {hi:.6f}] |"
        lines.append(row)
    repeats = same_runs_lines(result["rows"], result["settings"])
    if repeats:
        lines += ["", *(f"Note: {line}." for line in repeats)]
    atomic_write_text(out / "summary.md", "\n".join(lines) + "\n")
    written = [out / n for n in ("runs.csv", "runs.json", "summary.md")]
    if result.get("config", {}).get("run", {}).get("plots", True):
        try:
            plot_sweep_values(result, out / "values.png", setting_label)
            written.append(out / "values.png")
        except OSError as err:
            warnings.warn(
                f"{out}: values.png could not be written ({one_line(err)}); the sweep's tables "
                "are saved",
                OneLineWarning,
                stacklevel=2,
            )
    return written
