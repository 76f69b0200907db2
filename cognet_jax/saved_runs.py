"""Run folders read back: the config and seed of a checkpoint to resume (``resume_target``),
a finished run's config, search and best policy (``load_run``) and its honest value again
(``evaluate_run``, what ``cognet-jax evaluate DIR`` prints)."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import time
import warnings
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from cognet_jax.algorithms.engine import SearchParams
from cognet_jax.api import (
    Built,
    build,
    seed_key,
)
from cognet_jax.budget import evaluation_line
from cognet_jax.checkpoint import (
    CHECKPOINT_NAME,
    read_checkpoint,
    read_policy,
)
from cognet_jax.compiled import DRIVING_FIELDS
from cognet_jax.config import (
    Config,
    ConfigError,
    EvaluationSection,
    apply_overrides,
    parse_override,
    with_added_fields,
)
from cognet_jax.errors import CorruptFileError, MismatchError, OneLineWarning, UsageError, read_json
from cognet_jax.honest_value import final_value
from cognet_jax.observations import legacy_run_files
from cognet_jax.records import RESULTS_SCHEMA, RUN_OWN_FILES, current_meta, fingerprint
from cognet_jax.registry import config_from_dict, env_entry
from cognet_jax.run_folder import REPLACING_NAME, sweep_holding


def resume_target(run_dir, overrides: list[str] | None = None) -> tuple[Config, int]:
    """``(config, seed)`` stored in the checkpoint of the run folder ``run_dir``.
    ``overrides`` may only touch the ``run`` section (progress, plots, checkpoints)."""
    for text in overrides or []:
        (section, _), _ = parse_override(text)
        if section != "run":
            raise ConfigError(text.split("=")[0], "cannot be changed when resuming")
    folder = Path(run_dir)
    path = folder / CHECKPOINT_NAME
    sweep = folder if (folder / "sweep.json").is_file() else sweep_holding(folder)
    if sweep is not None and not path.is_file():  # a sweep continues its own runs
        raise UsageError(
            f"{run_dir} is {'a run of ' if sweep != folder else ''}the sweep in {sweep}: "
            f"continue it with `cognet-jax sweep --resume {sweep}`"
        )
    meta = current_meta(read_checkpoint(path)["meta"], path)
    if len(meta.get("runs", [])) != 1:
        raise ConfigError("", f"{run_dir} holds no checkpoint of a single train run")
    stored = with_added_fields(meta["configs"][0])
    seed = int(meta["runs"][0][1])
    _refuse_another_runs_checkpoint(Path(run_dir), stored, seed)
    config = config_from_dict(apply_overrides(stored, overrides or []))
    return config, seed


def finished_value(run_dir, config: Config) -> dict | None:
    """The ``final_value`` of the run in ``run_dir`` when its results.json is complete with
    every iteration of ``config`` (the checkpoint's, ``resume_target``), the checkpoint is of
    its last iteration and no ``--overwrite`` replaces it: resuming it would search nothing
    and only rewrite its timings. ``None`` otherwise (a stopped run, or a finished search not
    yet evaluated)."""
    run_dir = Path(run_dir)
    path = run_dir / "results.json"
    if not path.is_file() or (run_dir / REPLACING_NAME).exists():
        return None
    results = read_json(path, ("status", "iteration", "final_value"))
    iterations = getattr(config.algorithm, "iterations", None)
    checkpoint = read_checkpoint(run_dir / CHECKPOINT_NAME)["iteration"]
    done = results["status"] == "complete" and results["iteration"] == iterations == checkpoint
    value = results["final_value"]
    return value if done and isinstance(value, dict) and "mean" in value else None


def _refuse_another_runs_checkpoint(run_dir: Path, stored: dict, seed: int) -> None:
    """Refuse to resume a checkpoint of another run than the finished one whose results.json
    is beside it (e.g. copied there): resuming would replace those results. A run started with
    ``--overwrite`` and stopped (``run_folder.REPLACING_NAME`` present) is the exception: its
    checkpoint is meant to replace them. The ``run`` section may differ (resume changes it)."""
    results_path = run_dir / "results.json"
    if not results_path.is_file() or (run_dir / REPLACING_NAME).exists():
        return
    results = read_json(results_path, ("config", "seed"))
    if not isinstance(results["config"], dict):
        raise CorruptFileError(results_path, "its config is not a table of sections")
    finished = with_added_fields(results["config"])
    differing = sorted(
        f"{section}.{key}"
        for section in set(stored) | set(finished)
        if section != "run"
        for key in set(stored.get(section, {})) | set(finished.get(section, {}))
        if stored.get(section, {}).get(key) != finished.get(section, {}).get(key)
    )
    if results["seed"] != seed:
        differing.insert(0, "seed")
    if differing:
        raise MismatchError(
            f"{run_dir / CHECKPOINT_NAME} is the checkpoint of another run than "
            f"{results_path} ({', '.join(differing[:4])} differ); resuming it would replace "
            "that run's results: give the checkpoint a folder of its own"
        )


@dataclasses.dataclass
class LoadedRun:
    """A finished (or stopped) run folder: its config (with overrides), the search and params
    built from it, its best policy and its results.json."""

    config: Config
    algorithm: Any
    params: SearchParams
    policy: Any
    results: dict
    #: the overrides that change nothing the evaluation reads (``_no_effect``)
    no_effect: tuple = ()


def load_run(
    run_dir,
    overrides: list[str] | None = None,
    rollouts: int | None = None,
    built: Built | None = None,
) -> LoadedRun:
    """The run in ``run_dir``. ``overrides`` (``--set``) may change the evaluation setting,
    e.g. ``env.obs_noise=0.1``; shapes must match; ``rollouts`` replaces
    ``evaluation.rollouts`` before the run is built (and its size checked, ``api.build``).
    The run's own ``vae.msgpack`` (if any) is used unless ``network.vae_path`` is
    overridden. ``built``: the run as the caller built it (``api.build``; e.g. once for all
    the seeds of a sweep), used as built; its config must be the folder's (with
    ``overrides`` and ``rollouts``), ``MismatchError`` naming the fields otherwise; a file
    the run kept (an encoder) may be another copy with the same digest."""
    run_dir = Path(run_dir)
    results_path = run_dir / "results.json"
    if not results_path.is_file():
        raise FileNotFoundError(f"{results_path} not found: is {run_dir} a training output folder?")
    results = read_json(results_path, ("config",))
    if not isinstance(results["config"], dict):
        raise CorruptFileError(results_path, "its config is not a table of sections")
    schema = results.get("schema", 1)
    if isinstance(schema, bool) or not isinstance(schema, int) or not 1 <= schema <= RESULTS_SCHEMA:
        raise CorruptFileError(
            results_path,
            f"schema {schema!r}: this cognet-jax reads results.json schemas 1 .. "
            f"{RESULTS_SCHEMA} (a newer version wrote it, or it was edited)",
        )
    ran = with_added_fields(results["config"])  # results.json as written: the fingerprint's
    overrides = list(overrides or [])
    named = {tuple(parse_override(o)[0]) for o in overrides}
    for o in overrides:
        path, value = parse_override(o)
        trained_by = (ran.get("experiment") or {}).get("algorithm")
        if path == ["experiment", "algorithm"] and value != trained_by:
            raise UsageError(
                f"--set {o.strip()}: {run_dir} holds a policy of {trained_by!r}; another "
                "algorithm cannot evaluate it"
            )
    # the model file given anew (the run's path may be relative to another folder, or the
    # file moved): the same bytes only, as the policy file's fingerprint records them
    model_sets = [o for o in overrides if tuple(parse_override(o)[0]) == ("problem", "path")]
    model = (ran.get("problem") or {}).get("path")
    if not model_sets and isinstance(model, str) and model and not _exists(model, ran):
        raise FileNotFoundError(
            f"{run_dir} was trained on the model file {model!r}, which is not there from this "
            "folder (a relative path is read from where the command runs): run from the "
            "folder it was trained in, or give the same file with --set problem.path=FILE"
        )
    # the files the run kept (an encoder, ...), read from the folder unless a field is given
    recorded = "run_files" if "run_files" in results else "vae_sha256"  # before run_files
    kept = _run_files(results, run_dir, results_path)
    kept = {n: f for n, f in kept.items() if tuple(f["field"].split(".")) not in named}
    kept_sets = [f"{f['field']}={json.dumps(str(run_dir / name))}" for name, f in kept.items()]
    overrides = kept_sets + overrides

    def make(sets: list[str]) -> Config:
        made = config_from_dict(apply_overrides(ran, sets))
        if rollouts is None:
            return made
        evaluation = dataclasses.replace(made.evaluation, rollouts=rollouts)
        return dataclasses.replace(made, evaluation=evaluation)

    config = make(overrides)
    if built is None:
        built = build(config)
    else:
        _check_built(built, config, {f["field"] for f in kept.values()}, run_dir)
        config = built.config
        kept = {n: dict(f, path=_field_path(config, f["field"])) for n, f in kept.items()}
    algorithm, params = built.algorithm, built.params
    # the policy's structure and shapes, traced (running ``init`` op by op took seconds)
    template = jax.eval_shape(
        lambda k: algorithm.best_policy(algorithm.init(k, params)), jax.random.key(0)
    )
    # after the build and a trace: a user module may import its helpers only then
    trained = fingerprint(
        config_from_dict(apply_overrides(ran, model_sets)), results["config"], results.get("seed")
    )
    try:
        saved = read_policy(run_dir / "policy.msgpack", template, fingerprint=trained)
    except MismatchError:  # a policy copied from another run is named as that, if it is one
        _check_digest(run_dir / "policy.msgpack", results.get("policy_sha256"), "policy_sha256")
        raise
    _check_digest(run_dir / "policy.msgpack", results.get("policy_sha256"), "policy_sha256")
    for name, file in kept.items():
        _check_digest(file.get("path", run_dir / name), file["sha256"], recorded)
    policy = jax.tree.map(jnp.asarray, saved)
    given = [o for o in overrides if o not in model_sets and o not in kept_sets]
    no_effect = _no_effect(make, model_sets + kept_sets, given, built) if given else ()
    return LoadedRun(config, algorithm, params, policy, results, no_effect)


def _evaluated(built: Built) -> tuple:
    """What an evaluation of a stored policy reads of a built run: the simulator, its
    params, the controller, the evaluation's settings and the key's generator."""
    c = built.config
    return (built.env, built.env_params, built.algorithm.controller, c.evaluation, c.run.prng_impl)


def _same(a, b) -> bool:
    try:
        leaves_a, tree_a = jax.tree.flatten(a)
        leaves_b, tree_b = jax.tree.flatten(b)
        if tree_a != tree_b:
            return False
        return all(
            np.array_equal(np.asarray(x), np.asarray(y))
            if hasattr(x, "shape") or hasattr(y, "shape")
            else bool(x == y)
            for x, y in zip(leaves_a, leaves_b)
        )
    except Exception:  # objects that cannot be compared: taken as different
        return False


def _no_effect(make, fixed: list[str], given: list[str], built: Built) -> tuple:
    """The overrides of ``given`` that change nothing an evaluation reads (``_evaluated``):
    a search's or a run's field (``algorithm.iterations``, ``run.memory_gb``) set on
    ``evaluate`` gives the run's own value, which the value line would otherwise show beside
    them as if they were applied. ``make(overrides) -> Config``: the run's config with them;
    ``fixed``: the overrides every build keeps (the model file, the run's own files)."""
    try:
        base = _evaluated(build(make(fixed)))
    except Exception:  # the run's own setting does not build here: no verdict
        return ()
    if _same(base, _evaluated(built)):
        return tuple(given)
    if len(given) == 1:
        return ()
    quiet = []
    for o in given:
        try:
            alone = build(make([*fixed, o]))
        except Exception:
            continue
        if _same(base, _evaluated(alone)):
            quiet.append(o)
    return tuple(quiet)


def _exists(path: str, written: dict) -> bool:
    """Whether the model file ``path`` of the config ``written`` is a file from this folder
    (or one its simulator does not read)."""
    try:
        reads = "problem" in env_entry(str((written.get("env") or {}).get("name"))).reads
    except Exception:  # an unknown simulator: building the config names it
        return True
    return not reads or Path(path).expanduser().is_file()


def _check_built(built: Built, config: Config, kept_fields: set, run_dir: Path) -> None:
    """Refuse a ``built`` run whose config is not ``config`` (the folder's, with the
    caller's overrides), but for the ``run`` fields that only drive a run
    (``compiled.DRIVING_FIELDS``) and the fields of kept files."""
    mine, theirs = config.to_dict(), built.config.to_dict()
    differ = []
    for section in sorted(set(mine) | set(theirs)):
        a, b = mine.get(section) or {}, theirs.get(section) or {}
        for key in sorted(set(a) | set(b)):
            name = f"{section}.{key}"
            skip = name in kept_fields or (section == "run" and key in DRIVING_FIELDS)
            if not skip and a.get(key) != b.get(key):
                differ.append(f"{name} ({b.get(key)!r}, the run's {a.get(key)!r})")
    if differ:
        raise MismatchError(
            f"the Built run given is not the run in {run_dir}: it differs in "
            f"{', '.join(differ)}; build the folder's config (with the overrides) or pass none"
        )


def _field_path(config: Config, field: str) -> Path:
    """The file the ``section.key`` field of ``config`` names."""
    section, key = field.split(".")
    return Path(getattr(getattr(config, section), key)).expanduser()


def _run_files(results: dict, run_dir: Path, results_path: Path) -> dict:
    """results.json's ``run_files`` (``{name: {"field", "sha256"}}``), checked: plain file
    names of the folder that are not the run's own files; ``CorruptFileError`` otherwise."""
    kept = results.get("run_files")
    if kept is None:
        return legacy_run_files(results, run_dir)
    ok = isinstance(kept, dict) and all(
        isinstance(name, str)
        and name == Path(name).name
        and name not in RUN_OWN_FILES
        and isinstance(file, dict)
        and isinstance(file.get("field"), str)
        and file["field"].count(".") == 1
        and isinstance(file.get("sha256"), str | None)
        for name, file in kept.items()
    )
    if not ok:
        raise CorruptFileError(
            results_path, "its run_files is not a table {file name: {field, sha256}}"
        )
    return kept


def _check_digest(path: Path, digest, field: str) -> None:
    """Refuse a policy file (or a kept run file) other than the one its run wrote
    (``results.json``'s ``field``: ``policy_sha256``, ``run_files``; runs saved before them
    have none): a file copied from another run, or trained again into the folder, would give
    another number under this run's name."""
    if digest is None or not path.is_file():
        return  # read_policy names a missing file
    if hashlib.sha256(path.read_bytes()).hexdigest() != digest:
        raise MismatchError(
            f"{path}: not the file this run wrote (its sha256 differs from results.json's "
            f"{field}): it was replaced, or copied from another run; evaluate the run "
            f"folder it came from"
        )


def _note_other_chunks(run, config: Config) -> None:
    """One line when ``evaluation.batch`` differs from the run's and the rollouts do not fit
    in one batch of either: the rollouts are drawn in other chunks (each from its own key,
    ``rollout.many_returns``), so the value is another honest sample, not the run's number."""
    section = run.results["config"].get("evaluation")
    ran = EvaluationSection.batch  # the default, for a run that did not write it
    ran = section.get("batch", ran) if isinstance(section, dict) else ran
    now, n = config.evaluation.batch, config.evaluation.rollouts
    if ran != now and n > min(ran, now):
        warnings.warn(
            f"evaluation.batch {now} where the run had {ran}: its {n} rollouts are drawn in "
            "other chunks, so the value is another honest sample of the policy (within its "
            "standard error), not the run's number",
            OneLineWarning,
            stacklevel=3,
        )
    section = run.results["config"].get("run")
    ran = section.get("prng_impl") if isinstance(section, dict) else None
    if ran is not None and ran != config.run.prng_impl:
        warnings.warn(
            f"run.prng_impl {config.run.prng_impl} where the run had {ran}: the seed's key "
            "draws other rollouts, so the value is another honest sample of the policy "
            "(within its standard error), not the run's number",
            OneLineWarning,
            stacklevel=3,
        )


def evaluate_run(
    run_dir,
    rollouts: int | None = None,
    seed: int | None = None,
    overrides=(),
    announce=None,
    built: Built | None = None,
):
    """The honest value of the best policy in ``run_dir``: by default the run's own
    evaluation (its seed's evaluation key, ``evaluation.rollouts``), which reproduces its
    results.json ``final_value``; ``seed`` draws from that seed's evaluation key instead,
    ``rollouts`` changes the number, ``overrides`` the setting. ``announce(line)``, when given,
    hears a large evaluation's size and least time before it compiles (``evaluation_line``).
    ``built``: the run as the caller built it (``load_run``), e.g. once for every seed of a
    sweep. Returns the summary with ``seed``, ``overrides`` and ``wall_s``."""
    t0 = time.perf_counter()
    run = load_run(run_dir, list(overrides), rollouts, built)
    config = run.config
    line = evaluation_line(config, run.algorithm.env, str(run_dir))
    if announce is not None and line is not None:
        announce(line)
    stored = run.results.get("seed", 0)
    if seed is None and (not isinstance(stored, int) or isinstance(stored, bool) or stored < 0):
        raise CorruptFileError(Path(run_dir) / "results.json", f"seed {stored!r} is no seed")
    seed = stored if seed is None else seed
    _note_other_chunks(run, config)
    evaluate = final_value(run.algorithm, config, run.params)
    value = evaluate(seed_key(config, seed), run.policy)
    value.update(seed=seed, overrides=list(overrides), wall_s=time.perf_counter() - t0)
    if run.no_effect:
        value["no_effect"] = list(run.no_effect)
        ran = run.results["config"]
        own = []
        for o in run.no_effect:  # a field the evaluation reads, given the run's own value
            (section, key), given = parse_override(o)
            fields = ran.get(section) if isinstance(ran.get(section), dict) else {}
            if key in fields and fields[key] == given:
                own.append(o)
        if own:
            value["own_values"] = own
    return value
