"""Registries of simulators and search algorithms (gymnax style): a name -> how to build it.

A simulator is one module: the environment (``cognet_jax.envs.base.Environment``), a dataclass
for its ``[env]`` config section (every field a setting with its default; an optional
``check(config)`` method raising ``ConfigError`` names bad values) and one call::

    register_env("my-sim", MySection, build=lambda section, config: (env, env_params))

after which ``make_env("my-sim", **settings)``, ``make_algorithm(name, env, env_params)``,
``load_config`` / TOML files with ``env.name = "my-sim"`` and ``sweep.run_sweep`` know it in
the process that registered it (the ``cognet-jax`` command line knows the built-in ones). An
algorithm is registered the same way with ``register_algorithm(name, section, build)``,
``build(config, env, env_params) -> algorithm``. The built-in entries are registered by their
own modules, imported on first lookup (``BUILTIN_ENVS`` / ``BUILTIN_ALGORITHMS``), so reading a
config loads only what it names; they never replace an entry registered before them.
"""

from __future__ import annotations

import dataclasses
import importlib
from collections.abc import Callable, Mapping
from typing import Any

#: built-in simulator name -> the module that registers it
BUILTIN_ENVS = {
    "tagging": "cognet_jax.envs.tagging",
    "heatmap": "cognet_jax.envs.heatmap",
    "dpomdp": "cognet_jax.envs.tabular",
}
#: built-in algorithm name -> the module that registers it
BUILTIN_ALGORITHMS = {
    "cognet-dice": "cognet_jax.algorithms.cognet_weights",
    "cognet-dice-thesis": "cognet_jax.algorithms.cognet_dice",
    "gdice": "cognet_jax.algorithms.gdice",
    "cogdice": "cognet_jax.algorithms.cogdice",
}


@dataclasses.dataclass(frozen=True)
class EnvEntry:
    """A registered simulator.

    ``section``: the ``[env]`` dataclass (its ``name`` field defaults to the registered name).
    ``build(section, config) -> (env, env_params)``. ``dynamic``: section fields that only
    change the params pytree, so a sweep runs settings differing in them in one compiled
    program. ``references``: known values shown in plots, ``{setting: {label: value}}`` with
    the setting read from the section field ``reference_field``.
    """

    name: str
    section: type
    build: Callable[[Any, Any], tuple[Any, Any]]
    dynamic: tuple[str, ...] = ()
    references: Mapping[str, Mapping[str, float]] = dataclasses.field(default_factory=dict)
    reference_field: str = ""


@dataclasses.dataclass(frozen=True)
class AlgorithmEntry:
    """A registered search algorithm: ``section`` is the ``[algorithm]`` dataclass,
    ``build(config, env, env_params) -> algorithm``; ``dynamic``: dotted config fields
    (``"algorithm.alpha"``, ``"network.learning_rate"``) that are hyper-parameters (sweepable
    in one program); ``discrete``: the algorithm needs discrete observations (simulators that
    can discretise, e.g. tagging, then return indices)."""

    name: str
    section: type
    build: Callable[[Any, Any, Any], Any]
    dynamic: tuple[str, ...] = ()
    discrete: bool = False


_ENVS: dict[str, EnvEntry] = {}
_ALGORITHMS: dict[str, AlgorithmEntry] = {}


def register_env(
    name: str,
    section: type,
    build: Callable[[Any, Any], tuple[Any, Any]],
    dynamic: tuple[str, ...] = (),
    references: Mapping[str, Mapping[str, float]] | None = None,
    reference_field: str = "",
    overwrite: bool = True,
) -> EnvEntry:
    """Register (or, with ``overwrite``, replace) the simulator ``name``; returns its entry.
    ``dynamic``: fields of ``section`` (bare names) that only change the params pytree. A
    ``check(config)`` method of the section, if any, validates it (``ConfigError``)."""
    if not overwrite and name in _ENVS:
        return _ENVS[name]
    _check_section(section, name, "env")
    if "name" not in {f.name for f in dataclasses.fields(section)}:
        raise TypeError(f"register env {name!r}: section needs a field `name: str = {name!r}`")
    entry = EnvEntry(name, section, build, tuple(dynamic), dict(references or {}), reference_field)
    _ENVS[name] = entry
    return entry


def register_algorithm(
    name: str,
    section: type,
    build: Callable[[Any, Any, Any], Any],
    dynamic: tuple[str, ...] = (),
    discrete: bool = False,
    overwrite: bool = True,
) -> AlgorithmEntry:
    """Register (or, with ``overwrite``, replace) the algorithm ``name``; returns its entry.
    ``dynamic``: dotted config fields (``"algorithm.alpha"``)."""
    if not overwrite and name in _ALGORITHMS:
        return _ALGORITHMS[name]
    _check_section(section, name, "algorithm")
    for field in dynamic:
        if field.count(".") != 1:
            raise TypeError(
                f"register algorithm {name!r}: dynamic field {field!r} must be 'section.key'"
            )
    entry = AlgorithmEntry(name, section, build, tuple(dynamic), discrete)
    _ALGORITHMS[name] = entry
    return entry


def _check_section(section: type, name: str, kind: str) -> None:
    if not dataclasses.is_dataclass(section):
        raise TypeError(f"register {kind} {name!r}: section must be a dataclass, got {section!r}")
    for f in dataclasses.fields(section):
        if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise TypeError(f"register {kind} {name!r}: section field {f.name!r} needs a default")


def _lookup(name: str, table: dict, builtin: dict, kind: str):
    if name not in table and name in builtin:
        importlib.import_module(builtin[name])
    if name not in table:
        from cognet_jax.config import ConfigError

        field = "env.name" if kind == "environment" else "experiment.algorithm"
        known = ", ".join(sorted(set(table) | set(builtin)))
        raise ConfigError(field, f"unknown {kind} {name!r} (known: {known})")
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


def make_env(name: str, algorithm: str = "cognet-dice", **settings):
    """``(env, env_params)`` of simulator ``name`` with ``settings`` (fields of its ``[env]``
    section; for ``"dpomdp"`` also of ``[problem]``: ``path``, ``horizon``, ``discount``),
    validated as a config file is, for the search ``algorithm`` (e.g. ``"gdice"`` makes
    tagging with ``obs_division > 0`` return observation indices, as G-DICE needs)."""
    from cognet_jax.api import build_env
    from cognet_jax.config import ConfigError, ProblemSection, config_from_dict

    entry = env_entry(name)
    env_fields = {f.name for f in dataclasses.fields(entry.section)}
    problem_fields = {f.name for f in dataclasses.fields(ProblemSection)}
    data: dict = {"experiment": {"algorithm": algorithm}, "env": {"name": name}, "problem": {}}
    for key, value in settings.items():
        if key in env_fields and key != "name":
            data["env"][key] = value
        elif name == "dpomdp" and key in problem_fields:
            data["problem"][key] = value
        else:
            extra = problem_fields if name == "dpomdp" else set()
            known = sorted((env_fields - {"name"}) | extra)
            raise ConfigError(f"env.{key}", f"unknown setting of {name!r} (known: {known})")
    return build_env(config_from_dict(data))


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


@dataclasses.dataclass
class ExternalEnvSection:
    """The ``[env]`` of a config whose simulator is passed as an object (``make_algorithm``)."""

    name: str = "external"


def make_algorithm(name: str, env, env_params, network: dict | None = None, **settings):
    """The search ``name`` on a simulator object ``env`` (any ``envs.base.Environment``, e.g.
    your own) with ``settings`` (fields of its ``[algorithm]`` section) and ``network`` (fields
    of ``[network]``), validated as a config file is: the object the CLI runs (``init(key)``,
    ``step(key, state)``, ``best_policy(state)``, ``policy_returns``; ``ask`` / ``tell`` for
    the searches of ``algorithms.engine``)."""
    from cognet_jax.api import build_algorithm
    from cognet_jax.config import (
        Config,
        ExperimentSection,
        NetworkSection,
        section_from_dict,
        validate,
    )

    entry = algorithm_entry(name)
    config = Config(
        experiment=ExperimentSection(name=name, algorithm=name),
        env=ExternalEnvSection(),
        algorithm=section_from_dict(entry.section, settings, "algorithm"),
        network=section_from_dict(NetworkSection, network or {}, "network"),
    )
    validate(config)
    return build_algorithm(config, env, env_params)
