"""Typed experiment configuration: TOML files, ``--set section.key=value`` overrides and
validation that names the offending field before anything compiles.

A configuration has these sections (``[experiment]``, ``[env]``, ``[problem]``,
``[algorithm]``, ``[network]``, ``[evaluation]``, ``[run]``). Which dataclass reads ``[env]``
depends on ``env.name``; which reads ``[algorithm]`` on ``experiment.algorithm``. Unknown keys,
wrong types and out-of-range values raise ``ConfigError`` naming the dotted field.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from importlib import resources
from pathlib import Path
from typing import Any

import tomllib

from cognet_jax.errors import InputError


class ConfigError(InputError):
    """A configuration problem; ``field`` is the dotted name (e.g. ``algorithm.nodes``)."""

    def __init__(self, field: str, message: str):
        self.field = field
        super().__init__(f"config field '{field}': {message}" if field else message)


# --------------------------------------------------------------------------------------------
# sections
# --------------------------------------------------------------------------------------------
@dataclasses.dataclass
class ExperimentSection:
    name: str = "custom"
    algorithm: str = "cognet-dice"
    description: str = ""


@dataclasses.dataclass
class ProblemSection:
    """The MADP ``.dpomdp`` problem (used when ``env.name = "dpomdp"``)."""

    path: str = ""
    horizon: int = 3
    discount: float | None = None


@dataclasses.dataclass
class CognetAlgorithmSection:
    """COGNet-DICE as the thesis specifies it (SPEC 5), algorithm ``cognet-dice-thesis``; names
    follow the thesis: K_roll, K_top, K_keep, K_eval."""

    nodes: int = 3
    iterations: int = 500
    rollouts: int = 1000
    top: int = 100
    keep: int = 10
    eval_rollouts: int = 100
    alpha: float = 0.2
    threshold_rule: str = "elite"
    separate: bool = False
    common_random_numbers: bool = True
    train_last_transition: bool = True
    #: "kept" (SPEC) or "top": train the node networks on the pairs of all K_top pre-selected
    #: rollouts instead of the K_keep kept ones
    train_on: str = "kept"
    #: 0 (SPEC): step 8 evaluates the updated policy with eval_rollouts; N > 0: with N
    best_rollouts: int = 0
    entropy_injection: bool = True
    entropy_rate: float = 0.02
    entropy_std: float = 0.5
    entropy_window: int = 4
    entropy_patience: int = 5


@dataclasses.dataclass
class CognetWeightsAlgorithmSection:
    """COGNet-DICE, the default ``cognet-dice``: cross-entropy over the node networks' weights
    (``algorithms.cognet_weights``). Per iteration ``candidates`` joint controllers, each
    evaluated with ``eval_rollouts`` rollouts (common random numbers), the best ``elites``
    refit the distribution with smoothing ``alpha``; ``action_floor`` / ``category_floor`` mix
    the categoricals with the uniform distribution every iteration; the winner and the
    distribution's mode are re-evaluated on ``best_rollouts`` fresh rollouts for the anytime
    best. ``init_scale``: initial std of the hidden layer (``init_scale / sqrt(inputs)`` for the
    weights); ``vote_mean`` / ``vote_std``: initial Gaussian of the output votes;
    ``standardize_inputs``: search over a network that reads each input feature standardised by
    its mean and standard deviation under the random controller; ``paired_best``: the best
    policy so far is re-evaluated on the challengers' fresh rollouts and replaced only when a
    challenger beats it there. The hidden width is ``network.hidden``."""

    nodes: int = 3
    iterations: int = 600
    candidates: int = 200
    eval_rollouts: int = 500
    elites: int = 10
    alpha: float = 0.3
    action_floor: float = 0.02
    category_floor: float = 0.02
    best_rollouts: int = 1000
    common_random_numbers: bool = True
    init_scale: float = 10.0
    vote_mean: float = 5.0
    vote_std: float = 5.0
    standardize_inputs: bool = False
    paired_best: bool = False


@dataclasses.dataclass
class GDiceAlgorithmSection:
    """G-DICE (SPEC 3): N_n nodes, N_k iterations, N_s samples, N_b elites, N_sim rollouts."""

    nodes: int = 7
    iterations: int = 100
    samples: int = 100
    elites: int = 10
    eval_rollouts: int = 100
    alpha: float = 0.1
    common_random_numbers: bool = True
    entropy_injection: bool = False
    entropy_rate: float = 0.02
    entropy_std: float = 0.5
    entropy_window: int = 4
    entropy_patience: int = 5
    #: 0: best tracking compares the iteration winner's in-loop mean (SPEC); N > 0: a fresh
    #: mean over N rollouts, free of the winner's selection bias
    best_rollouts: int = 0
    #: "rollouts" (SPEC: mean of eval_rollouts returns), "exact" (tabular models only: the
    #: exact expected return over the horizon, computed inside the compiled iteration),
    #: "hybrid" (rollouts pick the ``exact_top`` best samples, which get exact values) or
    #: "auto" (exact when one iteration's exact values cost at most ``api.EXACT_AUTO_LIMIT``
    #: multiply-adds, else hybrid when its exact part does, else rollouts)
    evaluator: str = "rollouts"
    #: evaluator "hybrid": the samples (best by rollouts) that get exact values
    exact_top: int = 50
    #: identical agents: each sample is one controller used by every agent (a search over
    #: symmetric joint controllers; SPEC's G-DICE samples every agent independently)
    shared_controller: bool = False
    #: a time-layered controller for a finite horizon: ``problem.horizon`` layers of ``nodes``
    #: nodes each; node q of layer t acts at step t and moves to layer t + 1 only
    layered: bool = False
    #: independent searches run side by side in one compiled step; the best policy of all
    restarts: int = 1
    #: extra searches over shared controllers beside them (identical agents only; skipped for
    #: agents with different action or observation counts, so a default can always ask)
    shared_restarts: int = 0
    #: extra independent searches whose entropy injection mixes in ``explore_entropy_rate``
    #: of uniform (a strong rate escapes local optima that the usual rate settles in)
    explore_restarts: int = 0
    explore_entropy_rate: float = 0.2
    #: after the last iteration, at most this many single-entry changes of the best controller
    #: by exact steepest ascent (exact or hybrid evaluator only; 0: none, as in SPEC)
    polish_sweeps: int = 0
    #: with the polish of a layered controller: at most this many rounds of each agent's exact
    #: best response to the others (written into its layers when it fits), each followed by
    #: the single-entry polish (``algorithms.best_response``; 0: none)
    best_response_rounds: int = 0


@dataclasses.dataclass
class CogDiceAlgorithmSection:
    """COG-DICE (SPEC 4): N_n nodes, N_t regions, iterations, N_s samples, N_b elites, N_sim
    rollouts; Beta fit clamp ``beta_eps`` and denominator floor ``min_denominator``."""

    nodes: int = 3
    regions: int = 3
    iterations: int = 500
    samples: int = 2000
    elites: int = 50
    eval_rollouts: int = 1000
    alpha: float = 0.1
    common_random_numbers: bool = True
    beta_eps: float = 1e-6
    min_denominator: float = 1e-6
    #: as G-DICE's ``best_rollouts``
    best_rollouts: int = 0
    entropy_injection: bool = False
    entropy_rate: float = 0.02
    entropy_std: float = 0.5
    entropy_window: int = 4
    entropy_patience: int = 5


@dataclasses.dataclass
class NetworkSection:
    """Node networks of COGNet-DICE and what they read (``cognet_jax.observations``).

    ``observation``: ``"raw"`` (the environment's observation) or ``"encoded"`` (heatmap only:
    the patch VAE's encoder mean). ``vae_path``: a VAE file from ``cognet-jax vae train``; empty:
    trained on demand from ``vae_seed`` / ``vae_epochs`` (and saved in the run folder).
    ``augment``: add ``augment_samples`` VAE-sampled training pairs per pair (SPEC section 6).
    """

    hidden: int = 10
    optimizer: str = "adam"
    learning_rate: float = 0.01
    momentum: float = 0.5
    train_steps: int = 20
    observation: str = "raw"
    vae_path: str = ""
    vae_seed: int = 0
    vae_epochs: int = 60
    #: latent dimensions and KL weight of the on-demand VAE (``cognet_jax.vae``)
    vae_latent: int = 1
    vae_kl_weight: float = 1.0
    augment: bool = False
    augment_samples: int = 1


@dataclasses.dataclass
class EvaluationSection:
    """Honest final evaluation of the best policy (fresh key)."""

    rollouts: int = 10_000
    batch: int = 10_000


@dataclasses.dataclass
class RunSection:
    """How a run is driven. ``checkpoint_every``: write the full search state every K
    iterations (0: only at the end and on Ctrl-C)."""

    #: "threefry2x32" (default), "rbg", "unsafe_rbg", or "hash": the counter-based generator
    #: of ``cognet_jax.prng`` (rollouts about 1.3x faster on CPU than threefry; other numbers)
    prng_impl: str = "threefry2x32"
    progress: bool = True
    plots: bool = True
    checkpoint_every: int = 0
    #: lay every batch of rollouts (and the candidates' evaluations) over all local devices
    #: (``runner.rollout_mesh``); for hosts with several accelerators -- on a CPU split into
    #: devices it is slower than one device (benchmarks/NOTES.md)
    shard_rollouts: bool = False
    #: GB the rollouts in flight may take (0: half of this machine's memory); candidates are
    #: evaluated in chunks to stay within it (``cognet_jax.memory``), and a program whose
    #: single array exceeds it is refused before compiling
    memory_gb: float = 0.0


def _env_section(name: str) -> type:
    """The ``[env]`` dataclass of simulator ``name`` (``registry``; ConfigError if unknown)."""
    from cognet_jax.registry import env_entry

    return env_entry(name).section


def _algorithm_section(name: str) -> type:
    """The ``[algorithm]`` dataclass of algorithm ``name`` (``registry``)."""
    from cognet_jax.registry import algorithm_entry

    return algorithm_entry(name).section


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
    namespace = {"__doc__": doc or f"Static settings: the fields of ``config.{section.__name__}``."}
    return dataclasses.make_dataclass(name, fields, frozen=True, namespace=namespace)


#: the entropy-injection fields of a config section (dynamic: ``EntropyConfig``)
ENTROPY_SECTION_FIELDS = ("entropy_injection", "entropy_rate", "entropy_std", "entropy_patience")


@dataclasses.dataclass
class Config:
    experiment: ExperimentSection = dataclasses.field(default_factory=ExperimentSection)
    env: Any = dataclasses.field(default_factory=lambda: _env_section("tagging")())
    problem: ProblemSection = dataclasses.field(default_factory=ProblemSection)
    algorithm: Any = dataclasses.field(default_factory=CognetWeightsAlgorithmSection)
    network: NetworkSection = dataclasses.field(default_factory=NetworkSection)
    evaluation: EvaluationSection = dataclasses.field(default_factory=EvaluationSection)
    run: RunSection = dataclasses.field(default_factory=RunSection)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


# --------------------------------------------------------------------------------------------
# reading
# --------------------------------------------------------------------------------------------
def _check_type(field: str, value: Any, annotation: Any) -> Any:
    """Convert/validate one value against a simple annotation (int, float, bool, str, X|None)."""
    origin = typing.get_origin(annotation)
    if origin in (typing.Union, types.UnionType):
        options = typing.get_args(annotation)
        if value is None and type(None) in options:
            return None
        inner = [o for o in options if o is not type(None)]
        return _check_type(field, value, inner[0])
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


def config_from_dict(data: dict) -> Config:
    """Build and validate a ``Config`` from nested dicts (as read from TOML)."""
    data = dict(data)
    known = {f.name for f in dataclasses.fields(Config)}
    for key in data:
        if key not in known:
            raise ConfigError(key, f"unknown section (known: {', '.join(sorted(known))})")
    experiment = section_from_dict(ExperimentSection, data.get("experiment", {}), "experiment")
    env_data = data.get("env", {})
    if not isinstance(env_data, dict):
        raise ConfigError("env", f"expected a table of settings, got {env_data!r}")
    env_name = env_data.get("name", "tagging")
    if not isinstance(env_name, str):
        raise ConfigError("env.name", f"expected a simulator name, got {env_name!r}")
    env_section = _env_section(env_name)
    algorithm_section = _algorithm_section(experiment.algorithm)
    config = Config(
        experiment=experiment,
        env=section_from_dict(env_section, env_data, "env"),
        problem=section_from_dict(ProblemSection, data.get("problem", {}), "problem"),
        algorithm=section_from_dict(algorithm_section, data.get("algorithm", {}), "algorithm"),
        network=section_from_dict(NetworkSection, data.get("network", {}), "network"),
        evaluation=section_from_dict(EvaluationSection, data.get("evaluation", {}), "evaluation"),
        run=section_from_dict(RunSection, data.get("run", {}), "run"),
    )
    validate(config)
    return config


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
    return path, value


def apply_overrides(data: dict, overrides: list[str]) -> dict:
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
        text = path.read_text()
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
    data.setdefault("experiment", {}).setdefault(
        "name", path.stem if path.exists() else name_or_path
    )
    return data


def load_config(name_or_path: str, overrides: list[str] | None = None) -> Config:
    """Read an experiment, apply ``--set`` overrides, validate."""
    return config_from_dict(apply_overrides(read_experiment(name_or_path), overrides or []))


# --------------------------------------------------------------------------------------------
# validation
# --------------------------------------------------------------------------------------------
def require(cond: bool, field: str, message: str):
    """``ConfigError(field, message)`` unless ``cond`` (for sections' ``check`` methods)."""
    if not cond:
        raise ConfigError(field, message)


def require_positive(section: Any, prefix: str, *names: str):
    """Each named field of ``section`` is ``None`` or ``>= 1`` (``prefix.name`` otherwise)."""
    for n in names:
        v = getattr(section, n)
        require(v is None or v >= 1, f"{prefix}.{n}", f"must be >= 1, got {v}")


_require, _positive = require, require_positive


def _probability(section: Any, prefix: str, *names: str):
    for n in names:
        v = getattr(section, n)
        _require(0.0 <= v <= 1.0, f"{prefix}.{n}", f"must be in [0, 1], got {v}")


def _validate_sampler(alg) -> None:
    """Fields shared by the algorithms that sample deterministic controllers (G-DICE, COG-DICE)."""
    _positive(
        alg,
        "algorithm",
        "nodes",
        "iterations",
        "samples",
        "elites",
        "eval_rollouts",
        "entropy_window",
        "entropy_patience",
    )
    _require(
        alg.elites <= alg.samples,
        "algorithm.elites",
        f"elites ({alg.elites}) cannot exceed algorithm.samples ({alg.samples})",
    )
    _probability(alg, "algorithm", "alpha", "entropy_rate")
    _require(alg.best_rollouts >= 0, "algorithm.best_rollouts", "must be >= 0")
    _require(
        alg.entropy_std >= 0,
        "algorithm.entropy_std",
        f"must be >= 0 (the flat-window trigger's threshold), got {alg.entropy_std}",
    )


def _validate_network(config: Config, training: bool) -> None:
    """``[network]`` of both COGNet-DICE variants; ``training``: the optimiser settings too."""
    net = config.network
    env = config.env
    _positive(net, "network", "hidden")
    if training:
        _positive(net, "network", "train_steps")
        _require(
            net.optimizer in ("adam", "sgd"),
            "network.optimizer",
            f"must be 'adam' or 'sgd', got {net.optimizer!r}",
        )
        _require(net.learning_rate > 0, "network.learning_rate", "must be > 0")
        _require(0 <= net.momentum < 1, "network.momentum", "must be in [0, 1)")
    _require(
        net.observation in ("raw", "encoded"),
        "network.observation",
        f"must be 'raw' or 'encoded', got {net.observation!r}",
    )
    _positive(net, "network", "vae_epochs", "augment_samples", "vae_latent")
    _require(
        math.isfinite(net.vae_kl_weight) and net.vae_kl_weight > 0,
        "network.vae_kl_weight",
        f"must be > 0, got {net.vae_kl_weight}",
    )
    _require(net.vae_seed >= 0, "network.vae_seed", f"must be >= 0, got {net.vae_seed}")
    needs_vae = net.observation == "encoded" or net.augment
    _require(
        not needs_vae or env.name == "heatmap",
        "network.observation" if net.observation == "encoded" else "network.augment",
        "the patch VAE reads 4 x 4 heatmap patches: needs env.name = 'heatmap'",
    )


def _check_finite(config: Config) -> None:
    """Every number of every section is finite: ``inf`` and ``nan`` parse as TOML floats but
    mean nothing as a noise level, rate, reward or size."""
    for section in dataclasses.fields(config):
        values = getattr(config, section.name)
        for f in dataclasses.fields(values):
            v = getattr(values, f.name)
            if isinstance(v, float) and not math.isfinite(v):
                raise ConfigError(f"{section.name}.{f.name}", f"must be a finite number, got {v}")


def validate(config: Config) -> None:
    """Range and consistency checks; raises ``ConfigError`` naming the field."""
    _check_finite(config)
    env = config.env
    check_env = getattr(env, "check", None)  # the section's own checks (``registry``)
    if callable(check_env):
        check_env(config)

    alg = config.algorithm
    if isinstance(alg, CognetAlgorithmSection):
        _positive(
            alg,
            "algorithm",
            "nodes",
            "iterations",
            "rollouts",
            "top",
            "keep",
            "eval_rollouts",
            "entropy_window",
            "entropy_patience",
        )
        _require(
            alg.top <= alg.rollouts,
            "algorithm.top",
            f"pre-selected rollouts ({alg.top}) cannot exceed algorithm.rollouts ({alg.rollouts})",
        )
        limit = alg.rollouts if alg.separate else alg.top
        _require(
            alg.keep <= limit,
            "algorithm.keep",
            f"kept elites ({alg.keep}) cannot exceed the candidates ({limit})",
        )
        _probability(alg, "algorithm", "alpha", "entropy_rate")
        _require(alg.entropy_std >= 0, "algorithm.entropy_std", "must be >= 0")
        _require(
            alg.threshold_rule in ("elite", "best"),
            "algorithm.threshold_rule",
            f"must be 'elite' or 'best', got {alg.threshold_rule!r}",
        )
        _require(alg.best_rollouts >= 0, "algorithm.best_rollouts", "must be >= 0")
        _require(
            alg.train_on in ("kept", "top"),
            "algorithm.train_on",
            f"must be 'kept' or 'top', got {alg.train_on!r}",
        )
        _validate_network(config, training=True)
    if isinstance(alg, CognetWeightsAlgorithmSection):
        _positive(alg, "algorithm", "nodes", "iterations", "candidates", "eval_rollouts", "elites")
        _require(
            alg.elites <= alg.candidates,
            "algorithm.elites",
            f"elites ({alg.elites}) cannot exceed algorithm.candidates ({alg.candidates})",
        )
        _require(alg.elites >= 2, "algorithm.elites", "needs >= 2 to fit a standard deviation")
        _probability(alg, "algorithm", "alpha", "action_floor", "category_floor")
        _require(alg.best_rollouts >= 1, "algorithm.best_rollouts", "must be >= 1")
        for name in ("init_scale", "vote_mean", "vote_std"):
            v = getattr(alg, name)
            _require(math.isfinite(v) and v >= 0, f"algorithm.{name}", f"must be >= 0, got {v}")
        _require(alg.init_scale > 0, "algorithm.init_scale", "must be > 0")
        defaults = NetworkSection()
        for name in ("train_steps", "optimizer", "learning_rate", "momentum"):
            _require(
                getattr(config.network, name) == getattr(defaults, name),
                f"network.{name}",
                "trains the node networks of cognet-dice-thesis; the default cognet-dice "
                "samples network weights and has no optimiser",
            )
        _validate_network(config, training=False)
        _require(
            not config.network.augment,
            "network.augment",
            "VAE augmentation adds training pairs; the weight-space cognet-dice trains no "
            "network (use experiment.algorithm = 'cognet-dice-thesis')",
        )
    if isinstance(alg, GDiceAlgorithmSection):
        _validate_sampler(alg)
        _require(
            env.name != "heatmap"
            and (env.name != "tagging" or getattr(env, "obs_division", 0) > 0),
            "env.name",
            "G-DICE needs discrete observations: a .dpomdp problem, or tagging with "
            "env.obs_division > 0",
        )
        _require(
            alg.evaluator in ("rollouts", "exact", "hybrid", "auto"),
            "algorithm.evaluator",
            f"must be 'rollouts', 'exact', 'hybrid' or 'auto', got {alg.evaluator!r}",
        )
        _require(
            alg.evaluator == "rollouts" or env.name == "dpomdp",
            "algorithm.evaluator",
            f"{alg.evaluator!r} needs a tabular .dpomdp problem (env.name = 'dpomdp')",
        )
        _positive(alg, "algorithm", "restarts", "exact_top")
        _require(alg.shared_restarts >= 0, "algorithm.shared_restarts", "must be >= 0")
        _require(alg.explore_restarts >= 0, "algorithm.explore_restarts", "must be >= 0")
        _require(alg.polish_sweeps >= 0, "algorithm.polish_sweeps", "must be >= 0")
        _require(alg.best_response_rounds >= 0, "algorithm.best_response_rounds", "must be >= 0")
        _probability(alg, "algorithm", "explore_entropy_rate")
    if isinstance(alg, CogDiceAlgorithmSection):
        _validate_sampler(alg)
        _require(
            alg.regions >= 2,
            "algorithm.regions",
            f"needs >= 2 regions (at least one division point), got {alg.regions}",
        )
        _require(alg.entropy_std >= 0, "algorithm.entropy_std", "must be >= 0")
        _require(
            0.0 < alg.beta_eps < 0.5,
            "algorithm.beta_eps",
            f"must be in (0, 0.5), got {alg.beta_eps}",
        )
        _require(
            0.0 < alg.min_denominator < 1.0,
            "algorithm.min_denominator",
            f"must be in (0, 1), got {alg.min_denominator}",
        )
        _require(
            env.name not in ("heatmap", "dpomdp"),
            "env.name",
            "COG-DICE needs a scalar continuous observation: the tagging environment (or a "
            "registered simulator with one)",
        )
    _positive(config.evaluation, "evaluation", "rollouts", "batch")
    _require(config.evaluation.rollouts >= 2, "evaluation.rollouts", "needs >= 2 for a std error")
    _require(
        config.run.checkpoint_every >= 0,
        "run.checkpoint_every",
        f"must be >= 0, got {config.run.checkpoint_every}",
    )
    _require(
        config.run.memory_gb >= 0, "run.memory_gb", f"must be >= 0, got {config.run.memory_gb}"
    )
    _require(
        config.run.prng_impl in ("threefry2x32", "rbg", "unsafe_rbg", "hash"),
        "run.prng_impl",
        f"must be threefry2x32, rbg, unsafe_rbg or hash, got {config.run.prng_impl!r}",
    )
