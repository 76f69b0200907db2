"""Cross-entropy pieces shared by G-DICE, COG-DICE and COGNet-DICE (SPEC section 2).

All values are returns to **maximise**. Everything here is a pure array function; shapes are
static, so these compile once inside an algorithm's ``step``.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from flax import struct

from cognet_jax.config import require, require_positive, require_probability


def elite_selection(values: jax.Array, threshold: jax.Array, num_elites: int):
    """Elite threshold rule of G-DICE.

    Keeps the candidates whose value is strictly above ``threshold`` (V_w), sorts them and takes
    the best ``num_elites``; the new threshold is the smallest kept value. When no candidate
    beats V_w the threshold is unchanged and nothing is kept.

    Args:
      values: ``[C]`` candidate values.
      threshold: ``[]`` current V_w (``-inf`` at the start).
      num_elites: N_b (static).

    Returns:
      ``(indices [N_b] int32, kept [N_b] bool, new_threshold [])``; ``indices`` are sorted by
      decreasing value and ``kept`` marks the ones that beat ``threshold``.
    """
    eligible = jnp.where(values > threshold, values, -jnp.inf)
    top, idx = jax.lax.top_k(eligible, num_elites)
    kept = top > -jnp.inf
    smallest_kept = jnp.min(jnp.where(kept, top, jnp.inf))
    new_threshold = jnp.where(jnp.any(kept), smallest_kept, threshold)
    return idx.astype(jnp.int32), kept, new_threshold


def count_table(indices: jax.Array, num_categories: int, weights: jax.Array | None = None):
    """One-hot counts: ``indices [..., B]`` -> ``[..., num_categories]`` summed over B,
    each entry weighted by ``weights [..., B]`` (1 when omitted)."""
    onehot = jax.nn.one_hot(indices, num_categories, dtype=jnp.float32)
    if weights is not None:
        onehot = onehot * weights[..., None]
    return onehot.sum(-2)


def smooth(old: jax.Array, counts: jax.Array, alpha: jax.Array | float) -> jax.Array:
    """Count MLE + smoothing: ``alpha * counts / sum(counts) + (1 - alpha) * old`` along the
    last axis, for every row with at least one count; rows without counts keep ``old``."""
    total = counts.sum(-1, keepdims=True)
    mle = counts / jnp.maximum(total, 1e-30)
    return jnp.where(total > 0, alpha * mle + (1.0 - alpha) * old, old)


def inject_entropy(probs: jax.Array, rate: jax.Array | float, support: jax.Array | None = None):
    """Maximum-entropy injection: ``(1 - rate) * probs + rate * uniform`` along the last axis.

    ``support`` (broadcastable bool, same last axis) restricts the uniform distribution to the
    allowed categories, e.g. the actions an agent actually has.
    """
    if support is None:
        uniform = jnp.full_like(probs, 1.0 / probs.shape[-1])
    else:
        s = jnp.broadcast_to(support, probs.shape).astype(probs.dtype)
        uniform = s / s.sum(-1, keepdims=True)
    return (1.0 - rate) * probs + rate * uniform


@struct.dataclass
class EntropyConfig:
    """Dynamic entropy-injection settings (a pytree, sweepable)."""

    enabled: jax.Array | bool = True
    rate: jax.Array | float = 0.02
    std_threshold: jax.Array | float = 0.5
    patience: jax.Array | int = 5


@struct.dataclass
class Progress:
    """Bookkeeping of the search: the elite threshold, the last iteration values, the best
    in-loop value and how long it has not improved.

    ``recent [k]`` holds the last k iteration values (oldest first), ``num_recent`` how many are
    real. Two injection triggers (SPEC section 2): population std of the last k values below
    ``std_threshold`` (only once k values exist), or no improvement of the best value for
    ``patience`` iterations. **[choice]** After an injection the history and the patience counter
    restart, so the next injection needs fresh evidence (otherwise a stalled search would inject
    every iteration); V_w is reset to -inf as the SPEC says.
    """

    threshold: jax.Array
    recent: jax.Array
    num_recent: jax.Array
    in_loop_best: jax.Array
    since_improved: jax.Array
    iteration: jax.Array
    injections: jax.Array

    @classmethod
    def create(cls, window: int = 4) -> Progress:
        return cls(
            threshold=jnp.float32(-jnp.inf),
            recent=jnp.zeros(window, jnp.float32),
            num_recent=jnp.int32(0),
            in_loop_best=jnp.float32(-jnp.inf),
            since_improved=jnp.int32(0),
            iteration=jnp.int32(0),
            injections=jnp.int32(0),
        )

    def should_inject(self, cfg: EntropyConfig) -> jax.Array:
        """Whether either trigger fires on the history so far (bool ``[]``)."""
        window = self.recent.shape[0]
        full = self.num_recent >= window
        flat = full & (jnp.std(self.recent) < cfg.std_threshold)
        stale = (self.iteration > 0) & (self.since_improved >= cfg.patience)
        return jnp.asarray(cfg.enabled) & (flat | stale)

    def after_injection(self, injected: jax.Array) -> Progress:
        """Reset V_w, the value history and the patience counter where ``injected``."""
        return self.replace(
            threshold=jnp.where(injected, -jnp.inf, self.threshold),
            num_recent=jnp.where(injected, 0, self.num_recent),
            since_improved=jnp.where(injected, 0, self.since_improved),
            injections=self.injections + injected.astype(jnp.int32),
        )

    def record(self, value: jax.Array) -> tuple[Progress, jax.Array]:
        """Append this iteration's value; returns ``(progress, improved)``."""
        improved = value > self.in_loop_best
        recent = jnp.concatenate([self.recent[1:], value[None]])
        return (
            self.replace(
                recent=recent,
                num_recent=jnp.minimum(self.num_recent + 1, self.recent.shape[0]),
                in_loop_best=jnp.where(improved, value, self.in_loop_best),
                since_improved=jnp.where(improved, 0, self.since_improved + 1),
                iteration=self.iteration + 1,
            ),
            improved,
        )


def select_tree(pred: jax.Array, on_true, on_false):
    """``jnp.where`` over two pytrees of the same structure (scalar ``pred``)."""
    return jax.tree.map(lambda a, b: jnp.where(pred, a, b), on_true, on_false)


def entropy_config(section) -> EntropyConfig:
    """The entropy-injection settings of a config section (``entropy_injection``,
    ``entropy_rate``, ``entropy_std``, ``entropy_patience``)."""
    return EntropyConfig(
        enabled=section.entropy_injection,
        rate=section.entropy_rate,
        std_threshold=section.entropy_std,
        patience=section.entropy_patience,
    )


#: the entropy-injection fields of a config section (dynamic: ``EntropyConfig``)
ENTROPY_SECTION_FIELDS = ("entropy_injection", "entropy_rate", "entropy_std", "entropy_patience")
#: the config fields of ``entropy_config``, as sweepable dotted names
ENTROPY_FIELDS = tuple(f"algorithm.{name}" for name in ENTROPY_SECTION_FIELDS)


@dataclasses.dataclass
class EntropySection:
    """The entropy-injection fields of an ``[algorithm]`` section (SPEC section 2; ``Progress``
    has the triggers): on or off, the ``rate`` of uniform mixed in, the flat-window trigger
    (population std of the last ``entropy_window`` iteration values below ``entropy_std``) and
    the stale trigger (no improvement for ``entropy_patience`` iterations)."""

    entropy_injection: bool = False
    entropy_rate: float = 0.02
    entropy_std: float = 0.5
    entropy_window: int = 4
    entropy_patience: int = 5

    def check_entropy(self) -> None:
        """``ConfigError`` naming the field of a bad entropy setting."""
        require_positive(self, "algorithm", "entropy_window", "entropy_patience")
        require_probability(self, "algorithm", "entropy_rate")
        require(
            self.entropy_std >= 0,
            "algorithm.entropy_std",
            f"must be >= 0 (the flat-window trigger's threshold), got {self.entropy_std}",
        )
