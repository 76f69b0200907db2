"""Sweeps: many seeds and settings of one experiment in one compiled program.

A sweep is the cartesian product of ``grid`` values (``{"algorithm.alpha": [0.1, 0.2], ...}``)
times ``seeds``. Settings whose fields all live in the algorithm's hyper-parameter pytree or in
the environment's params pytree (``dynamic_fields``: alpha, entropy settings, learning rate, noise
levels, discount, respawn) share one compiled program: the search of every (seed, setting) pair
is ``vmap``-ed over a leading ``[runs]`` axis, the hyper-parameters and env params being stacked
along it. Any other field (nodes, rollouts, horizon, ...) changes shapes or the program, so
settings that differ in one form separate *groups*, compiled and run one after another.

Run r of a group uses exactly the keys of ``train --seed s``: ``seed -> (init, run, eval)``,
iteration i uses ``fold_in(run_key, i)``, and the honest final value is the mean +- standard
error of ``evaluation.rollouts`` fresh rollouts of the best policy with the eval key. So a run of
a sweep computes the same thing as the single run with its seed and setting (see
tests/test_sweep.py for how close the numbers are).

Devices: the ``[runs]`` axis is sharded over the local devices (``NamedSharding`` over a 1-D
mesh ``("runs",)``; padded to a multiple of the device count by repeating the last run); each
device runs the vmapped search on its block of runs (``shard_map``, no collectives). On CPU the
CLI splits the host into one device per core (``--cpu-devices``) so that every core works.
Hosts: with ``jax.distributed`` initialised, process p runs the runs ``p, p + P, ...`` and
process 0 gathers every row (``process_allgather``) and writes the tables.

Outputs (``write_outputs``): ``runs.csv`` / ``runs.json`` (one row per run), ``summary.md``
(mean +- s.e. over seeds per setting) and ``values.png`` (value per iteration per setting).
With a checkpointing work folder (the CLI always has one) every run also gets its own training
folder ``OUT/runs/setting{k}-seed{s}/`` (``policy.msgpack``, ``results.json``), written when its
group ends and on Ctrl-C, so ``cognet-jax evaluate`` works on any run of a sweep.
"""

from __future__ import annotations

import copy
import csv
import itertools
import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from cognet_jax.api import (
    build_algorithm,
    honest_returns,
    iteration_step,
    seed_key,
    split_seed_key,
)
from cognet_jax.config import Config, ConfigError, load_config, parse_override
from cognet_jax.errors import MismatchError
from cognet_jax.memory import budget_bytes, trace_checked

#: The sweep's own arguments, written next to its checkpoints (read by ``--resume``).
SWEEP_SPEC = "sweep.json"
RUNS_DIR = "runs"  # OUT/runs/setting{k}-seed{s}/: each run's best policy and results.json


def dynamic_fields(config: Config) -> frozenset[str]:
    """Dotted config fields that only change the hyper-parameters or the env params pytree
    (the registry entries' ``dynamic``), so settings differing in them share one program."""
    from cognet_jax.registry import algorithm_entry, env_entry

    env = env_entry(config.env.name).dynamic
    return frozenset(algorithm_entry(config.experiment.algorithm).dynamic) | {
        f"env.{name}" for name in env
    }


# ---------------------------------------------------------------------------------------------
# planning
# ---------------------------------------------------------------------------------------------
def parse_grid(texts: list[str]) -> dict[str, list]:
    """``["section.key=v1,v2", ...]`` -> ``{"section.key": [v1, v2]}`` (values read as TOML
    literals, like ``--set``)."""
    grid: dict[str, list] = {}
    for text in texts:
        if "=" not in text:
            raise ConfigError(text, "a grid entry must look like section.key=v1,v2,...")
        name, raw = text.split("=", 1)
        name = name.strip()
        values = [parse_override(f"{name}={v}")[1] for v in raw.split(",") if v.strip()]
        if not values:
            raise ConfigError(name, "a grid entry needs at least one value")
        if name in grid:
            raise ConfigError(name, "appears twice in the grid")
        grid[name] = values
    return grid


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


def plan(experiment: str, grid: dict[str, list], overrides: list[str]) -> list[Group]:
    """Validated settings (every grid combination), grouped by their static fields."""
    names = list(grid)
    groups: dict[str, Group] = {}
    combos = itertools.product(*(grid[n] for n in names)) if names else [()]
    for index, combo in enumerate(combos):
        values = dict(zip(names, combo, strict=True))
        sets = overrides + [f"{n}={json.dumps(v)}" for n, v in values.items()]
        config = load_config(experiment, sets)
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


# ---------------------------------------------------------------------------------------------
# running one group
# ---------------------------------------------------------------------------------------------
def with_env_params(algorithm, env_params):
    """A shallow copy of ``algorithm`` using ``env_params`` (may be traced)."""
    algo = copy.copy(algorithm)
    algo.env_params = env_params
    return algo


def _take(tree, r: int):
    return jax.tree.map(lambda x: x[r], tree)


def _stack(trees):
    return jax.tree.map(lambda *xs: jnp.stack([jnp.asarray(x) for x in xs]), *trees)


def _same_tree(a, b) -> bool:
    """Whether two pytrees of arrays have the same structure and values."""
    leaves_a, leaves_b = jax.tree.leaves(a), jax.tree.leaves(b)
    return jax.tree.structure(a) == jax.tree.structure(b) and all(
        np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(leaves_a, leaves_b)
    )


def _mesh_sharding():
    """``(NamedSharding of the leading [runs] axis over a 1-D mesh of the local devices,
    number of devices)``."""
    from jax.sharding import Mesh, NamedSharding, PartitionSpec

    mesh = Mesh(np.array(jax.local_devices()), ("runs",))
    return NamedSharding(mesh, PartitionSpec("runs")), mesh.size


def per_run(fn, sharding, num_args: int, **jit_kwargs):
    """``jit`` of ``vmap(fn)`` over the leading ``[runs]`` axis of every argument and output,
    each device running ``vmap(fn)`` on its own block of runs (``shard_map``): runs never talk
    to each other, so the program holds no collective."""
    spec = sharding.spec
    mapped = jax.shard_map(
        jax.vmap(fn),
        mesh=sharding.mesh,
        in_specs=(spec,) * num_args,
        out_specs=spec,
        check_vma=False,  # carries start as constants; runs are independent anyway
    )
    return jax.jit(mapped, **jit_kwargs)


@dataclass
class Checkpointing:
    """Where and how often a sweep saves its state (``work_dir`` per process and group:
    ``{tag}.checkpoint.msgpack`` while a group runs, ``{tag}.rows.json`` once it is done)."""

    work_dir: Path
    every: int = 0
    resume: bool = False


def run_group(
    group: Group,
    progress: bool = False,
    desc: str = "sweep",
    checkpointing: Checkpointing | None = None,
    tag: str = "group0-p0",
) -> tuple[list, dict]:
    """Run every run of ``group`` in one compiled program; returns ``(rows, timing)``.

    Each row: ``{"setting", "seed", "final_value" {mean, stderr, rollouts}, "in_loop_best",
    "values_per_iteration", "best_per_iteration"}``. With ``checkpointing`` the stacked search
    state of all runs is written every ``every`` iterations and on SIGINT (then
    ``runner.Interrupted`` is raised); ``resume`` continues from it bit for bit."""
    if not group.runs:
        return [], {"compile_s": 0.0, "loop_s": 0.0, "eval_s": 0.0}
    by_index = {s.index: s for s in group.settings}
    config = group.settings[0].config
    sharding, n_dev = _mesh_sharding()
    n_real = len(group.runs)
    runs = group.runs + [group.runs[-1]] * (-n_real % n_dev)  # pad to the device count
    # the runs share the memory budget: each vmapped lane gets its part
    algorithm = build_algorithm(config, lanes=len(runs))
    per_setting = {i: build_algorithm(s.config) for i, s in by_index.items()}
    keys = jnp.stack([seed_key(config, seed) for _, seed in runs])
    hyper = _stack([per_setting[i].hyper for i, _ in runs])
    env_params = _stack([per_setting[i].env_params for i, _ in runs])
    keys, hyper, env_params = jax.device_put((keys, hyper, env_params), sharding)
    iterations = config.algorithm.iterations
    ev = config.evaluation

    def init_one(key):
        k_init, _, _ = split_seed_key(key)
        return algorithm.init(k_init)

    # env params that no setting changes stay constants of the program, as in a single run:
    # batched, a zero noise level could not skip its draws (``envs.base.scaled_normal``)
    shared_env = all(_same_tree(a.env_params, algorithm.env_params) for a in per_setting.values())

    def run_algorithm(env_params):
        return algorithm if shared_env else with_env_params(algorithm, env_params)

    def step_one(key, state, hyper, env_params):
        _, k_run, _ = split_seed_key(key)
        return iteration_step(run_algorithm(env_params))(k_run, state, hyper)

    def eval_one(key, state, env_params):
        algo = run_algorithm(env_params)
        return honest_returns(algo, ev)(key, algo.best_policy(state))

    # every leaf (state, metrics, keys, params) has the leading [runs] axis: shard it
    state = per_run(init_one, sharding, 1)(keys)
    t0 = time.perf_counter()
    step = trace_checked(
        per_run(step_one, sharding, 4, donate_argnums=(1,)),
        (keys, state, hyper, env_params),
        budget_bytes(config.run.memory_gb),
        f"one iteration of {len(runs)} runs",
    )
    step = step.lower().compile()
    compile_s = time.perf_counter() - t0
    from cognet_jax.checkpoint import (
        read_checkpoint,
        restore_history,
        restore_state,
        save_checkpoint,
        stack_history,
    )
    from cognet_jax.runner import Interrupted, iterate

    meta = {"kind": "sweep", "tag": tag, "runs": runs, "config": config.to_dict()}
    ckpt = checkpointing
    path = ckpt.work_dir / f"{tag}.checkpoint.msgpack" if ckpt else None
    history, start = [], 0
    if ckpt and ckpt.resume and path.exists():
        raw = read_checkpoint(path)
        if raw["meta"] != json.loads(json.dumps(meta)):
            raise MismatchError(f"{path} was written by another sweep")
        state = jax.device_put(restore_state(jax.device_get(state), raw), sharding)
        metrics_shape = jax.eval_shape(jax.vmap(step_one), keys, state, hyper, env_params)[1]
        history, start = restore_history(metrics_shape, raw), int(raw["iteration"])

    def save(i, state, history):
        if ckpt:
            save_checkpoint(
                path, state=state, keys={}, iteration=i, history=stack_history(history), meta=meta
            )

    def write_policies(i, best, rows=None):
        """Each run's best policy (and ``results.json``) in ``runs/setting{k}-seed{s}/``."""
        if ckpt:
            out = ckpt.work_dir.parent / RUNS_DIR
            write_run_folders(out, by_index, runs[:n_real], best, algorithm, i, iterations, rows)

    def interrupted(i, state, signum):
        write_policies(i, jax.device_get(jax.vmap(algorithm.best_policy)(state)))
        out = ckpt.work_dir.parent if ckpt else Path(".")
        raise Interrupted(out, i, iterations, signum)

    t_loop = time.perf_counter()
    state = iterate(
        lambda s: step(keys, s, hyper, env_params),
        state,
        start=start,
        iterations=iterations,
        history=history,
        checkpoint_every=ckpt.every if ckpt else 0,
        save=save,
        on_interrupt=interrupted,
        progress=progress,
        desc=desc,
    )
    # on the host ([runs, iterations]): a jnp.stack of 500 arrays compiles a concatenation
    history = jax.tree.map(lambda x: np.moveaxis(x, 0, 1), stack_history(history))
    loop_s = time.perf_counter() - t_loop
    polish = None
    if getattr(algorithm, "polishes", False):  # G-DICE: exact polish of every run's best

        def finish_one(state, env_params):
            return run_algorithm(env_params).finish(state)

        state, polish = jax.device_get(per_run(finish_one, sharding, 2)(state, env_params))
        state = jax.device_put(state, sharding)
    t_eval = time.perf_counter()
    returns = np.asarray(
        jax.device_get(per_run(eval_one, sharding, 3)(keys, state, env_params)), np.float64
    )
    best = jax.device_get(jax.vmap(algorithm.best_policy)(state))
    eval_s = time.perf_counter() - t_eval

    from cognet_jax.runner import exact_evaluation, return_summary

    rows = []
    for r, (index, seed) in enumerate(runs[:n_real]):
        final = return_summary(returns[r])
        exact = exact_evaluation(by_index[index].config, _take(best, r))
        if exact is not None:
            final.update(exact)
        rows.append(
            {
                "setting": index,
                "seed": seed,
                "grid": by_index[index].values,
                "final_value": final,
                "in_loop_best": float(history.best_value[r, -1]),
                "polish": None
                if polish is None
                else {
                    "value_before": float(polish.before[r]),
                    "value_after": float(polish.after[r]),
                    "moves_applied": int(polish.moves_applied[r]),
                    "moves_per_sweep": int(polish.moves_per_sweep),
                    "best_responses_applied": int(polish.responses_applied[r]),
                },
                "values_per_iteration": history.value[r].tolist(),
                "best_per_iteration": history.best_value[r].tolist(),
            }
        )
    write_policies(iterations, best, rows)
    timing = {"compile_s": compile_s, "loop_s": loop_s, "eval_s": eval_s, "runs": n_real}
    timing["resumed_from_iteration"] = start if start else None
    return rows, timing


def run_folder_name(setting: int, seed: int) -> str:
    """``setting{k}-seed{s}``: the folder of one run under ``OUT/runs/``."""
    return f"setting{setting}-seed{seed}"


def write_run_folders(runs_dir, by_index, runs, best, algorithm, iteration, iterations, rows):
    """One training-output folder per run (``policy.msgpack``, ``results.json``, the VAE if the
    pipeline has one), so ``cognet-jax evaluate OUT/runs/setting0-seed3`` works on a sweep's
    runs as on a ``train`` folder. ``best``: the runs' best policies on the host, leading
    ``[runs]`` axis. ``rows=None``: the sweep was interrupted at ``iteration``
    (``status`` ``"interrupted"``, no final value); otherwise each run's row is stored too."""
    from cognet_jax.checkpoint import atomic_write_text
    from cognet_jax.runner import save_policy, save_vae_of

    for r, (index, seed) in enumerate(runs):
        folder = Path(runs_dir) / run_folder_name(index, seed)
        folder.mkdir(parents=True, exist_ok=True)
        config = by_index[index].config
        save_policy(folder / "policy.msgpack", _take(best, r))
        save_vae_of(algorithm, folder)
        record = {
            "experiment": config.experiment.name,
            "algorithm": config.experiment.algorithm,
            "seed": seed,
            "config": config.to_dict(),
            "grid": by_index[index].values,
            "status": "complete" if rows is not None else "interrupted",
            "iteration": iteration,
            "iterations": iterations,
            "final_value": rows[r]["final_value"] if rows is not None else None,
        }
        if rows is not None:
            record.update({k: rows[r][k] for k in ("in_loop_best", "values_per_iteration")})
        atomic_write_text(folder / "results.json", json.dumps(record, indent=1))


# ---------------------------------------------------------------------------------------------
# whole sweep
# ---------------------------------------------------------------------------------------------
def gather_rows(rows: list[dict]) -> list[dict]:
    """All processes' rows on every process (``process_allgather`` of JSON bytes)."""
    if jax.process_count() == 1:
        return rows
    from jax.experimental import multihost_utils

    data = np.frombuffer(json.dumps(rows).encode(), np.uint8)
    sizes = multihost_utils.process_allgather(np.array([data.size], np.int64))
    padded = np.zeros(int(sizes.max()), np.uint8)
    padded[: data.size] = data
    everything = multihost_utils.process_allgather(padded)
    out = []
    for p in range(everything.shape[0]):
        out.extend(json.loads(everything[p, : int(sizes[p, 0])].tobytes().decode()))
    return out


def run_sweep(
    experiment: str,
    seeds: list[int],
    grid: dict[str, list] | None = None,
    overrides: list[str] | None = None,
    progress: bool = False,
    log=print,
    checkpointing: Checkpointing | None = None,
) -> dict:
    """Run the sweep (checkpointed in ``checkpointing.work_dir`` when given: a finished
    group's rows are kept, so a resumed sweep skips it). Returns ``{"rows": [...] (every
    process's, sorted by setting and seed), "groups": [...], "grid", "seeds", "wall_s", ...}``.
    """
    if not seeds:
        raise ConfigError("seeds", "a sweep needs at least one seed")
    t0 = time.perf_counter()
    grid = grid or {}
    groups = plan(experiment, grid, overrides or [])
    total = assign_runs(groups, seeds, jax.process_index(), jax.process_count())
    rows, timings = [], []
    if checkpointing:
        from cognet_jax.checkpoint import atomic_write_text

        spec = {"experiment": experiment, "seeds": seeds, "grid": grid, "overrides": overrides}
        checkpointing.work_dir.mkdir(parents=True, exist_ok=True)
        atomic_write_text(checkpointing.work_dir / SWEEP_SPEC, json.dumps(spec, indent=1))
    for g_index, g in enumerate(groups):
        desc = f"group {g_index + 1}/{len(groups)}"
        tag = f"group{g_index}-p{jax.process_index()}"
        done = checkpointing.work_dir / f"{tag}.rows.json" if checkpointing else None
        if done and checkpointing.resume and done.exists():
            stored = json.loads(done.read_text())
            if stored["runs"] != [list(r) for r in g.runs]:
                raise MismatchError(f"{done} was written by another sweep")
            g_rows, timing = stored["rows"], stored["timing"]
        else:
            g_rows, timing = run_group(g, progress, desc, checkpointing, tag)
            if done:
                from cognet_jax.checkpoint import atomic_write_text

                record = {"runs": g.runs, "rows": g_rows, "timing": timing}
                atomic_write_text(done, json.dumps(record))
        for row in g_rows:
            row["group"] = g_index
        rows.extend(g_rows)
        timing.update(group=g_index, settings=[s.index for s in g.settings])
        timings.append(timing)
    rows = sorted(gather_rows(rows), key=lambda r: (r["setting"], r["seed"]))
    if len(rows) != total:  # pragma: no cover - a lost process
        raise RuntimeError(f"gathered {len(rows)} runs, expected {total}")
    wall_s = time.perf_counter() - t0
    log(
        f"sweep {experiment}: {total} runs in {len(groups)} compiled group(s), "
        f"{jax.process_count()} process(es) x {jax.local_device_count()} device(s), "
        f"wall {wall_s:.1f} s"
    )
    settings = {s.index: s.values for g in groups for s in g.settings}
    return {
        "experiment": experiment,
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


# ---------------------------------------------------------------------------------------------
# outputs
# ---------------------------------------------------------------------------------------------
def _stderr(x: np.ndarray) -> float:
    return float(x.std(ddof=1) / np.sqrt(x.size)) if x.size > 1 else float("nan")


def exact_of(final_value: dict) -> float | None:
    """The exact value of a run's best policy (tabular problems): the infinite discounted value
    when the discount is below 1, else the value at the horizon; ``None`` when not computed."""
    return final_value.get("exact_infinite", final_value.get("exact"))


def summarize(result: dict) -> list[dict]:
    """Per setting: mean +- s.e. over seeds of the honest final value and the in-loop best, and
    for tabular problems the exact values' mean, minimum and maximum over seeds."""
    out = []
    for index, values in enumerate(result["settings"]):
        rows = [r for r in result["rows"] if r["setting"] == index]
        finals = np.array([r["final_value"]["mean"] for r in rows])
        best = np.array([r["in_loop_best"] for r in rows])
        n = finals.size
        out.append(
            {
                "setting": index,
                "grid": values,
                "seeds": n,
                "final_mean": float(finals.mean()),
                "final_se": _stderr(finals),
                "in_loop_best_mean": float(best.mean()),
                "in_loop_best_se": _stderr(best),
            }
        )
        exact = [exact_of(r["final_value"]) for r in rows]
        if exact and all(e is not None for e in exact):
            out[-1].update(
                exact_mean=float(np.mean(exact)), exact_min=min(exact), exact_max=max(exact)
            )
    return out


def _setting_label(values: dict) -> str:
    return ", ".join(f"{k}={v}" for k, v in values.items()) or "(base config)"


def write_outputs(result: dict, out_dir: str | Path) -> list[Path]:
    """``runs.csv``, ``runs.json``, ``summary.md`` and ``values.png`` in ``out_dir``."""
    from cognet_jax.checkpoint import atomic_write_text

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    names = list(result["grid"])
    # tabular problems: the exact values of each best policy (runner.exact_evaluation)
    exact_keys = [k for k in ("exact", "exact_infinite") if k in result["rows"][0]["final_value"]]
    with (out / "runs.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(
            ["setting", "group", "seed", *names, "final_mean", "final_stderr", "final_rollouts"]
            + ["in_loop_best"]
            + [f"final_{k}" for k in exact_keys]
        )
        for r in result["rows"]:
            fv = r["final_value"]
            w.writerow(
                [r["setting"], r["group"], r["seed"], *(r["grid"][n] for n in names)]
                + [repr(fv["mean"]), repr(fv["stderr"]), fv["rollouts"], repr(r["in_loop_best"])]
                + [repr(fv.get(k)) for k in exact_keys]
            )
    atomic_write_text(out / "runs.json", json.dumps(result, indent=1))
    summary = summarize(result)
    lines = [
        f"# Sweep of {result['experiment']}",
        "",
        f"{len(result['seeds'])} seeds ({result['seeds'][0]}..{result['seeds'][-1]}), "
        f"{len(summary)} setting(s), {len(result['groups'])} compiled group(s); wall "
        f"{result['wall_s']:.1f} s. Honest value: mean over seeds of each run's fresh "
        f"evaluation of its best policy ({result['rows'][0]['final_value']['rollouts']} "
        "rollouts, the seed's eval key); +- is the standard error over seeds.",
    ]
    with_exact = all("exact_mean" in s for s in summary)
    if with_exact:
        infinite = "exact_infinite" in exact_keys
        lines[-1] += (
            " Exact value: the best policy's value by dynamic programming ("
            + ("infinite discounted sum" if infinite else "at the horizon")
            + "), mean over seeds and [min, max]."
        )
    header = "| setting | seeds | honest value | in-loop best |"
    lines += [
        "",
        header + (" exact value |" if with_exact else ""),
        "|---|---|---|---|" + ("---|" if with_exact else ""),
    ]
    for s in summary:
        row = (
            f"| {_setting_label(s['grid'])} | {s['seeds']} | {s['final_mean']:.3f} +- "
            f"{s['final_se']:.3f} | {s['in_loop_best_mean']:.3f} +- {s['in_loop_best_se']:.3f} |"
        )
        if with_exact:
            row += f" {s['exact_mean']:.6f} [{s['exact_min']:.6f}, {s['exact_max']:.6f}] |"
        lines.append(row)
    atomic_write_text(out / "summary.md", "\n".join(lines) + "\n")
    _plot_values(result, out / "values.png")
    return [out / n for n in ("runs.csv", "runs.json", "summary.md", "values.png")]


def _plot_values(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    for index, values in enumerate(result["settings"]):
        v = np.array([r["values_per_iteration"] for r in result["rows"] if r["setting"] == index])
        mean = v.mean(0)
        se = v.std(0, ddof=1) / np.sqrt(v.shape[0]) if v.shape[0] > 1 else np.zeros_like(mean)
        x = np.arange(1, mean.size + 1)
        (line,) = ax.plot(x, mean, label=_setting_label(values))
        ax.fill_between(x, mean - se, mean + se, color=line.get_color(), alpha=0.2)
    ax.set_xlabel("iteration")
    ax.set_ylabel("in-loop value (mean over seeds +- s.e.)")
    ax.set_title(f"{result['experiment']}: {len(result['seeds'])} seeds per setting")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
