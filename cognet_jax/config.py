"""The configuration schema: the sections every experiment has, TOML reading, ``--set
section.key=value`` overrides, typed fields and the helpers sections validate themselves with.

A configuration has the sections ``[experiment]``, ``[env]``, ``[problem]``, ``[algorithm]``,
``[network]``, ``[evaluation]`` and ``[run]``. This module knows no simulator and no algorithm:
which dataclass reads ``[env]`` (by ``env.name``) and which reads ``[algorithm]`` (by
``experiment.algorithm``) is the registry's business (``cognet_jax.registry.load_config``), and
each of those sections checks its own values (a ``check(config)`` method). Unknown keys, wrong
types and out-of-range values raise ``ConfigError`` naming the dotted field.
"""

from __future__ import annotations

import dataclasses
import math
import struct
import types
import typing
from importlib import resources
from pathlib import Path
from typing import Any, Literal

import tomllib

from cognet_jax.errors import InputError


class ConfigError(InputError):
    """A configuration problem; ``field`` is the dotted name (e.g. ``algorithm.nodes``)."""

    def __init__(self, field: str, message: str):
        self.field = field
        super().__init__(f"config field '{field}': {message}" if field else message)


# --------------------------------------------------------------------------------------------
# validation helpers (sections call them from their ``check`` methods)
# --------------------------------------------------------------------------------------------
def require(cond: bool, field: str, message: str) -> None:
    """``ConfigError(field, message)`` unless ``cond``."""
    if not cond:
        raise ConfigError(field, message)


def require_positive(section: Any, prefix: str, *names: str) -> None:
    """Each named field of ``section`` is ``None`` or ``>= 1`` (``prefix.name`` otherwise)."""
    for n in names:
        v = getattr(section, n)
        require(v is None or v >= 1, f"{prefix}.{n}", f"must be >= 1, got {v}")


def require_nonnegative(section: Any, prefix: str, *names: str) -> None:
    """Each named field of ``section`` is ``>= 0`` (``prefix.name`` otherwise)."""
    for n in names:
        v = getattr(section, n)
        require(v >= 0, f"{prefix}.{n}", f"must be >= 0, got {v}")


def require_discount(value: float | None, field: str) -> None:
    """A discount factor is in (0, 1] (``None``: the model's or setting's own)."""
    require(value is None or 0.0 < value <= 1.0, field, f"must be in (0, 1], got {value}")


def require_probability(section: Any, prefix: str, *names: str) -> None:
    """Each named field of ``section`` is in [0, 1]."""
    for n in names:
        v = getattr(section, n)
        require(0.0 <= v <= 1.0, f"{prefix}.{n}", f"must be in [0, 1], got {v}")


# --------------------------------------------------------------------------------------------
# the sections every experiment has
# --------------------------------------------------------------------------------------------
@dataclasses.dataclass
class ExperimentSection:
    """What the experiment is called (it names the run folder ``runs/NAME-seedS``), the search
    algorithm's registered name, and a line of description."""

    name: str = "custom"
    algorithm: str = "cognet-dice"
    description: str = ""

    def check(self, config: Config) -> None:
        name = self.name
        safe = name and not name.startswith(".") and not set(name) & set("/\\:\0")
        safe = safe and name.isprintable()  # a newline or tab would split the lines it is in
        require(
            bool(safe),
            "experiment.name",
            f"{name!r} is no folder name (it names runs/NAME-seedS): a name must not be empty, "
            "start with '.' or hold '/', '\\', ':', NUL or characters that do not print",
        )
        size = len(name.encode("utf-8", "surrogatepass"))
        require(
            size <= MAX_NAME_BYTES,
            "experiment.name",
            f"is {size} bytes long, at most {MAX_NAME_BYTES} (it names the folder "
            "runs/NAME-seedS, and a file name holds at most 255 bytes)",
        )


#: the longest ``experiment.name`` (bytes): ``NAME-seedS`` with a seed of 10 digits then fits
#: the 255 bytes of a file name
MAX_NAME_BYTES = 240


@dataclasses.dataclass
class ProblemSection:
    """A model file (read by the simulators that declare it, e.g. ``env.name = "dpomdp"``)."""

    path: str = ""
    horizon: int = 3
    discount: float | None = None


@dataclasses.dataclass
class VaeFields:
    """The patch VAE of ``[network]`` (``cognet_jax.vae``): ``vae_path``, a VAE file from
    ``cognet-jax vae train``; empty: trained on demand from ``vae_seed`` with ``vae_epochs``
    epochs, ``vae_latent`` latent dimensions and KL weight ``vae_kl_weight`` (and saved in the
    run folder)."""

    vae_path: str = ""
    vae_seed: int = 0
    vae_epochs: int = 60
    vae_latent: int = 1
    vae_kl_weight: float = 1.0


@dataclasses.dataclass
class NetworkSection(VaeFields):
    """Node networks of COGNet-DICE and what they read (``cognet_jax.observations``; read by the
    algorithms that declare it): ``hidden`` units; the thesis algorithm's optimiser
    (``optimizer``, ``learning_rate``, ``momentum``, ``train_steps``); ``observation``:
    ``"raw"`` (the environment's observation) or ``"encoded"`` (a VAE's encoder mean, ``VaeFields``:
    the heatmap's patch VAE, or one trained on any other simulator's own observations,
    ``observations.simulator_vae``); ``augment``: add ``augment_samples`` VAE-sampled training pairs
    per pair (SPEC section 6).
    """

    hidden: int = 10
    optimizer: Literal["adam", "sgd"] = "adam"
    learning_rate: float = 0.01
    momentum: float = 0.5
    train_steps: int = 20
    observation: Literal["raw", "encoded"] = "raw"
    augment: bool = False
    augment_samples: int = 1


@dataclasses.dataclass
class EvaluationSection:
    """Honest final evaluation of the best policy (the seed's evaluation key)."""

    rollouts: int = 10_000
    batch: int = 10_000

    def check(self, config: Config) -> None:
        require_positive(self, "evaluation", "rollouts", "batch")
        require(self.rollouts >= 2, "evaluation.rollouts", "needs >= 2 for a std error")


@dataclasses.dataclass
class RunSection:
    """How a run is driven (``cognet_jax.driver``); only ``prng_impl`` changes a result (it
    picks the random number generator)."""

    #: "threefry2x32" (default), "rbg", "unsafe_rbg", or "hash": the counter-based generator
    #: of ``cognet_jax.prng`` (faster rollouts on CPU than threefry, benchmarks/README.md;
    #: other numbers)
    prng_impl: Literal["threefry2x32", "rbg", "unsafe_rbg", "hash"] = "threefry2x32"
    progress: bool = True
    plots: bool = True
    #: write the full search state every K iterations (0: not by iterations)
    checkpoint_every: int = 0
    #: write the full search state after every S seconds of search (0: not by time); a
    #: SIGKILL then loses at most S seconds
    checkpoint_seconds: float = 60.0
    #: lay every batch of rollouts (and the candidates' evaluations) over all local devices
    #: (``compiled.rollout_mesh``); for hosts with several accelerators -- on a CPU split into
    #: devices it is slower than one device (benchmarks/NOTES.md)
    shard_rollouts: bool = False
    #: GB the rollouts in flight may take (0: half of this machine's memory); candidates are
    #: evaluated in chunks to stay within it (``cognet_jax.memory``), and a program whose
    #: single array exceeds it is refused before compiling
    memory_gb: float = 0.0
    #: keep the anytime best every S seconds of the run (0: never); after the search each kept
    #: policy gets the honest evaluation, so results.json's ``probes`` tell when the best first
    #: reached a value, by fresh evaluations rather than the in-loop maximum
    probe_seconds: float = 0.0

    def check(self, config: Config) -> None:
        require(
            self.probe_seconds >= 0,
            "run.probe_seconds",
            f"must be >= 0, got {self.probe_seconds}",
        )
        require(
            self.checkpoint_every >= 0,
            "run.checkpoint_every",
            f"must be >= 0, got {self.checkpoint_every}",
        )
        require(
            self.checkpoint_seconds >= 0,
            "run.checkpoint_seconds",
            f"must be >= 0, got {self.checkpoint_seconds}",
        )
        require(
            self.memory_gb == 0 or self.memory_gb >= MIN_MEMORY_GB,
            "run.memory_gb",
            f"0 (half of this machine's memory) or at least {MIN_MEMORY_GB} GB, got "
            f"{self.memory_gb}",
        )


#: the smallest ``run.memory_gb`` (1 MB): below it no program fits, and the budget's bytes
#: round to nothing in the messages that name it
MIN_MEMORY_GB = 0.001


@dataclasses.dataclass
class Config:
    """A whole experiment. ``env`` and ``algorithm`` are the registered sections of the
    simulator and the search (``cognet_jax.registry``); build one with ``load_config``."""

    experiment: ExperimentSection
    env: Any
    algorithm: Any
    problem: ProblemSection = dataclasses.field(default_factory=ProblemSection)
    network: NetworkSection = dataclasses.field(default_factory=NetworkSection)
    evaluation: EvaluationSection = dataclasses.field(default_factory=EvaluationSection)
    run: RunSection = dataclasses.field(default_factory=RunSection)

    #: the sections in the order a TOML file and ``to_dict`` list them
    SECTIONS: typing.ClassVar[tuple[str, ...]] = (
        "experiment",
        "env",
        "problem",
        "algorithm",
        "network",
        "evaluation",
        "run",
    )

    def to_dict(self) -> dict:
        return {name: dataclasses.asdict(getattr(self, name)) for name in self.SECTIONS}

    def input_files(self) -> list[str]:
        """The files the run reads: every non-empty field named ``path`` or ``*_path`` of any
        section (a model, a VAE), as written. A simulator or algorithm that reads a file names
        its field so; the programs kept are keyed by those files' bytes."""
        return [
            value
            for section in self.to_dict().values()
            for name, value in section.items()
            if (name == "path" or name.endswith("_path")) and isinstance(value, str) and value
        ]


#: sections that only a simulator or an algorithm that declares them reads (registry ``reads``)
OPTIONAL_SECTIONS = {"problem": ProblemSection, "network": NetworkSection}


def settings_class(
    name: str, section: type, exclude: tuple[str, ...] = (), extra: tuple = (), doc: str = ""
) -> type:
    """A frozen dataclass ``name`` with the fields (names, types, defaults) of the config
    dataclass ``section`` minus ``exclude``, then ``extra`` fields taken from other sections,
    each ``(section_class, field_name)``: an algorithm's static settings, declared once in its
    config section (the dynamic hyper-parameters are excluded and live in its hyper pytree)."""
    fields = []
    sources = [(section, f.name) for f in dataclasses.fields(section) if f.name not in exclude]
    for cls, field_name in [*sources, *extra]:
        f = next(f for f in dataclasses.fields(cls) if f.name == field_name)
        fields.append((f.name, f.type, dataclasses.field(default=f.default)))
    namespace = {"__doc__": doc or f"Static settings: the fields of ``{section.__name__}``."}
    return dataclasses.make_dataclass(name, fields, frozen=True, namespace=namespace)


# --------------------------------------------------------------------------------------------
# reading
# --------------------------------------------------------------------------------------------
def _type_name(annotation: Any) -> str:
    """``int``, ``'auto'`` (a ``Literal``'s choices), ... for error messages."""
    if typing.get_origin(annotation) is Literal:
        return " or ".join(repr(c) for c in typing.get_args(annotation))
    return getattr(annotation, "__name__", str(annotation))


def _check_type(field: str, value: Any, annotation: Any) -> Any:
    """Convert/validate one value against a simple annotation (int, float, bool, str, X|None,
    ``Literal[...]`` of strings, a union of them such as ``int | Literal["auto"]``)."""
    origin = typing.get_origin(annotation)
    if origin is Literal:
        choices = typing.get_args(annotation)
        if isinstance(value, str) and value in choices:
            return value
        names = ", ".join(repr(c) for c in choices)
        raise ConfigError(field, f"must be one of {names}, got {value!r}")
    if origin in (typing.Union, types.UnionType):
        options = typing.get_args(annotation)
        if value is None and type(None) in options:
            return None
        inner = [o for o in options if o is not type(None)]
        if len(inner) == 1:
            return _check_type(field, value, inner[0])
        for option in inner:  # e.g. ``int | Literal["auto"]``: the first that fits
            try:
                return _check_type(field, value, option)
            except ConfigError:
                pass
        names = " or ".join(_type_name(o) for o in inner)
        raise ConfigError(field, f"expected {names}, got {type(value).__name__} {value!r}")
    if annotation is bool:
        if isinstance(value, bool):
            return value
    elif annotation is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
    elif annotation is float:
        if isinstance(value, int | float) and not isinstance(value, bool):
            return float(value)
    elif annotation is str:
        if isinstance(value, str):
            return value
    else:  # pragma: no cover - only simple annotations are used
        return value
    raise ConfigError(
        field, f"expected {annotation.__name__}, got {type(value).__name__} {value!r}"
    )


def section_from_dict(cls: type, data: Any, prefix: str):
    """The dataclass ``cls`` from a dict of settings (``ConfigError`` naming ``prefix.key``)."""
    if not isinstance(data, dict):
        raise ConfigError(prefix, f"expected a table of settings, got {data!r}")
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    for key in data:
        if key not in names:
            raise ConfigError(f"{prefix}.{key}", f"unknown key (known: {', '.join(sorted(names))})")
    kwargs = {k: _check_type(f"{prefix}.{k}", v, hints[k]) for k, v in data.items()}
    return cls(**kwargs)


def check_known_sections(data: dict) -> None:
    """``ConfigError`` for a top-level key that is no section of ``Config``."""
    for key in data:
        if key not in Config.SECTIONS:
            raise ConfigError(key, f"unknown section (known: {', '.join(sorted(Config.SECTIONS))})")


#: the largest float32; the simulators and searches compute in float32
FLOAT32_MAX = 3.4028234663852886e38
#: the largest integer a size may take (array indices are int32)
INT32_MAX = 2**31 - 1
#: the largest magnitude of a simulator's number (``[env]``): its square must fit float32, as
#: the variances and standard errors of returns square what the simulator makes of it (an
#: observation noise of 3e38 made every observation inf, then every value NaN)
ENV_FLOAT_MAX = 1.8e19


def _f32(v: float) -> float:
    """``v`` rounded to float32 (``v`` within float32's range)."""
    return struct.unpack("f", struct.pack("f", v))[0]


def check_finite(config: Config) -> None:
    """Every number of every section is finite and fits the float32 / int32 arithmetic of the
    compiled programs: ``inf`` and ``nan`` parse as TOML floats but mean nothing as a noise
    level, rate, reward or size, and 1e308 would become ``inf`` in float32."""
    for name in Config.SECTIONS:
        values = getattr(config, name)
        for f in dataclasses.fields(values):
            v, field = getattr(values, f.name), f"{name}.{f.name}"
            if isinstance(v, float) and not math.isfinite(v):
                raise ConfigError(field, f"must be a finite number, got {v}")
            if isinstance(v, float) and abs(v) > FLOAT32_MAX:
                raise ConfigError(field, f"{v} does not fit float32 (|x| <= {FLOAT32_MAX:.3g})")
            if name in ("env", "problem") and isinstance(v, float) and v and not _f32(v):
                raise ConfigError(  # a discount of 1e-46 became 0 and was named as the model's
                    field,
                    f"{v:g} is 0 in the simulator's float32 arithmetic (0, or |x| >= 1.4e-45)",
                )
            if name == "env" and isinstance(v, (int, float)) and abs(v) > ENV_FLOAT_MAX:
                raise ConfigError(
                    field,
                    f"{v:g} overflows the simulator's float32 arithmetic (its square is inf); "
                    f"|x| <= {ENV_FLOAT_MAX:.2g}",
                )
            if isinstance(v, int) and not isinstance(v, bool) and abs(v) > INT32_MAX:
                raise ConfigError(field, f"{v} does not fit a 32-bit integer (<= {INT32_MAX})")


def parse_override(text: str) -> tuple[list[str], Any]:
    """``"section.key=value"`` -> (``["section", "key"]``, value). The value is read as a TOML
    literal (``3``, ``0.5``, ``true``, ``"x"``); anything else is taken as a plain string."""
    if "=" not in text:
        raise ConfigError(text, "an override must look like section.key=value")
    dotted, raw = text.split("=", 1)
    path = [p.strip() for p in dotted.strip().split(".")]
    if len(path) != 2 or not all(path):
        raise ConfigError(dotted.strip(), "an override names section.key (e.g. algorithm.nodes=6)")
    try:
        value = tomllib.loads(f"v = {raw.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw.strip()
    except RecursionError:  # arrays or tables nested thousands deep
        raise ConfigError(".".join(path), "the value is nested too deeply") from None
    return path, value


#: per algorithm, fields added after configs were written whose default changes the search they
#: were added to, with the value that keeps it: a stored config (a checkpoint's, a results.json)
#: that did not write one resumes and evaluates as it ran (``with_added_fields``)
ADDED_FIELDS = {
    "cognet-dice": {
        "algorithm": {
            "distinct_actions": False,
            "refine_redraw": 0.0,
            "kept_sharpness": 1.0,
            "polish_share": 0.0,
            "polish_axes": False,
            "polish_counter": False,
            "polish_extend": 1.0,
            "start_draw": False,
            "start_spread": 1.0,
        }
    }
}


def with_added_fields(data: dict) -> dict:
    """A copy of the stored raw config ``data`` with the ``ADDED_FIELDS`` of its algorithm that
    it does not hold set to the values it ran with."""
    algorithm = (data.get("experiment") or {}).get("algorithm", ExperimentSection.algorithm)
    data = {k: dict(v) if isinstance(v, dict) else v for k, v in data.items()}
    for section, fields in ADDED_FIELDS.get(algorithm, {}).items():
        if isinstance(data.get(section), dict):
            data[section] = {**fields, **data[section]}
    return data


def apply_overrides(data: dict, overrides: list[str]) -> dict:
    """A copy of the raw ``data`` with every ``section.key=value`` of ``overrides`` set."""
    data = {k: dict(v) if isinstance(v, dict) else v for k, v in data.items()}
    for text in overrides:
        (section, key), value = parse_override(text)
        if section in data and not isinstance(data[section], dict):
            raise ConfigError(section, "is not a section")
        data.setdefault(section, {})[key] = value
    return data


def builtin_experiments() -> list[str]:
    """Names of the experiments shipped with the package."""
    folder = resources.files("cognet_jax") / "experiments"
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def read_experiment(name_or_path: str) -> dict:
    """Raw dict of a built-in experiment (by name) or of a TOML file (by path)."""
    path = Path(name_or_path)
    if name_or_path.endswith(".toml") or path.exists():
        if not path.exists():
            raise ConfigError("", f"no such experiment file: {name_or_path}")
        if not path.is_file():
            raise ConfigError(
                "", f"{name_or_path}: not a regular file (an experiment is a TOML file)"
            )
        try:
            text = path.read_text(encoding="utf-8-sig")  # a byte-order mark (Notepad) is no TOML
        except UnicodeDecodeError as err:
            raise ConfigError("", f"{name_or_path}: not a UTF-8 TOML file ({err.reason})") from None
        if not text.strip():
            raise ConfigError("", f"{name_or_path}: empty experiment file (no settings)")
        origin = str(path)
    else:
        res = resources.files("cognet_jax") / "experiments" / f"{name_or_path}.toml"
        if not res.is_file():
            raise ConfigError(
                "",
                f"unknown experiment {name_or_path!r}; built-in experiments: "
                f"{', '.join(builtin_experiments())} (or give a .toml file)",
            )
        text = res.read_text()
        origin = name_or_path
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise ConfigError("", f"{origin}: invalid TOML: {err}") from None
    except RecursionError:  # arrays or tables nested thousands deep
        raise ConfigError("", f"{origin}: invalid TOML: a value is nested too deeply") from None
    section = data.setdefault("experiment", {})
    if not isinstance(section, dict):  # `experiment = 5`, or an array of [[experiment]] tables
        raise ConfigError(
            "experiment",
            f"{origin}: expected a table of settings ([experiment]), got {section!r:.60}",
        )
    section.setdefault("name", path.stem if path.exists() else name_or_path)
    return data
