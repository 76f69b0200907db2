"""COG-DICE (SPEC section 4; Clark-Turner & Amato, IJCAI 2017): cross-entropy search over
deterministic *region* FSCs for a scalar continuous observation.

Each node q of agent i cuts the observation range ``env.obs_range`` (tagging: [-10, 10]) into
``regions`` (N_t) regions with ``regions - 1`` division points; the next node depends on the
node and the region of the observation (``cognet_jax.controllers.regions``: region of z = number
of sorted points strictly below z).

Search distribution per agent (``RegionDistribution``), all agents stacked:

* ``action_probs [agents, nodes, actions]`` -- f(a | q), uniform at the start (over each agent's
  own actions);
* ``transition_probs [agents, nodes, regions, nodes]`` -- g(q' | q, region), uniform at the start;
* ``beta_params [agents, nodes, regions - 1, 2]`` -- one Beta(alpha, beta) on [0, 1] per division
  point *slot* l of node q (``[..., 0]`` = alpha, ``[..., 1]`` = beta), Beta(1, 1) at the start.
  A draw x is mapped affinely to the observation range: ``low + (high - low) * x``.

One iteration (``CogDice.step``, compiled once; the protocol of ``algorithms.engine``), values
are discounted returns to **maximise**:

1. draw ``samples`` deterministic joint controllers in one block: one action per node,
   one next node per (node, region), every division point from its own Beta
   (``jax.random.beta``), mapped to the observation range; each node's points are sorted for the
   controller while the *unsorted* [0, 1] draws are kept per slot (``RegionSample.unit_points``)
   for the refit;
2. evaluate each with ``eval_rollouts`` rollouts of the shared engine
   (``rollout.evaluate_candidates``; common random numbers across samples by default, as G-DICE);
3. elite threshold (SPEC section 2, ``elite_selection``): keep the best ``elites`` samples whose
   value beats V_w;
4. update, all with the smoothing rate ``alpha``:
   * actions and region transitions: count MLE over the kept elites' *tables* (frequency over
     elites, not over visits), then ``alpha * MLE + (1 - alpha) * old`` (``count_table``,
     ``smooth``);
   * every Beta slot is refit to the kept elites' unsorted draws of *that slot* with the NIST
     approximate MLE (``beta_mle``) and smoothed, ``theta <- alpha * theta_hat + (1 - alpha) *
     theta_old`` for both parameters; only when at least 2 elites are kept, otherwise the Betas
     are unchanged;
5. optional maximum-entropy injection (``EntropyConfig``; off by default, the COG-DICE paper has
   none) into the categorical parts;
6. keep the best sample seen so far (anytime; ``best_policy``).

NIST approximate Beta MLE of one slot over N kept draws x_j (clamped into (eps, 1 - eps)):
``G_x = (prod x_j)^(1/N)``, ``G_1x = (prod (1 - x_j))^(1/N)``,
``alpha_hat = 1/2 + G_x / (2 D)``, ``beta_hat = 1/2 + G_1x / (2 D)``, ``D = 1 - G_x - G_1x``.
The estimator comes from digamma(a) ~ log(a - 1/2) and is biased for small parameters (for data
from Beta(1, 1) it gives about 1.2, from Beta(0.7, 0.7) about 0.92; within about 6 % for
parameters >= 1.5; see ``tests/test_cogdice.py``).

Choices (**[choice]**):

* The geometric means are computed in log space, centred on the (kept-elite) mean m of the
  draws: ``log G_x = log m + u`` with ``u = mean(log(x / m) - d)``, ``d = (x - m) / m`` (an exact
  rewrite, since ``mean(d) = 0``; ``log(x / m)`` as ``log1p(d)`` when ``|d| < 1/2``), likewise
  ``v`` for ``1 - x``; then
  ``D = m * (-expm1(u)) + (1 - m) * (-expm1(v))``. This avoids the catastrophic cancellation of
  ``1 - G_x - G_1x`` in float32 when the elites' draws are concentrated.
* Denominator guard: by AM-GM ``G_x + G_1x <= mean(x) + mean(1 - x) = 1``, so ``D >= 0``, with
  ``D = 0`` only when all kept draws of a slot are equal (the MLE is infinite). ``D`` is floored at
  ``min_denominator`` (settings, default 1e-6), which caps the fitted concentration
  ``alpha_hat + beta_hat`` at about ``1 / (2 min_denominator) + 1`` (5e5: a standard deviation of
  about 7e-4 of the observation range for a mid-range point, 0.014 on tagging's [-10, 10]) while
  keeping the fit's mean close to ``G_x / (G_x + G_1x)``. Fitted parameters are always > 1/2, so the
  sampler never sees tiny Beta parameters.
* Clamp: draws are clamped into ``(beta_eps, 1 - beta_eps)`` before the refit,
  ``beta_eps = 1e-6`` by default (settings) -- ``jax.random.beta`` can return exactly 0 or 1 in
  float32 for small parameters.
* Entropy injection touches only ``action_probs`` (restricted to each agent's actions) and
  ``transition_probs``; the Betas are left as they are (SPEC: continuous parameters are not
  mixed). An injection resets V_w to -inf as in SPEC section 2.
* The value an iteration records (entropy-injection triggers, best-value curve) is its best
  sample's value (the in-loop, optimistic estimate), as in G-DICE.
* ``samples`` defaults to the paper's 2000 (the released code used 1000).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from flax import struct

from cognet_jax.algorithms.cross_entropy import (
    ENTROPY_FIELDS,
    ENTROPY_SECTION_FIELDS,
    Progress,
    count_table,
    inject_entropy,
    smooth,
)
from cognet_jax.algorithms.engine import (
    SearchParams,
    ThresholdHyper,
    ThresholdSearch,
    ThresholdSection,
    threshold_hyper,
)
from cognet_jax.config import ConfigError, require, settings_class
from cognet_jax.controllers.base import action_support, sample_categorical, uniform_distribution
from cognet_jax.controllers.figures import region_plots
from cognet_jax.controllers.regions import DeterministicRegionPolicy, RegionController
from cognet_jax.registry import fields_from, register_algorithm


# --------------------------------------------------------------------------------------------
# pytrees
# --------------------------------------------------------------------------------------------
@struct.dataclass
class RegionDistribution:
    """COG-DICE search distribution (all agents stacked)."""

    action_probs: jax.Array  # [agents, nodes, actions]
    transition_probs: jax.Array  # [agents, nodes, regions, nodes]
    beta_params: jax.Array  # [agents, nodes, regions - 1, 2] (alpha, beta) per point slot


@struct.dataclass
class RegionSample:
    """One sampled deterministic controller plus the unsorted [0, 1] draws of its points:
    ``unit_points[i, q, l]`` was drawn from ``beta_params[i, q, l]`` (before sorting)."""

    policy: DeterministicRegionPolicy
    unit_points: jax.Array  # [agents, nodes, regions - 1] float32 in [0, 1], unsorted


@dataclasses.dataclass
class CogDiceSection(ThresholdSection):
    """``[algorithm]`` of COG-DICE (SPEC 4): the shared fields of ``ThresholdSection`` with the
    paper's defaults, N_t ``regions``, the Beta fit clamp ``beta_eps`` and denominator floor
    ``min_denominator``."""

    nodes: int = 3
    iterations: int = 500
    samples: int = 2000
    elites: int = 50
    eval_rollouts: int = 1000
    regions: int = 3
    beta_eps: float = 1e-6
    min_denominator: float = 1e-6

    def check(self, config) -> None:
        super().check(config)
        require(
            self.regions >= 2,
            "algorithm.regions",
            f"needs >= 2 regions (at least one division point), got {self.regions}",
        )
        require(
            0.0 < self.beta_eps < 0.5,
            "algorithm.beta_eps",
            f"must be in (0, 0.5), got {self.beta_eps}",
        )
        require(
            0.0 < self.min_denominator < 1.0,
            "algorithm.min_denominator",
            f"must be in (0, 1), got {self.min_denominator}",
        )


#: static settings: the fields of ``CogDiceSection`` without the hyper-parameters
#: (``ThresholdHyper``)
CogDiceSettings = settings_class(
    "CogDiceSettings", CogDiceSection, exclude=("alpha", *ENTROPY_SECTION_FIELDS)
)


@struct.dataclass
class CogDiceState:
    distribution: RegionDistribution
    best_policy: DeterministicRegionPolicy
    progress: Progress


# --------------------------------------------------------------------------------------------
# Beta pieces
# --------------------------------------------------------------------------------------------
def points_from_unit(unit: jax.Array, obs_range: tuple[float, float]) -> jax.Array:
    """Affine map of [0, 1] draws to the observation range ``(low, high)``."""
    low, high = obs_range
    return low + (high - low) * unit


def beta_mle(
    x: jax.Array,
    weights: jax.Array | None = None,
    eps: float = 1e-6,
    min_denominator: float = 1e-6,
) -> tuple[jax.Array, jax.Array]:
    """NIST approximate maximum-likelihood Beta fit along the last axis.

    Args:
      x: ``[..., N]`` draws in [0, 1] (clamped into ``(eps, 1 - eps)``).
      weights: ``[..., N]`` (broadcastable) non-negative weights, e.g. a 0/1 elite mask; all ones
        when omitted. Geometric means are weighted means of the logs.
      eps: clamp of the draws.
      min_denominator: floor of ``D = 1 - G_x - G_1x`` (see the module docstring).

    Returns:
      ``(alpha_hat, beta_hat)``, each ``[...]``. Rows whose total weight is 0 return finite
      values that mean nothing (the caller masks them).
    """
    x = jnp.clip(jnp.asarray(x, jnp.float32), eps, 1.0 - eps)
    w = jnp.ones_like(x) if weights is None else jnp.broadcast_to(weights, x.shape)
    w = w.astype(jnp.float32)
    total = w.sum(-1, keepdims=True)
    has = total > 0
    safe_total = jnp.where(has, total, 1.0)
    m = jnp.where(has, (w * x).sum(-1, keepdims=True) / safe_total, 0.5)
    m = jnp.clip(m, eps, 1.0 - eps)

    def centred_log_mean(y, mean):
        # mean(log(y / mean)) = mean(log1p(d) - d), d = y / mean - 1, since mean(d) = 0
        d = (y - mean) / mean
        log_ratio = jnp.where(jnp.abs(d) < 0.5, jnp.log1p(d), jnp.log(y) - jnp.log(mean))
        return jnp.minimum(((log_ratio - d) * w).sum(-1, keepdims=True) / safe_total, 0.0)

    u = centred_log_mean(x, m)  # log G_x - log m  (<= 0)
    v = centred_log_mean(1.0 - x, 1.0 - m)  # log G_1x - log (1 - m)  (<= 0)
    g_x = m * jnp.exp(u)
    g_1x = (1.0 - m) * jnp.exp(v)
    denom = m * (-jnp.expm1(u)) + (1.0 - m) * (-jnp.expm1(v))
    denom = jnp.maximum(denom, min_denominator)
    alpha_hat = 0.5 + g_x / (2.0 * denom)
    beta_hat = 0.5 + g_1x / (2.0 * denom)
    return alpha_hat[..., 0], beta_hat[..., 0]


def refit_betas(
    beta_params: jax.Array,
    unit_points: jax.Array,
    kept: jax.Array,
    alpha: jax.Array | float,
    eps: float = 1e-6,
    min_denominator: float = 1e-6,
) -> jax.Array:
    """Refit every Beta slot to the kept elites' draws of that slot and smooth.

    Args:
      beta_params: ``[..., 2]`` current (alpha, beta) of every slot.
      unit_points: ``[E, ...]`` the elites' unsorted [0, 1] draws, slot-aligned with
        ``beta_params``.
      kept: ``[E]`` bool, which elites count.
      alpha: smoothing rate.

    Returns:
      ``alpha * (alpha_hat, beta_hat) + (1 - alpha) * beta_params`` where at least 2 elites are
      kept, else ``beta_params`` unchanged.
    """
    x = jnp.moveaxis(unit_points, 0, -1)  # [..., E]
    w = kept.astype(jnp.float32)
    a_hat, b_hat = beta_mle(x, w, eps, min_denominator)
    fitted = jnp.stack([a_hat, b_hat], axis=-1)
    refit = w.sum() >= 2
    return jnp.where(refit, alpha * fitted + (1.0 - alpha) * beta_params, beta_params)


# --------------------------------------------------------------------------------------------
# algorithm
# --------------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True, eq=False)
class CogDice(ThresholdSearch):
    """COG-DICE on an environment with a scalar continuous observation; ``init`` / ``ask`` /
    ``evaluate`` / ``tell`` / ``step`` are pure (``algorithms.engine``; see the module
    docstring)."""

    def __post_init__(self):
        env, settings = self.env, self.settings
        if tuple(env.obs_shape) != () or env.obs_range is None:
            raise ConfigError(
                "env.name",
                "COG-DICE needs a scalar continuous observation with a range "
                f"(this simulator has obs_shape {env.obs_shape!r}, obs_range {env.obs_range!r})",
            )
        self._set(
            obs_range=(float(env.obs_range[0]), float(env.obs_range[1])),
            controller=RegionController(
                num_agents=env.num_agents, num_nodes=settings.nodes, num_regions=settings.regions
            ),
        )

    # ---------------------------------------------------------------- distribution / sampling
    def init_distribution(self) -> RegionDistribution:
        a, n, r = self.env.num_agents, self.settings.nodes, self.settings.regions
        return RegionDistribution(
            action_probs=uniform_distribution((a, n, self.env.num_actions), self.env.action_counts),
            transition_probs=uniform_distribution((a, n, r, n)),
            beta_params=jnp.ones((a, n, r - 1, 2), jnp.float32),
        )

    def draw(self, key: jax.Array, dist: RegionDistribution, num: int) -> RegionSample:
        """``num`` deterministic joint controllers (leaves with a leading ``[num]`` axis) and
        their unsorted [0, 1] point draws.

        All draws of the block are made at once: one uniform block per categorical table (inverse
        CDF) and one ``jax.random.beta`` call of shape ``[num, agents, nodes, regions - 1]`` (one
        call for the whole block compiled faster on CPU than a vmapped per-sample call, which
        draws the same distribution)."""
        k_a, k_t, k_p = jax.random.split(key, 3)
        a, b = dist.beta_params[..., 0], dist.beta_params[..., 1]
        unit = jax.random.beta(k_p, a, b, (num,) + a.shape, dtype=jnp.float32)
        return self._assemble(k_a, k_t, unit, dist)

    def _assemble(self, k_a, k_t, unit, dist: RegionDistribution) -> RegionSample:
        num = unit.shape[0]
        u_a = jax.random.uniform(k_a, (num,) + dist.action_probs.shape[:-1])
        u_t = jax.random.uniform(k_t, (num,) + dist.transition_probs.shape[:-1])
        policy = DeterministicRegionPolicy(
            actions=sample_categorical(u_a, dist.action_probs),
            points=jnp.sort(points_from_unit(unit, self.obs_range), axis=-1),
            transitions=sample_categorical(u_t, dist.transition_probs),
        )
        return RegionSample(policy=policy, unit_points=unit)

    @staticmethod
    def policies_of(samples: RegionSample) -> DeterministicRegionPolicy:
        return samples.policy

    def sample_policies(self, key: jax.Array, dist: RegionDistribution) -> RegionSample:
        """``samples`` controllers (leaves with a leading ``[samples]`` axis)."""
        return self.draw(key, dist, self.settings.samples)

    # ---------------------------------------------------------------- update
    def update_distribution(
        self, dist: RegionDistribution, elites: RegionSample, kept, hyper: ThresholdHyper
    ) -> RegionDistribution:
        """Count MLE + smoothing of actions and region transitions over the kept elites' tables,
        Beta refit per slot (>= 2 kept elites). ``elites``: leading ``[elites]`` axis; ``kept
        [elites]`` bool."""
        w = kept.astype(jnp.float32)
        n, a = self.settings.nodes, self.env.num_actions
        act_counts = count_table(jnp.moveaxis(elites.policy.actions, 0, -1), a, w)
        trans_counts = count_table(jnp.moveaxis(elites.policy.transitions, 0, -1), n, w)
        return RegionDistribution(
            action_probs=smooth(dist.action_probs, act_counts, hyper.alpha),
            transition_probs=smooth(dist.transition_probs, trans_counts, hyper.alpha),
            beta_params=refit_betas(
                dist.beta_params,
                elites.unit_points,
                kept,
                hyper.alpha,
                self.settings.beta_eps,
                self.settings.min_denominator,
            ),
        )

    def inject(self, dist: RegionDistribution, injected, hyper: ThresholdHyper):
        """Entropy injection into the categorical parts where ``injected``; Betas unchanged."""
        rate = hyper.entropy.rate
        return dist.replace(
            action_probs=jnp.where(
                injected,
                inject_entropy(dist.action_probs, rate, action_support(self.env)),
                dist.action_probs,
            ),
            transition_probs=jnp.where(
                injected, inject_entropy(dist.transition_probs, rate), dist.transition_probs
            ),
        )

    # ---------------------------------------------------------------- public
    def init(self, key: jax.Array, params: SearchParams) -> CogDiceState:
        """Initial state; its ``best_policy`` is one draw from the initial distribution (the
        first ``step`` replaces it). The initial Betas are Beta(1, 1) = U(0, 1), so the points are
        drawn with ``jax.random.uniform`` -- the same distribution, without compiling the Beta
        sampler a second time."""
        dist = self.init_distribution()
        k_a, k_t, k_p = jax.random.split(key, 3)
        unit = jax.random.uniform(k_p, (1,) + dist.beta_params.shape[:-1])
        first = jax.tree.map(lambda x: x[0], self._assemble(k_a, k_t, unit, dist))
        return CogDiceState(
            distribution=dist,
            best_policy=first.policy,
            progress=Progress.create(self.settings.entropy_window),
        )

    @property
    def rollouts_per_iteration(self) -> int:
        """Simulated rollouts in one ``step``."""
        s = self.settings
        return s.samples * s.eval_rollouts + s.best_rollouts

    def write_plots(self, config, policy, record: dict, out_dir) -> list:
        """``controllers.png``: each agent's region controller as a graph."""
        return region_plots(self.env, policy, record, out_dir)


# ---------------------------------------------------------------------------------------------
# the registry entry: config -> algorithm, hyper-parameters
# ---------------------------------------------------------------------------------------------
def build(config, env, env_params, memory: int | None = None) -> CogDice:
    """The search of ``config`` (``experiment.algorithm = "cogdice"``)."""
    return CogDice(env, fields_from(CogDiceSettings, config.algorithm), memory)


register_algorithm(
    "cogdice",
    CogDiceSection,
    build,
    threshold_hyper,
    dynamic=(*ENTROPY_FIELDS, "algorithm.alpha"),
    overwrite=False,
)
