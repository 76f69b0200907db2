"""Settings, hyper-parameters and search bookkeeping shared by both PyTorch references.

Field names follow ``cognet_jax.algorithms.cognet_thesis.CognetSettings`` / ``CognetHyper`` and
``cognet_jax.algorithms.cross_entropy.EntropyConfig`` / ``Progress``, so a cognet_jax settings
object can be passed as is (``as_settings`` / ``as_hyper`` copy the fields by name); the
settings are read from cognet_jax's config declarations (the algorithm's section in
``cognet_jax.algorithms.cognet_thesis``; importing it loads JAX's Python modules, but no torch
code calls JAX).
"""

from __future__ import annotations

import dataclasses
import math
import statistics

from cognet_jax.algorithms.cognet_thesis import CognetThesisSection
from cognet_jax.algorithms.cross_entropy import ENTROPY_SECTION_FIELDS
from cognet_jax.config import NetworkSection, settings_class


@dataclasses.dataclass(frozen=True)
class EntropyConfig:
    """Maximum-entropy injection (SPEC section 2)."""

    enabled: bool = True
    rate: float = 0.02
    std_threshold: float = 0.5
    patience: int = 5


@dataclasses.dataclass(frozen=True)
class CognetHyper:
    """Hyper-parameters that may change between iterations (``step(hyper=...)``)."""

    alpha: float = 0.2
    learning_rate: float = 0.01
    entropy: EntropyConfig = dataclasses.field(default_factory=EntropyConfig)


#: Structural settings: the fields and defaults of cognet_jax's ``CognetSettings`` (declared in
#: ``cognet_thesis.CognetThesisSection`` and ``NetworkSection``) that this reference implements;
#: it has no ``train_on="top"`` and no fresh re-evaluation (``best_rollouts``).
CognetSettings = settings_class(
    "CognetSettings",
    CognetThesisSection,
    exclude=("alpha", *ENTROPY_SECTION_FIELDS, "train_on", "best_rollouts"),
    extra=tuple(
        (NetworkSection, name) for name in ("hidden", "train_steps", "optimizer", "momentum")
    ),
)


def as_settings(obj=None, **overrides) -> CognetSettings:
    """``CognetSettings`` from ``None`` (defaults), this module's class or any object with the
    same attribute names (e.g. cognet_jax's ``CognetSettings``); ``overrides`` set fields."""
    values = {}
    if obj is not None:
        for f in dataclasses.fields(CognetSettings):
            if hasattr(obj, f.name):
                values[f.name] = type(f.default)(getattr(obj, f.name))
    values.update(overrides)
    return CognetSettings(**values)


def as_hyper(obj=None, **overrides) -> CognetHyper:
    """``CognetHyper`` from ``None``, this module's class or cognet_jax's (array leaves are
    converted to Python numbers)."""
    if obj is None:
        hyper = CognetHyper()
    else:
        ent = getattr(obj, "entropy", EntropyConfig())
        hyper = CognetHyper(
            alpha=float(obj.alpha),
            learning_rate=float(obj.learning_rate),
            entropy=EntropyConfig(
                enabled=bool(ent.enabled),
                rate=float(ent.rate),
                std_threshold=float(ent.std_threshold),
                patience=int(ent.patience),
            ),
        )
    return dataclasses.replace(hyper, **overrides)


class Progress:
    """Elite threshold V_w, last ``window`` iteration values, best value and patience counter.

    Same rules as cognet_jax's ``Progress``: injection when the population std of the last
    ``window`` values is below ``std_threshold`` (only once the window is full) or when the best
    value has not improved for ``patience`` iterations; after an injection V_w is reset to -inf
    and the history and patience counter restart.
    """

    def __init__(self, window: int = 4):
        self.window = window
        self.threshold = -math.inf
        self.recent: list[float] = []
        self.best_value = -math.inf
        self.since_improved = 0
        self.iteration = 0
        self.injections = 0

    def should_inject(self, cfg: EntropyConfig) -> bool:
        flat = len(self.recent) >= self.window and (
            statistics.pstdev(self.recent) < cfg.std_threshold
        )
        stale = self.iteration > 0 and self.since_improved >= cfg.patience
        return bool(cfg.enabled) and (flat or stale)

    def after_injection(self, injected: bool) -> None:
        if injected:
            self.threshold = -math.inf
            self.recent = []
            self.since_improved = 0
            self.injections += 1

    def record(self, value: float) -> bool:
        """Append this iteration's value; returns whether it improved the best value."""
        improved = value > self.best_value
        self.recent = (self.recent + [value])[-self.window :]
        if improved:
            self.best_value = value
            self.since_improved = 0
        else:
            self.since_improved += 1
        self.iteration += 1
        return improved
