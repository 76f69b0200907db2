"""What a group leaves on disk: its checkpoint (``save_group`` / ``restore_group``: the
search state, run keys and per-iteration metrics, ``checkpoint.save_checkpoint``) and each
run's folder (``write_run``): ``results.json`` (``RESULTS_SCHEMA``: experiment, algorithm,
seed, setting and grid of a sweep, full config, ``final_value`` {mean, stderr, rollouts, exact
values of tabular controllers}, ``in_loop_best`` (the search's own estimate), per-iteration
values, ``finish`` (the record of the algorithm's ``finish`` step, or null; ``polish`` in
files written before it had that name), timings), ``policy.msgpack`` (the best policy with its
``fingerprint``), ``vae.msgpack`` when the observation pipeline has a VAE, and PNG plots."""

from __future__ import annotations

import hashlib
import json
import warnings
from pathlib import Path

import jax
import numpy as np

from cognet_jax.api import (
    split_seed_key,
)
from cognet_jax.atomic_files import atomic_write_bytes, atomic_write_json
from cognet_jax.checkpoint import (
    fingerprint_difference,
    policy_bytes,
    read_checkpoint,
    restore_history,
    restore_key,
    restore_state,
    save_checkpoint,
    stack_history,
)
from cognet_jax.compiled import file_digest
from cognet_jax.config import Config, with_added_fields
from cognet_jax.errors import (
    CorruptFileError,
    MismatchError,
    OneLineWarning,
    SimulatorError,
    UsageError,
)
from cognet_jax.hook_results import RUN_RECORD_FIELDS, checked_record
from cognet_jax.io.dpomdp import model_digest
from cognet_jax.plugins import one_line, user_code_error
from cognet_jax.program import Program, Run
from cognet_jax.registry import (
    env_entry,
    foreign_code,
    late_code,
)
from cognet_jax.reporting import write_plots

#: version of results.json (2: one schema for train and sweep runs; see ``run_record``)
RESULTS_SCHEMA = 2
#: the files of a run folder that a search's ``run_files`` may not name
RUN_OWN_FILES = (
    "results.json",
    "policy.msgpack",
    "checkpoint.msgpack",
    "evaluations.jsonl",
    ".lock",
)


def _meta(runs: list[Run]) -> dict:
    """What a checkpoint was written by (compared on resume, ``run`` sections aside)."""
    return {
        "kind": "runs",
        "runs": [[r.setting, r.seed] for r in runs],
        "configs": [r.config.to_dict() for r in runs],
    }


def _without_run_section(meta: dict) -> dict:
    meta = json.loads(json.dumps(meta))
    for config in meta.get("configs", []):
        config.pop("run", None)
    return meta


def _run_keys(program: Program):
    """Every run's run key (``[runs]``, or the one run's), computed once per program: a stop
    writes its checkpoint while an iteration may still be computing, and a new computation
    would wait behind it."""
    keys = getattr(program, "_run_keys", None)
    if keys is None:
        keys = jax.vmap(lambda k: split_seed_key(k)[1])(program.seed_keys)  # [runs]
        keys = keys[0] if not program.batched else keys
        program._run_keys = keys
    return keys


def _run_fingerprints(program: Program) -> list[dict]:
    """Per run, what besides its config shapes its numbers (``fingerprint`` without the
    config: the model file's digest, the numeric settings and imported modules), taken once
    per group: a model edited while the search runs is a difference on resume."""
    cached = getattr(program, "_run_fingerprints", None)
    if cached is None:
        by_config = {}  # a sweep's seeds of one setting share a config: one model digest
        for r in program.runs:
            if id(r.config) not in by_config:
                made = fingerprint(r.config)
                by_config[id(r.config)] = {k: v for k, v in made.items() if k != "config"}
        cached = [by_config[id(r.config)] for r in program.runs]
        program._run_fingerprints = cached
    return cached


def save_group(program: Program, path: Path, iteration: int, state, history) -> None:
    save_checkpoint(
        path,
        state=state,
        keys={"run": _run_keys(program)},
        iteration=iteration,
        history=stack_history(history),
        meta={**_meta(program.runs), "fingerprints": _run_fingerprints(program)},
    )


#: a fingerprint's keys in the words of a refused resume
RESUME_DIFFERENCES = {
    "model": "another model file",
    "numerics": "other numeric settings or --import modules",
    "generator": "another generator",
}


def _check_run_fingerprints(path: Path, stored, program: Program) -> None:
    """``MismatchError`` naming what differs when the group was started under another model
    file, numeric settings or imported modules than it resumes under (``checkpoint``'s
    rules for a policy: a setting not recorded then is no difference)."""
    if not isinstance(stored, list):  # written before fingerprints
        return
    for old, now in zip(stored, _run_fingerprints(program)):
        if not isinstance(old, dict):
            raise CorruptFileError(path, "its fingerprints are not a list of records")
        differ = fingerprint_difference(old, now)
        if differ:
            key, _, detail = differ.partition(" ")
            what = RESUME_DIFFERENCES.get(key, key)
            raise MismatchError(
                f"{path}: the run was started with {what} {detail}; resuming would go on "
                "with another simulator's or generator's numbers (resume with the model file, "
                "settings and --import modules it was started with, or start again)"
            )


def current_meta(meta: dict, path) -> dict:
    """``meta`` of a checkpoint in today's form: a ``train`` checkpoint of the earlier runner is
    the group of its one run; an earlier sweep's cannot be read (it kept no run keys)."""
    kind = meta.get("kind")
    if kind == "train" and "config" in meta and "seed" in meta:
        return {"kind": "runs", "runs": [[0, meta["seed"]]], "configs": [meta["config"]]}
    if kind != "runs":
        raise MismatchError(
            f"{path} holds a {kind!r} checkpoint of an earlier cognet-jax; resume it with that "
            "version, or start again"
        )
    return meta


def _written_fields(meta: dict, stored: dict) -> dict:
    """``meta`` without the config fields ``stored`` (a checkpoint's meta) did not write: fields
    added to the library since, which a resumed config holds at their defaults, and a new
    field's default keeps the search it was added to (the library's rule for new fields)."""
    meta = json.loads(json.dumps(meta))
    for new, old in zip(meta.get("configs", []), stored.get("configs", [])):
        for section, fields in new.items():
            if isinstance(fields, dict) and isinstance(old.get(section), dict):
                for key in [k for k in fields if k not in old[section]]:
                    del fields[key]
    return meta


def _first_difference(stored: dict, current: dict) -> str:
    """What differs first between a checkpoint's meta and this group's, as words: the seeds,
    or the first config field (``section.key: stored -> now``; a field an older version did
    not write shows as "not written")."""
    if stored.get("runs") != current.get("runs"):
        return "group of seeds and settings"
    for old, new in zip(stored.get("configs", []), current.get("configs", [])):
        for section in sorted(set(old) | set(new)):
            a, b = old.get(section, {}), new.get(section, {})
            for key in sorted(set(a) | set(b)):
                if a.get(key, "not written") != b.get(key, "not written"):
                    was, now = a.get(key, "not written"), b.get(key, "not written")
                    return f"config ({section}.{key}: {was} there, {now} now)"
    return "config or seed"


def restore_group(program: Program, state, path: Path):
    """``(state, raw, iteration)`` from the checkpoint at ``path`` (``raw``: what
    ``read_checkpoint`` read, whose history ``restore_history`` restores); ``MismatchError``
    when another group (configs, seeds or generator) wrote it."""
    raw = read_checkpoint(path)
    if not isinstance(raw["meta"], dict):
        raise CorruptFileError(path, "its meta is not a record")
    stored_fingerprints = raw["meta"].pop("fingerprints", None)
    raw["meta"] = current_meta(raw["meta"], path)
    stored_meta, meta = _without_run_section(raw["meta"]), _without_run_section(_meta(program.runs))
    if isinstance(stored_meta.get("configs"), list):  # fields whose default changed the search
        stored_meta["configs"] = [
            with_added_fields(c) if isinstance(c, dict) else c for c in stored_meta["configs"]
        ]
    meta = _written_fields(meta, stored_meta)
    if stored_meta != meta:
        raise MismatchError(f"{path} was written by another {_first_difference(stored_meta, meta)}")
    impl = program.config.run.prng_impl
    stored_impl = {
        c.get("run", {}).get("prng_impl", "threefry2x32")
        for c in raw["meta"].get("configs", [])
        if isinstance(c, dict)
    }
    if stored_impl and stored_impl != {impl}:
        raise MismatchError(
            f"{path}: run.prng_impl {impl!r}, but the run was started with "
            f"{', '.join(sorted(stored_impl))}; its keys continue only with that generator "
            "(drop the --set run.prng_impl)"
        )
    _check_run_fingerprints(path, stored_fingerprints, program)
    stored = restore_key(raw, "run", impl)
    expected = jax.random.key_data(_run_keys(program))
    if not np.array_equal(np.asarray(jax.random.key_data(stored)), np.asarray(expected)):
        raise MismatchError(f"{path}: stored run keys do not match the seeds")
    if program.batched:
        _relaid(raw, len(program.runs), program.lanes)
    restored = restore_state(jax.device_get(state), raw)
    _check_restored(restored, state, raw, path, program.config.algorithm.iterations)
    # laid out as the initial state (its programs are compiled for that layout)
    state = jax.tree.map(lambda x, like: jax.device_put(x, like.sharding), restored, state)
    return state, raw, int(raw["iteration"])


def _relaid(raw: dict, runs: int, lanes: int) -> None:
    """A batched checkpoint's state and history, padded to another number of lanes than
    ``lanes`` (the devices of the process that wrote it: ``--cpu-devices``, another machine),
    laid out again: its ``runs`` real runs kept, the padding (copies of the last run, whose
    state it is) made again to ``lanes``."""

    def fit(x, axis: int):
        if not isinstance(x, np.ndarray) or x.ndim <= axis or not runs <= x.shape[axis] != lanes:
            return x
        kept = np.take(x, np.arange(runs), axis=axis)
        pad = np.repeat(np.take(kept, [runs - 1], axis=axis), lanes - runs, axis=axis)
        return np.concatenate([kept, pad], axis=axis)

    raw["state"] = jax.tree.map(lambda x: fit(x, 0), raw["state"])
    if raw.get("history") is not None:  # [iterations, lanes, ...]
        raw["history"] = jax.tree.map(lambda x: fit(x, 1), raw["history"])


def _check_restored(restored, initial, raw: dict, path: Path, iterations: int) -> None:
    """``CorruptFileError`` naming ``path`` when its iteration is not a count in 0 ..
    ``iterations`` or an array of its state has another shape or dtype than the run's initial
    state (a checkpoint edited or damaged by hand: the search would fail inside a compiled
    call, or run from a history that is not its own)."""
    iteration = raw.get("iteration")
    if not isinstance(iteration, int | np.integer) or not 0 <= int(iteration) <= iterations:
        raise CorruptFileError(path, f"iteration {iteration!r} is not in 0 .. {iterations}")
    paths = jax.tree_util.tree_flatten_with_path(initial)[0]
    got = jax.tree.leaves(restored)
    if len(got) != len(paths):
        raise CorruptFileError(path, "its search state has other arrays than the run's")
    for (where, like), x in zip(paths, got):
        shape, dtype = tuple(getattr(x, "shape", ())), getattr(x, "dtype", type(x))
        if shape != tuple(like.shape) or dtype != like.dtype:
            name = jax.tree_util.keystr(where)
            raise CorruptFileError(
                path,
                f"state{name} is {dtype}{list(shape)}, the run's is {like.dtype}{list(like.shape)}",
            )


def restored_history(step, raw: dict, path: Path) -> list:
    """The checkpoint's per-iteration metrics, shaped as ``step``'s (after it is compiled: its
    output shapes are the template); ``CorruptFileError`` when they do not fit."""
    try:
        return restore_history(step.metrics_shapes, raw)
    except (ValueError, KeyError, TypeError, IndexError, AttributeError) as err:
        raise CorruptFileError(path, f"history does not fit: {err}") from None


def run_record(run: Run, program: Program, **fields) -> dict:
    """The results.json of ``run`` (``RESULTS_SCHEMA``), from ``fields``: ``status``,
    ``iteration``, ``final_value`` and, for a finished run, its history and timings."""
    config = run.config
    record = {
        "schema": RESULTS_SCHEMA,
        "experiment": config.experiment.name,
        "algorithm": config.experiment.algorithm,
        "seed": run.seed,
        "setting": run.setting,
        "grid": run.grid,
        "config": config.to_dict(),
        "resolved": checked_record(
            program.algorithm, "settings_record", program.algorithm.settings_record()
        ),
        "iterations": config.algorithm.iterations,
        "runs_in_program": len(program.runs),
        "jax_version": jax.__version__,
        "backend": jax.default_backend(),
    }
    record.update(fields)
    return record


def history_fields(history, r: int | None, iterations: int, algorithm) -> dict:
    """The per-iteration fields of run ``r`` (``None``: an unbatched history): the value
    curves every run writes and what the search adds (``Search.history_record``)."""
    h = history if r is None else jax.tree.map(lambda x: x[:, r], history)
    env = algorithm.env
    rollouts = algorithm.rollouts_per_iteration  # a count (checked by ``api.build``)
    fields = {
        "in_loop_best": float(h.in_loop_best[-1]),
        # the search's budget: agent-steps simulated by all its iterations
        "simulated_agent_steps": iterations * int(rollouts) * env.horizon * env.num_agents,
        "values_per_iteration": np.asarray(h.value).tolist(),
        "in_loop_best_per_iteration": np.asarray(h.in_loop_best).tolist(),
    }
    own = algorithm.history_record(h)  # the search's own per-run figures
    fields.update(checked_record(algorithm, "history_record", own, RUN_RECORD_FIELDS))
    return fields


def check_finite_values(history, program: Program) -> None:
    """``SimulatorError`` when an iteration's value (``history.value``, ``[iterations]`` or
    ``[iterations, runs]``) is NaN: the simulator returned a NaN reward or observation for
    policies the search drew (``check_simulator``'s random episodes never reached them), so
    its elites were chosen among NaN means; nothing is written. ``UsageError`` naming the
    search's ``tell`` when its metrics lack ``value`` or ``in_loop_best``, give more than one
    number per run and iteration, or a NaN ``in_loop_best``."""
    search = type(program.algorithm).__name__
    runs = len(program.runs) if program.batched else 1
    fields = {}
    for name in ("value", "in_loop_best"):
        try:
            fields[name] = np.asarray(getattr(history, name), np.float64)
        except (AttributeError, TypeError, ValueError):
            raise UsageError(
                f"{search}.tell (the search's code) returned metrics of type "
                f"{type(history).__name__} without a numeric {name!r}: expected "
                "SearchMetrics(value, in_loop_best, mean_value)"
            ) from None
        shape = fields[name].shape
        if shape[1:] not in ((), (runs,), (program.lanes,)):
            raise UsageError(
                f"{search}.tell (the search's code) returned metrics.{name} of shape "
                f"{list(shape[1:])} per iteration: expected one number per run"
            )
    if np.isnan(fields["in_loop_best"]).any():
        raise UsageError(f"{search}.tell (the search's code) returned a NaN in_loop_best")
    value = fields["value"]
    if value.size == 0:  # no iteration ran
        return
    # an infinite value is a return past float32 (a reward of 4e37 summed over the steps)
    nan = ~np.isfinite(value.reshape(value.shape[0], -1)).all(axis=1)
    bad = "NaN" if np.isnan(value).any() else "infinite"
    if nan.any() and not type(program.algorithm).__module__.startswith("cognet_jax."):
        env = program.algorithm.env
        also = (
            ""
            if type(env).__module__.startswith("cognet_jax.")
            else f", or the simulator {program.config.env.name!r} returned a NaN reward or "
            "observation, or returns past float32, for policies it drew"
        )
        raise UsageError(
            f"{search}.tell (the search's code) returned "
            f"{'a NaN' if bad == 'NaN' else 'an infinite'} value at iteration "
            f"{int(np.argmax(nan)) + 1} ({int(nan.sum())} of {nan.size} iterations): a NaN of "
            f"its own computation{also}; nothing is written"
        )
    if nan.any():
        env = program.algorithm.env
        owner = f"{type(env).__module__}.{type(env).__name__}"
        raise SimulatorError(
            f"simulator {program.config.env.name!r} ({owner}): the search's value is "
            f"{bad} at iteration "
            f"{int(np.argmax(nan)) + 1} ({int(nan.sum())} of {nan.size} iterations): its step "
            "returned a NaN reward or observation, or rewards whose returns pass float32 "
            "(|x| > 3.4e38), for policies the search drew; nothing is written"
        )


def fingerprint(config: Config, written: dict | None = None, seed=None) -> dict:
    """What shapes a policy, hashed: ``config`` without its ``run`` and ``evaluation`` sections
    (as ``written`` to results.json when given: a newer version of the library may add
    settings with defaults, which must not make an old run's policy a stranger), the model
    file it reads (a simulator that reads ``[problem]``), the numeric settings and the run's
    ``run.prng_impl`` and ``seed`` (``generator``: the run's own evaluation draws with them).
    Stored in the policy file; ``load_run`` refuses a policy whose results.json or model
    changed since."""
    written = config.to_dict() if written is None else written
    shaping = {k: v for k, v in written.items() if k not in ("run", "evaluation")}
    text = json.dumps(shaping, sort_keys=True, default=str).encode()
    out = {"config": hashlib.sha256(text).hexdigest(), "numerics": numeric_settings()}
    run = written.get("run")
    generator = {"seed": seed} if seed is not None else {}  # the run's keys: its results.json's
    if isinstance(run, dict) and "prng_impl" in run:
        generator["run.prng_impl"] = run["prng_impl"]
    if generator:
        out["generator"] = generator
    path = Path(config.problem.path).expanduser() if config.problem.path else None
    if path is not None and "problem" in env_entry(config.env.name).reads and path.is_file():
        out["model"] = model_digest(path)  # the text: a .gz copy is the same model
        if out["model"] != file_digest(path):  # what runs of gzip files recorded before
            out["model_file"] = file_digest(path)
    return out


def numeric_settings() -> dict:
    """What besides the config changes a policy's numbers: JAX's 64-bit mode, default PRNG and
    threefry layout, and the modules imported from outside the package (``--import`` and the
    modules it imported) with their digests; ``imported_late``: the helpers a user module
    imported only when it ran (compared where loaded at both times: one an evaluation never
    loads never ran in it)."""
    return {
        "x64": bool(jax.config.jax_enable_x64),
        "prng": str(jax.config.jax_default_prng_impl),
        "threefry_partitionable": bool(jax.config.jax_threefry_partitionable),
        "imported": foreign_code(late=False),
        "imported_late": late_code(),
    }


def own_run_files(algorithm) -> dict:
    """``{name: (config field, bytes)}``: the files the search keeps in each run folder (its
    ``run_files`` hook; none without it), their names checked before any file is written."""
    files = getattr(algorithm, "run_files", dict)()
    for name in files:
        if name != Path(name).name or name in RUN_OWN_FILES:
            raise UsageError(
                f"run_files of {type(algorithm).__name__}: {name!r} is not a file name of its "
                "own in the run folder"
            )
    return files


def write_run(run: Run, record: dict, policy, algorithm, files: dict | None = None) -> None:
    """A run's training folder: ``policy.msgpack`` (with its ``fingerprint``),
    ``results.json`` (with the policy file's ``policy_sha256``) and the search's ``run_files``
    (``files``, else ``own_run_files(algorithm)``; recorded under ``run_files``: each one's
    config field and sha256); its figures are ``draw_figures``'."""
    if run.folder is None:
        return
    run.folder.mkdir(parents=True, exist_ok=True)
    policy_file = policy_bytes(policy, fingerprint(run.config, seed=run.seed))
    atomic_write_bytes(run.folder / "policy.msgpack", policy_file)
    # the file's digest: ``evaluate`` refuses a policy file replaced since (another run's)
    record = {**record, "policy_sha256": hashlib.sha256(policy_file).hexdigest()}
    kept = {}
    files = own_run_files(algorithm) if files is None else files
    for name, (field, data) in files.items():
        atomic_write_bytes(run.folder / name, data)
        kept[name] = {"field": field, "sha256": hashlib.sha256(data).hexdigest()}
    if kept:  # checked as the policy's digest is
        record["run_files"] = kept
    atomic_write_json(run.folder / "results.json", record)


def draw_figures(run: Run, record: dict, policy, algorithm) -> bool:
    """The figures of a complete run written by ``write_run`` (``reporting.write_plots``);
    whether they were drawn. A stop signal while they are drawn stops them (the results are
    complete: nothing is lost), so it is not deferred as writing the results is."""
    if run.folder is None or record.get("status") != "complete":
        return False
    try:
        write_plots(run.config, algorithm, policy, record, run.folder)
        return True
    # the run's results stand; figures of a run replaced go (``run_folder.claim``), so no
    # older figure stays beside them. ValueError: matplotlib refuses what it cannot draw (a
    # policy whose responses are not finite, e.g. read through an encoder of huge weights),
    # and any error of a search's own figures (``write_plots``, the search's code): the
    # results were written complete before
    except Exception as err:
        why = user_code_error(err) or f"{type(err).__name__}: {one_line(err)}"
        warnings.warn(
            f"{run.folder}: the figures could not be written ({why}); the run's results are saved",
            OneLineWarning,
            stacklevel=2,
        )
    return False
