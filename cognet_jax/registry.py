"""Registries of simulators and search algorithms (gymnax style), and reading a whole
configuration through them.

A simulator is one module: the environment (``cognet_jax.envs.base.Environment``), a dataclass
for its ``[env]`` config section (every field a setting with its default; a ``check(config)``
method raising ``ConfigError`` names bad values) and one call::

    register_env("my-sim", MySection, build=lambda section, config: (env, env_params))

An algorithm is one module too: its ``[algorithm]`` section (with ``check``) and::

    register_algorithm("my-search", MySection, build, hyper)

``build(config, env, env_params, memory) -> algorithm`` makes the immutable search object (the
protocol of ``algorithms.engine``, with what the driver reads: ``state.progress``, the
``SearchMetrics`` fields, ``rollouts_per_iteration``) and ``hyper(config) -> pytree`` reads its
dynamic hyper-parameters (``cognet_jax.api``). After
registration ``load_config`` / TOML files with ``env.name = "my-sim"`` or ``experiment.algorithm
= "my-search"``, ``api.make_env``, ``api.make_algorithm``, ``cognet-jax train --import`` and
sweeps know them; nothing in ``config.py`` or ``api.py`` names them. The built-in entries are
registered by their own modules, imported on first lookup (``BUILTIN_ENVS`` /
``BUILTIN_ALGORITHMS``), so reading a config loads only what it names; they never replace an
entry registered before them.

``load_config(name_or_path, overrides)``: read a built-in experiment or a TOML file, apply
``--set`` overrides, pick the ``[env]`` and ``[algorithm]`` dataclasses from the entries, and
validate (``validate``): every section's own ``check``, finite numbers, and no setting in a
section that neither the simulator nor the algorithm reads (``reads``).
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib
import json
import warnings
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from cognet_jax.config import (
    OPTIONAL_SECTIONS,
    Config,
    ConfigError,
    EvaluationSection,
    ExperimentSection,
    RunSection,
    apply_overrides,
    check_finite,
    check_known_sections,
    read_experiment,
    section_from_dict,
)
from cognet_jax.envs.base import build_from_fields, check_simulator
from cognet_jax.envs.base import dynamic_fields as params_fields
from cognet_jax.errors import ConfigWarning, OneLineWarning

#: built-in simulator name -> the module that registers it
BUILTIN_ENVS = {
    "tagging": "cognet_jax.envs.tagging",
    "heatmap": "cognet_jax.envs.heatmap",
    "dpomdp": "cognet_jax.envs.tabular",
    "hearing-tiger": "cognet_jax.envs.hearing_tiger",
    "beacon": "cognet_jax.envs.beacon",
    "bearing-chase": "cognet_jax.envs.bearing_chase",
    "plume": "cognet_jax.envs.plume",
    "box-push": "cognet_jax.envs.box_push",
}
#: built-in algorithm name -> the module that registers it
BUILTIN_ALGORITHMS = {
    "cognet-dice": "cognet_jax.algorithms.cognet_weights_entry",
    "cognet-dice-thesis": "cognet_jax.algorithms.cognet_thesis",
    "gdice": "cognet_jax.algorithms.gdice",
    "cogdice": "cognet_jax.algorithms.cogdice",
}


@dataclasses.dataclass(frozen=True)
class EnvEntry:
    """A registered simulator.

    ``section``: the ``[env]`` dataclass (its ``name`` field defaults to the registered name).
    ``build(section, config) -> (env, env_params)``. ``dynamic``: section fields that only
    change the params pytree, so a sweep runs settings differing in them in one compiled
    program. ``reads``: the optional config sections it reads (``"problem"``). ``references``:
    known values shown in plots, ``{setting: {label: value}}`` with the setting read from the
    section field ``reference_field``.
    """

    name: str
    section: type
    build: Callable[[Any, Any], tuple[Any, Any]]
    dynamic: tuple[str, ...] = ()
    reads: tuple[str, ...] = ()
    references: Mapping[str, Mapping[str, float]] = dataclasses.field(default_factory=dict)
    reference_field: str = ""


@dataclasses.dataclass(frozen=True)
class AlgorithmEntry:
    """A registered search algorithm: ``section`` is the ``[algorithm]`` dataclass,
    ``build(config, env, env_params, memory) -> algorithm`` (``memory``: bytes its rollouts in
    flight may take, ``None`` for half the machine), ``hyper(config) -> pytree`` its dynamic
    hyper-parameters; ``dynamic``: dotted config fields (``"algorithm.alpha"``,
    ``"network.learning_rate"``) that are hyper-parameters (sweepable in one program);
    ``discrete``: the algorithm needs discrete observations (simulators that can discretise,
    e.g. tagging, then return indices); ``reads``: the optional sections it reads
    (``"network"``); ``resolve(config, env, env_params) -> section``: the ``[algorithm]``
    section with its ``"auto"`` settings replaced by numbers read from the simulator (its
    sizes, or a measurement on it; ``load_config`` calls it, so a run's results.json holds the
    numbers it ran with)."""

    name: str
    section: type
    build: Callable[[Any, Any, Any, Any], Any]
    hyper: Callable[[Any], Any]
    dynamic: tuple[str, ...] = ()
    discrete: bool = False
    reads: tuple[str, ...] = ()
    resolve: Callable[[Any, Any, Any], Any] | None = None


_ENVS: dict[str, EnvEntry] = {}
_ALGORITHMS: dict[str, AlgorithmEntry] = {}
#: modules imported from outside the package (``--import``): file name -> SHA-256 of its bytes
_FOREIGN_CODE: dict[str, str] = {}
#: of those, the ones a user module imported after its own import (``LATE_IMPORTS``)
_LATE_CODE: dict[str, str] = {}


def note_foreign_code(name: str, origin: str | None, late: bool = False) -> None:
    """Record that the module ``name`` (file ``origin``) was imported from outside the package:
    its code may change any simulator or algorithm, so no program of this process is kept
    between processes, and policies record its digest (``foreign_code``)."""
    digest = ""
    if origin:
        try:
            digest = hashlib.sha256(Path(origin).read_bytes()).hexdigest()[:16]
        except OSError:
            pass
    key = Path(origin).name if origin else name
    if late and key not in _FOREIGN_CODE:
        _LATE_CODE[key] = digest
    else:
        _FOREIGN_CODE[key] = digest


#: called by ``foreign_code`` first: note the user modules imported since (``plugins``: the
#: helpers a user module imports only when its simulator is built or traced)
LATE_IMPORTS: list[Callable[[], None]] = []


def foreign_code(late: bool = True) -> dict[str, str]:
    """Modules imported from outside the package, with their digests (``note_foreign_code``);
    with ``late``, also those a user module imported after its own import (``LATE_IMPORTS``:
    a helper imported when the simulator is built or traced)."""
    for note_late in LATE_IMPORTS:
        note_late()
    return {**_FOREIGN_CODE, **_LATE_CODE} if late else dict(_FOREIGN_CODE)


def late_code() -> dict[str, str]:
    """The modules of ``foreign_code`` that were imported late, with their digests."""
    foreign_code()
    return dict(_LATE_CODE)


def is_builtin(entry: EnvEntry | AlgorithmEntry) -> bool:
    """Whether ``entry`` is the package's own entry of its name (not a user's registration of
    a built-in name, which ``--import`` may make first)."""
    table = BUILTIN_ENVS if isinstance(entry, EnvEntry) else BUILTIN_ALGORITHMS
    return getattr(entry.build, "__module__", None) == table.get(entry.name)


def _no_hyper(config) -> None:
    return None


def register_env(
    name: str,
    section: type,
    build: Callable[[Any, Any], tuple[Any, Any]],
    dynamic: tuple[str, ...] = (),
    reads: tuple[str, ...] = (),
    references: Mapping[str, Mapping[str, float]] | None = None,
    reference_field: str = "",
    overwrite: bool = True,
) -> EnvEntry:
    """Register (or, with ``overwrite``, replace) the simulator ``name``; returns its entry.
    ``dynamic``: fields of ``section`` (bare names) that only change the params pytree."""
    if not overwrite and name in _ENVS:
        return _ENVS[name]
    _check_section(section, name, "env")
    if "name" not in {f.name for f in dataclasses.fields(section)}:
        raise TypeError(f"register env {name!r}: section needs a field `name: str = {name!r}`")
    _check_reads(reads, name, "env")
    entry = EnvEntry(
        name, section, build, tuple(dynamic), tuple(reads), dict(references or {}), reference_field
    )
    _warn_if_replaced(_ENVS.get(name), entry, "simulator")
    _ENVS[name] = entry
    return entry


#: ``(kind, name) -> module`` of the registrations made since ``begin_command`` (the modules
#: of one command's ``--import``s)
_REGISTERED_NOW: dict[tuple[str, str], str] = {}


def begin_command() -> None:
    """Start a command's record of registrations (``_warn_if_replaced``)."""
    _REGISTERED_NOW.clear()


def _warn_if_replaced(old, new, kind: str) -> None:
    """One line when a registration replaces one another module made in the same command
    (two ``--import`` files registering one name): the last one wins, which a user who
    imported both rarely means. A module registering its own name again stays silent."""
    module = new.build.__module__
    was = _REGISTERED_NOW.get((kind, new.name))
    _REGISTERED_NOW[(kind, new.name)] = module
    if old is not None and was is not None and was != module:
        warnings.warn(
            f"{kind} {new.name!r} registered by {was} is replaced by the one of {module}",
            OneLineWarning,
            stacklevel=3,
        )


def register_fields_env(name: str, section: type, env_cls: type, params_cls: type) -> EnvEntry:
    """Register the simulator ``name`` whose ``[env]`` fields are named as the fields of the
    static ``env_cls`` (shapes) or of the ``params_cls`` pytree (every tunable number, the
    dynamic fields): built by ``envs.base.build_from_fields``; never replaces an entry."""

    def build(values, config):
        return build_from_fields(env_cls, params_cls, values)

    build.__module__ = env_cls.__module__  # whose simulator it is (``is_builtin``)
    build.__qualname__ = f"{env_cls.__qualname__}.build_from_section"
    return register_env(name, section, build, dynamic=params_fields(params_cls), overwrite=False)


def register_algorithm(
    name: str,
    section: type,
    build: Callable[[Any, Any, Any, Any], Any],
    hyper: Callable[[Any], Any] = _no_hyper,
    dynamic: tuple[str, ...] = (),
    discrete: bool = False,
    reads: tuple[str, ...] = (),
    overwrite: bool = True,
    resolve: Callable[[Any, Any, Any], Any] | None = None,
) -> AlgorithmEntry:
    """Register (or, with ``overwrite``, replace) the algorithm ``name``; returns its entry.
    ``dynamic``: dotted config fields (``"algorithm.alpha"``) read by ``hyper``."""
    if not overwrite and name in _ALGORITHMS:
        return _ALGORITHMS[name]
    _check_section(section, name, "algorithm")
    _check_reads(reads, name, "algorithm")
    for field in dynamic:
        if field.count(".") != 1:
            raise TypeError(
                f"register algorithm {name!r}: dynamic field {field!r} must be 'section.key'"
            )
    entry = AlgorithmEntry(
        name, section, build, hyper, tuple(dynamic), discrete, tuple(reads), resolve
    )
    _warn_if_replaced(_ALGORITHMS.get(name), entry, "algorithm")
    _ALGORITHMS[name] = entry
    return entry


def _check_section(section: type, name: str, kind: str) -> None:
    if not isinstance(name, str) or not name.strip() or name != name.strip():
        raise TypeError(f"register {kind} {name!r}: the name must be a non-empty string")
    if not dataclasses.is_dataclass(section):
        raise TypeError(f"register {kind} {name!r}: section must be a dataclass, got {section!r}")
    for f in dataclasses.fields(section):
        if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise TypeError(f"register {kind} {name!r}: section field {f.name!r} needs a default")


def _check_reads(reads: tuple[str, ...], name: str, kind: str) -> None:
    unknown = [r for r in reads if r not in OPTIONAL_SECTIONS]
    if unknown:
        raise TypeError(
            f"register {kind} {name!r}: reads {unknown}; optional sections are "
            f"{sorted(OPTIONAL_SECTIONS)}"
        )


def _lookup(name: str, table: dict, builtin: dict, kind: str):
    if name not in table and name in builtin:
        importlib.import_module(builtin[name])
    if name not in table:
        field = "env.name" if kind == "environment" else "experiment.algorithm"
        known = ", ".join(sorted(set(table) | set(builtin)))
        raise ConfigError(
            field,
            f"unknown {kind} {name!r} (known: {known}; one of your own is registered by its "
            "module: `cognet-jax --import MODULE.py ...`)",
        )
    return table[name]


def env_entry(name: str) -> EnvEntry:
    """The entry of simulator ``name`` (``ConfigError`` on ``env.name`` if unknown)."""
    return _lookup(name, _ENVS, BUILTIN_ENVS, "environment")


def algorithm_entry(name: str) -> AlgorithmEntry:
    """The entry of algorithm ``name`` (``ConfigError`` on ``experiment.algorithm``)."""
    return _lookup(name, _ALGORITHMS, BUILTIN_ALGORITHMS, "algorithm")


def list_envs() -> list[str]:
    """Names of every simulator: built-in and registered."""
    return sorted(set(_ENVS) | set(BUILTIN_ENVS))


def list_algorithms() -> list[str]:
    """Names of every algorithm: built-in and registered."""
    return sorted(set(_ALGORITHMS) | set(BUILTIN_ALGORITHMS))


def dynamic_fields(config: Config) -> frozenset[str]:
    """Dotted config fields that only change the hyper-parameters or the env params pytree
    (the entries' ``dynamic``), so settings differing in them share one compiled program."""
    env = env_entry(config.env.name).dynamic
    return frozenset(algorithm_entry(config.experiment.algorithm).dynamic) | {
        f"env.{name}" for name in env
    }


def fields_from(cls: type, *sources: Any, **given: Any):
    """``cls(**kwargs)`` with every field of the dataclass ``cls`` taken from ``given`` or else
    from the first of ``sources`` (config sections) that has an attribute of that name: an
    algorithm's settings read from its config sections without a field-by-field copy. A field
    found nowhere is a ``TypeError`` (a setting the config does not declare)."""
    kwargs = {}
    for f in dataclasses.fields(cls):
        if f.name in given:
            kwargs[f.name] = given[f.name]
            continue
        for source in sources:
            if hasattr(source, f.name):
                kwargs[f.name] = getattr(source, f.name)
                break
        else:
            raise TypeError(f"{cls.__name__}.{f.name}: no config field of that name")
    return cls(**kwargs)


# --------------------------------------------------------------------------------------------
# a whole configuration
# --------------------------------------------------------------------------------------------
def validate(config: Config, env_reads: tuple[str, ...] | None = None) -> None:
    """Range and consistency checks of every section; raises ``ConfigError`` naming the field.
    Each section checks itself (``check(config)``); an optional section that neither the
    simulator nor the algorithm reads must keep its defaults. ``env_reads``: the simulator's
    ``reads`` when it is an object rather than a registered entry (``api.make_algorithm``)."""
    check_finite(config)
    for name in ("experiment", "env", "algorithm", "evaluation", "run"):
        check = getattr(getattr(config, name), "check", None)
        if callable(check):
            check(config)
    if env_reads is None:
        env_reads = env_entry(config.env.name).reads
    reads = set(env_reads) | set(algorithm_entry(config.experiment.algorithm).reads)
    for name, cls in OPTIONAL_SECTIONS.items():
        if name in reads:
            continue
        given, default = getattr(config, name), cls()
        for f in dataclasses.fields(cls):
            if getattr(given, f.name) != getattr(default, f.name):
                raise ConfigError(
                    f"{name}.{f.name}",
                    f"the simulator {config.env.name!r} and the algorithm "
                    f"{config.experiment.algorithm!r} read no [{name}] section",
                )


def config_from_dict(data: dict) -> Config:
    """Build and validate a ``Config`` from nested dicts (as read from TOML)."""
    if not isinstance(data, dict):
        raise ConfigError("", f"expected a table of sections, got {type(data).__name__}")
    check_known_sections(data)
    experiment = section_from_dict(ExperimentSection, data.get("experiment", {}), "experiment")
    env_data = data.get("env", {})
    if not isinstance(env_data, dict):
        raise ConfigError("env", f"expected a table of settings, got {env_data!r}")
    env_name = env_data.get("name", "tagging")
    if not isinstance(env_name, str):
        raise ConfigError("env.name", f"expected a simulator name, got {env_name!r}")
    env_section = env_entry(env_name).section
    algorithm_section = algorithm_entry(experiment.algorithm).section
    optional = {
        name: section_from_dict(cls, data.get(name, {}), name)
        for name, cls in OPTIONAL_SECTIONS.items()
    }
    config = Config(
        experiment=experiment,
        env=section_from_dict(env_section, env_data, "env"),
        algorithm=section_from_dict(algorithm_section, data.get("algorithm", {}), "algorithm"),
        evaluation=section_from_dict(EvaluationSection, data.get("evaluation", {}), "evaluation"),
        run=section_from_dict(RunSection, data.get("run", {}), "run"),
        **optional,
    )
    validate(config)
    resolve = algorithm_entry(experiment.algorithm).resolve
    if resolve is not None:  # the simulator checked before a resolve runs it (noise pilot)
        env, env_params = build_env(config)
        builtin = is_builtin(env_entry(env_name))
        check_simulator(env, env_params, env_name, values=not builtin)
        config = dataclasses.replace(config, algorithm=resolve(config, env, env_params))
        validate(config)
    return config


def build_env(config: Config):
    """``(env, env_params)`` described by ``config.env`` (and, for a model file,
    ``config.problem``), built by the simulator's registry entry once per description: a
    later call with the same config (its ``[algorithm]``, ``[evaluation]`` and ``[run]``
    sections aside, which a simulator is not built from; the search's kind in
    ``[experiment]`` counts: tagging's observations depend on it), the same registered builder
    and the same model file returns the same objects (immutable: a frozen env, a params pytree
    of arrays)."""
    entry = env_entry(config.env.name)
    key = _env_key(config, entry)
    if key not in _BUILT_ENVS:
        if len(_BUILT_ENVS) >= _BUILT_ENVS_MAX:
            _BUILT_ENVS.pop(next(iter(_BUILT_ENVS)))
        _BUILT_ENVS[key] = entry.build(config.env, config)
    return _BUILT_ENVS[key]


#: simulators built by ``build_env``, by ``_env_key`` (the most recent ``_BUILT_ENVS_MAX``)
_BUILT_ENVS: dict = {}
_BUILT_ENVS_MAX = 4


def env_description(config: Config) -> str:
    """A text that differs between configs whose simulators differ (``build_env``'s key): for
    measurements on a simulator kept by what it was built from."""
    entry = env_entry(config.env.name)
    builder, shown = _env_key(config, entry)
    return f"{builder.__module__}.{builder.__qualname__}:{id(builder)}:{shown}"


def _env_key(config: Config, entry) -> tuple:
    """What a simulator is built from: its registered builder, the config without its
    ``[algorithm]``, ``[evaluation]`` and ``[run]`` sections (sizes resolved from the simulator
    must not make a second build) and, when it reads ``[problem]``, the model file's size and
    mtime."""
    skipped = ("algorithm", "evaluation", "run")
    shown = {k: v for k, v in config.to_dict().items() if k not in skipped}
    sections = [shown, dataclasses.asdict(config.env)]
    if "problem" in entry.reads:
        sections.append(dataclasses.asdict(config.problem))
        path = Path(config.problem.path).expanduser() if config.problem.path else None
        try:
            stat = path.stat() if path is not None else None
            sections.append([str(path.resolve()), stat.st_size, stat.st_mtime_ns] if stat else "")
        except OSError:
            sections.append("missing")
    return (entry.build, json.dumps(sections, sort_keys=True, default=repr))


def load_config(name_or_path: str, overrides: list[str] | None = None) -> Config:
    """Read an experiment (built-in name or TOML file), apply ``--set`` overrides, validate;
    a setting the user gave to no effect (the algorithm section's ``given_warnings``) is a
    ``ConfigWarning``."""
    data = apply_overrides(read_experiment(name_or_path), overrides or [])
    try:
        config = config_from_dict(data)
    except ConfigError as err:
        name = (data.get("experiment") or {}).get("name")
        if err.field == "experiment.name" and name == Path(name_or_path).stem != name_or_path:
            said = str(err).split(": ", 1)[-1]
            raise ConfigError(  # the file set none: its name did
                err.field,
                f"{said}; {Path(name_or_path).name} sets no experiment.name, so its file name "
                "gives it: set experiment.name in the file or with --set",
            ) from None
        raise
    given = data.get("algorithm", {})
    for text in getattr(config.algorithm, "given_warnings", lambda _: [])(given):
        warnings.warn(ConfigWarning(text), stacklevel=2)
    return config
