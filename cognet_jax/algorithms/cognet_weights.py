"""COGNet-DICE by cross-entropy over the node networks' weights: the default ``cognet-dice``.

The policy class is the one of SPEC section 5 (``controllers.neural``): per agent and node an
action distribution and a small MLP ``obs -> hidden (ReLU) -> logits over next nodes``. What
differs from the thesis algorithm (``cognet-dice-thesis``, ``algorithms.cognet_dice``) is the
search: instead of imitating elite rollouts by gradient steps, whole joint controllers are
*sampled* from a distribution over network weights and actions, evaluated with common random
numbers, and the distribution is refit to the elites -- the DICE idea that COG-DICE applies to
its Beta region boundaries, applied to the networks.

Search distribution (``WeightDistribution``, all agents and nodes stacked, H hidden units,
Q nodes, F network inputs):

* ``action_probs [agents, Q, actions]``: one action per node (a deterministic controller);
* hidden layer, diagonal Gaussians: ``w1_mean / w1_std [agents, Q, F, H]``,
  ``b1_mean / b1_std [agents, Q, H]``; initial mean 0, std ``init_scale / sqrt(F)`` for the
  weights and ``init_scale`` for the biases (a unit's threshold ``-b / w`` then falls anywhere in
  the observation range);
* output layer, *structured*: each hidden unit j votes for one next node ``k_j`` with strength
  ``m_j``, and the output bias is a vote ``B`` for one default node ``d``:
  ``W2[j, :] = m_j * onehot(k_j)``, ``b2 = B * onehot(d)``. ``unit_target_probs [agents, Q, H,
  Q]`` and ``default_probs [agents, Q, Q]`` are categorical; ``m_mean / m_std [agents, Q, H]`` and
  ``bias_mean / bias_std [agents, Q]`` Gaussian (initial mean and std ``vote_mean`` /
  ``vote_std``). A threshold on the observation is one ReLU unit voting for a node, so the
  reactive controllers of the tagging problem are a few draws away, and a node's role (which
  next node an observation leads to) is a categorical choice the elites can agree on. A diagonal
  Gaussian over a dense output layer averages the roles of different elites; in prototypes (not
  kept) it stalled below the reactive controller on tagging n3.

**Input standardisation** (``standardize_inputs``, **[choice]**, off by default): the Gaussians
are then over a network that reads ``(x - mean) / scale`` per input feature, where ``mean`` and
``scale [agents, F]`` are the features' mean and standard deviation over the observations of
``STATS_ROLLOUTS`` rollouts of the uniformly random controller (fixed key, so every seed of a
run sees the same constants). ``to_policy`` folds them into the first layer (``W1 / scale``,
``b1 - (mean / scale) . W1``), so the policy still reads the raw features. Without it a hidden
unit's threshold ``-b / w`` is spread over the scale of ``init_scale``; on the raw heatmap patch
(pixels in [0, 1], most positions differing by a few hundredths) almost no sampled unit then
splits the positions that matter.

The sampled network is an ordinary ``NeuralPolicy`` (softmax over the logits; with votes of
about 5 the draw is nearly deterministic), so evaluation, ``controller_step`` and saved policies
are those of the thesis algorithm.

One iteration (``step``), values are returns to **maximise**:

1. draw ``candidates`` joint controllers (every agent and node independently);
2. evaluate each with ``eval_rollouts`` rollouts (common random numbers: one key for all);
3. elites: the best ``elites`` candidates (**[choice]** no rising threshold: with common random
   numbers and a fixed population the top fraction is the classic CE rule; the threshold
   ``V_w`` reported is the smallest elite value);
4. refit with smoothing rate ``alpha``: categoricals by count MLE over the elites, Gaussians by
   the elites' mean and standard deviation (``new = alpha * fit + (1 - alpha) * old``); then
   every categorical is mixed with the uniform distribution, ``(1 - floor) * p + floor / K``
   (``action_floor`` for actions, ``category_floor`` for the output-layer categoricals), so no
   choice ever becomes impossible (a constant entropy injection instead of SPEC's triggered
   one);
5. anytime best (**[choice]**): the iteration's winner and the distribution's mode (Gaussian
   means, most likely categories) are each evaluated on ``best_rollouts`` fresh rollouts; the
   best of the two replaces the best policy when it beats the best fresh value so far. The
   value recorded per iteration is that fresh value, never the winner's in-loop mean.
   With ``paired_best`` the current best policy is re-evaluated too, on the *same* fresh
   rollouts as the two challengers (common random numbers), and a challenger replaces it only
   when it beats that paired estimate: the comparison's noise is then the noise of a
   difference between similar policies, and the best fresh value so far, the maximum of
   hundreds of noisy means, no longer decides (its upward bias is the anytime best's
   winner's curse). ``best_value`` is then the best policy's estimate of this iteration.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
from flax import struct

from cognet_jax.algorithms.cross_entropy import (
    Progress,
    count_table,
    inject_entropy,
    select_tree,
    smooth,
)
from cognet_jax.algorithms.engine import Search, SearchParams, streams
from cognet_jax.config import (
    NetworkSection,
    require,
    require_positive,
    require_probability,
    settings_class,
)
from cognet_jax.controllers.base import action_support, sample_categorical, uniform_distribution
from cognet_jax.controllers.neural import NeuralPolicy
from cognet_jax.memory import trace_checked
from cognet_jax.observations import (
    ObservationPipeline,
    build_pipeline,
    check_network,
    neural_controller,
)
from cognet_jax.prng import fast_key
from cognet_jax.registry import fields_from, register_algorithm
from cognet_jax.rollout import rollouts


@struct.dataclass
class WeightDistribution:
    """Search distribution over joint neural controllers (see the module docstring)."""

    action_probs: jax.Array  # [agents, Q, actions]
    w1_mean: jax.Array  # [agents, Q, F, H]
    w1_std: jax.Array  # [agents, Q, F, H]
    b1_mean: jax.Array  # [agents, Q, H]
    b1_std: jax.Array  # [agents, Q, H]
    unit_target_probs: jax.Array  # [agents, Q, H, Q]
    m_mean: jax.Array  # [agents, Q, H]
    m_std: jax.Array  # [agents, Q, H]
    default_probs: jax.Array  # [agents, Q, Q]
    bias_mean: jax.Array  # [agents, Q]
    bias_std: jax.Array  # [agents, Q]


@struct.dataclass
class WeightSample:
    """The draws of one candidate (leaves without the candidate axis)."""

    actions: jax.Array  # [agents, Q] int32
    w1: jax.Array  # [agents, Q, F, H]
    b1: jax.Array  # [agents, Q, H]
    unit_targets: jax.Array  # [agents, Q, H] int32
    m: jax.Array  # [agents, Q, H]
    default: jax.Array  # [agents, Q] int32
    bias: jax.Array  # [agents, Q]


@dataclasses.dataclass
class CognetWeightsSection:
    """``[algorithm]`` of the default ``cognet-dice`` (this module). Per iteration
    ``candidates`` joint controllers, each evaluated with ``eval_rollouts`` rollouts (common
    random numbers), the best ``elites`` refit the distribution with smoothing ``alpha``;
    ``action_floor`` / ``category_floor`` mix the categoricals with the uniform distribution
    every iteration; the winner and the distribution's mode are re-evaluated on
    ``best_rollouts`` fresh rollouts for the anytime best. ``init_scale``: initial std of the
    hidden layer (``init_scale / sqrt(inputs)`` for the weights); ``vote_mean`` /
    ``vote_std``: initial Gaussian of the output votes; ``standardize_inputs``: search over a
    network that reads each input feature standardised by its mean and standard deviation under
    the random controller; ``paired_best``: the best policy so far is re-evaluated on the
    challengers' fresh rollouts and replaced only when a challenger beats it there. The hidden
    width is ``network.hidden``."""

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

    def rollouts_per_iteration(self) -> int:
        """Rollouts one iteration simulates (the size checks of ``api.check_budget``)."""
        return rollouts_per_iteration(self)

    def check(self, config) -> None:
        names = ("nodes", "iterations", "candidates", "eval_rollouts", "elites", "best_rollouts")
        require_positive(self, "algorithm", *names)
        require(
            self.elites <= self.candidates,
            "algorithm.elites",
            f"elites ({self.elites}) cannot exceed algorithm.candidates ({self.candidates})",
        )
        require(self.elites >= 2, "algorithm.elites", "needs >= 2 to fit a standard deviation")
        require_probability(self, "algorithm", "alpha", "action_floor", "category_floor")
        for name in ("init_scale", "vote_mean", "vote_std"):
            v = getattr(self, name)
            require(v >= 0, f"algorithm.{name}", f"must be >= 0, got {v}")
        require(self.init_scale > 0, "algorithm.init_scale", "must be > 0")
        defaults = NetworkSection()
        for name in ("train_steps", "optimizer", "learning_rate", "momentum"):
            require(
                getattr(config.network, name) == getattr(defaults, name),
                f"network.{name}",
                "trains the node networks of cognet-dice-thesis; the default cognet-dice "
                "samples network weights and has no optimiser",
            )
        check_network(config, training=False)
        require(
            not config.network.augment,
            "network.augment",
            "VAE augmentation adds training pairs; the weight-space cognet-dice trains no "
            "network (use experiment.algorithm = 'cognet-dice-thesis')",
        )


def rollouts_per_iteration(s) -> int:
    """Rollouts one iteration of the settings (or section) ``s`` simulates: the candidates'
    evaluations plus the fresh evaluations of the winner and of the mode (and of the best so
    far, ``paired_best``)."""
    return s.candidates * s.eval_rollouts + (3 if s.paired_best else 2) * s.best_rollouts


@struct.dataclass
class WeightsHyper:
    """Dynamic (sweepable) hyper-parameters; defaults those of the config section."""

    alpha: jax.Array | float = CognetWeightsSection.alpha
    action_floor: jax.Array | float = CognetWeightsSection.action_floor
    category_floor: jax.Array | float = CognetWeightsSection.category_floor


#: static settings: the fields of ``CognetWeightsSection`` without the hyper-parameters
#: (``WeightsHyper``), and the hidden width ``network.hidden``
WeightsSettings = settings_class(
    "WeightsSettings",
    CognetWeightsSection,
    exclude=("alpha", "action_floor", "category_floor"),
    extra=((NetworkSection, "hidden"),),
)


#: Rollouts of the uniformly random controller that give the input statistics.
STATS_ROLLOUTS = 4096


@struct.dataclass
class WeightsState:
    distribution: WeightDistribution
    best_policy: NeuralPolicy
    progress: Progress


@struct.dataclass
class WeightsMetrics:
    value: jax.Array  # [] fresh value of the better of (winner, mode) this iteration
    best_value: jax.Array  # [] best fresh value so far
    mean_value: jax.Array  # [] mean candidate value (in-loop)
    winner_value: jax.Array  # [] largest candidate value (in-loop, optimistic)
    threshold: jax.Array  # [] smallest elite value
    kept: jax.Array  # [] number of elites
    injected: jax.Array  # [] always False (the floors act every iteration)


def _gaussian_refit(mean, std, elite_draws, alpha):
    """``alpha * (elite mean, elite std) + (1 - alpha) * (mean, std)``; ``elite_draws [E, ...]``."""
    return (
        alpha * elite_draws.mean(0) + (1.0 - alpha) * mean,
        alpha * elite_draws.std(0) + (1.0 - alpha) * std,
    )


def input_statistics(env, controller, pipeline, env_params, memory=None):
    """``(mean, scale) [agents, F]`` of the networks' input features over the observations
    of ``STATS_ROLLOUTS`` rollouts of the uniformly random controller (key 0) under
    ``env_params``; a feature that never varies gets scale 1. Their trajectories must fit
    ``memory`` bytes (``memory.trace_checked``)."""
    template = controller.init(jax.random.key(0))  # uniform actions; zero nets: uniform nodes
    uniform = template.replace(net_params=jax.tree.map(jnp.zeros_like, template.net_params))
    record = jax.jit(
        lambda k: rollouts(env, controller, k, STATS_ROLLOUTS, env_params, uniform, record=True)
    )
    what = f"the input statistics ({STATS_ROLLOUTS} recorded rollouts)"
    trace_checked(record, (jax.random.key(0),), memory, what)
    traj = record(jax.random.key(0))
    feats = pipeline.features(traj.obs)  # [R, H, agents, *feature_shape]
    feats = feats.reshape(feats.shape[:3] + (-1,))
    mean, std = feats.mean((0, 1)), feats.std((0, 1))
    return mean, jnp.where(std > 1e-6, std, 1.0)


@dataclasses.dataclass(frozen=True, eq=False)
class CognetWeights(Search):
    """COGNet-DICE with cross-entropy over node-network weights; ``init`` / ``ask`` /
    ``evaluate`` / ``tell`` / ``step`` are pure (the protocol of ``algorithms.engine``).

    ``pipeline`` maps the environment's observations to the networks' input (identity, or the
    patch VAE's encoder mean; ``cognet_jax.observations``). ``input_stats``: ``(mean, scale)
    [agents, F]`` of the input features (``input_statistics``), needed with
    ``standardize_inputs`` -- a fixed reparametrisation of the search space, computed once
    under the config's env params (``build``), not a function of the params a search runs
    with.
    """

    pipeline: ObservationPipeline | None = None
    input_stats: tuple | None = None

    def __post_init__(self):
        s = self.settings
        pipeline, controller = neural_controller(self.env, s.nodes, s.hidden, self.pipeline)
        if s.standardize_inputs and self.input_stats is None:
            raise ValueError("standardize_inputs needs input_stats (input_statistics)")
        self._set(pipeline=pipeline, controller=controller)

    # ---------------------------------------------------------------- distribution
    def init_distribution(self) -> WeightDistribution:
        s, c = self.settings, self.controller
        a, q, h, f = c.num_agents, s.nodes, s.hidden, c.in_features
        full = lambda shape, v: jnp.full(shape, v, jnp.float32)  # noqa: E731
        return WeightDistribution(
            action_probs=uniform_distribution((a, q, c.num_actions), self.env.action_counts),
            w1_mean=full((a, q, f, h), 0.0),
            w1_std=full((a, q, f, h), s.init_scale / math.sqrt(f)),
            b1_mean=full((a, q, h), 0.0),
            b1_std=full((a, q, h), s.init_scale),
            unit_target_probs=full((a, q, h, q), 1.0 / q),
            m_mean=full((a, q, h), s.vote_mean),
            m_std=full((a, q, h), s.vote_std),
            default_probs=full((a, q, q), 1.0 / q),
            bias_mean=full((a, q), s.vote_mean),
            bias_std=full((a, q), s.vote_std),
        )

    def draw(self, key: jax.Array, dist: WeightDistribution, num: int) -> WeightSample:
        """``num`` candidates (leaves with a leading ``[num]`` axis). The draws go through
        ``prng.fast_key`` (the same numbers; JAX's own CPU threefry made this iteration compile
        about 3 s slower)."""
        ks = jax.random.split(fast_key(key), 7)

        def normal(k, mean, std):
            return mean + std * jax.random.normal(k, (num,) + mean.shape, jnp.float32)

        def categorical(k, probs):
            return sample_categorical(jax.random.uniform(k, (num,) + probs.shape[:-1]), probs)

        return WeightSample(
            actions=categorical(ks[0], dist.action_probs),
            w1=normal(ks[1], dist.w1_mean, dist.w1_std),
            b1=normal(ks[2], dist.b1_mean, dist.b1_std),
            unit_targets=categorical(ks[3], dist.unit_target_probs),
            m=normal(ks[4], dist.m_mean, dist.m_std),
            default=categorical(ks[5], dist.default_probs),
            bias=normal(ks[6], dist.bias_mean, dist.bias_std),
        )

    def mode(self, dist: WeightDistribution) -> WeightSample:
        """The most likely controller: Gaussian means and the most likely categories."""
        return WeightSample(
            actions=jnp.argmax(dist.action_probs, -1).astype(jnp.int32),
            w1=dist.w1_mean,
            b1=dist.b1_mean,
            unit_targets=jnp.argmax(dist.unit_target_probs, -1).astype(jnp.int32),
            m=dist.m_mean,
            default=jnp.argmax(dist.default_probs, -1).astype(jnp.int32),
            bias=dist.bias_mean,
        )

    def to_policy(self, sample: WeightSample) -> NeuralPolicy:
        """The ``NeuralPolicy`` of one sample (works on a leading candidate axis too): one-hot
        actions, ``W2 = m * onehot(unit_targets)``, ``b2 = bias * onehot(default)``."""
        q, na = self.settings.nodes, self.env.num_actions
        w1, b1 = sample.w1, sample.b1
        if self.settings.standardize_inputs:  # fold (x - mean) / scale into the first layer
            input_mean, input_scale = self.input_stats
            lead = w1.ndim - 4  # a candidate axis or none; w1 [..., agents, Q, F, H]
            scale = input_scale.reshape((1,) * lead + input_scale.shape[:1] + (1, -1, 1))
            shift = (input_mean / input_scale).reshape(scale.shape)
            b1 = b1 - jnp.sum(shift * w1, axis=-2)
            w1 = w1 / scale
        w2 = sample.m[..., None] * jax.nn.one_hot(sample.unit_targets, q, dtype=jnp.float32)
        b2 = sample.bias[..., None] * jax.nn.one_hot(sample.default, q, dtype=jnp.float32)
        params = {
            "params": {
                "Dense_0": {"kernel": w1, "bias": b1},
                "Dense_1": {"kernel": w2, "bias": b2},
            }
        }
        return NeuralPolicy(
            action_probs=jax.nn.one_hot(sample.actions, na, dtype=jnp.float32),
            net_params=params,
        )

    def update_distribution(
        self, dist: WeightDistribution, elites: WeightSample, hyper: WeightsHyper
    ) -> WeightDistribution:
        """Refit to ``elites`` (leading ``[E]`` axis) with smoothing, then the uniform floors."""
        alpha, q = hyper.alpha, self.settings.nodes

        def categorical(old, draws, k, floor, support=None):
            counts = count_table(jnp.moveaxis(draws, 0, -1), k)
            return inject_entropy(smooth(old, counts, alpha), floor, support)

        w1_mean, w1_std = _gaussian_refit(dist.w1_mean, dist.w1_std, elites.w1, alpha)
        b1_mean, b1_std = _gaussian_refit(dist.b1_mean, dist.b1_std, elites.b1, alpha)
        m_mean, m_std = _gaussian_refit(dist.m_mean, dist.m_std, elites.m, alpha)
        bias_mean, bias_std = _gaussian_refit(dist.bias_mean, dist.bias_std, elites.bias, alpha)
        return WeightDistribution(
            action_probs=categorical(
                dist.action_probs,
                elites.actions,
                self.env.num_actions,
                hyper.action_floor,
                action_support(self.env),
            ),
            w1_mean=w1_mean,
            w1_std=w1_std,
            b1_mean=b1_mean,
            b1_std=b1_std,
            unit_target_probs=categorical(
                dist.unit_target_probs, elites.unit_targets, q, hyper.category_floor
            ),
            m_mean=m_mean,
            m_std=m_std,
            default_probs=categorical(dist.default_probs, elites.default, q, hyper.category_floor),
            bias_mean=bias_mean,
            bias_std=bias_std,
        )

    # ---------------------------------------------------------------- protocol
    def init(self, key: jax.Array, params: SearchParams) -> WeightsState:
        """Initial state; its ``best_policy`` is one draw of the initial distribution."""
        dist = self.init_distribution()
        first = jax.tree.map(lambda x: x[0], self.draw(key, dist, 1))
        return WeightsState(
            distribution=dist, best_policy=self.to_policy(first), progress=Progress.create(1)
        )

    @property
    def rollouts_per_iteration(self) -> int:
        """Simulated rollouts in one ``step`` (``rollouts_per_iteration``)."""
        return rollouts_per_iteration(self.settings)

    def ask(self, key: jax.Array, state: WeightsState, params: SearchParams):
        """``(samples, policies)``: ``candidates`` joint controllers drawn from the state's
        distribution (leading ``[candidates]`` axis), from the ``sample`` stream."""
        samples = self.draw(streams(key).sample, state.distribution, self.settings.candidates)
        return samples, self.to_policy(samples)

    def tell(
        self,
        key: jax.Array,
        state: WeightsState,
        samples: WeightSample,
        values: jax.Array,
        params: SearchParams,
        *,
        fresh_value=None,
    ):
        """The state after ``values [candidates]`` of ``samples``; returns ``(state,
        WeightsMetrics)``. The winner is valued on the ``best`` stream, the mode on the
        ``other`` one; ``fresh_value(key, policy) -> value`` replaces their ``best_rollouts``
        fresh rollouts of the simulator."""
        hyper = params.hyper
        if fresh_value is None:
            fresh_value = lambda k, p: self.fresh_value(k, p, params)  # noqa: E731
        s = self.settings
        k = streams(key)
        elite_values, elite_idx = jax.lax.top_k(values, s.elites)
        elites = jax.tree.map(lambda x: x[elite_idx], samples)
        dist = self.update_distribution(state.distribution, elites, hyper)

        winner = self.to_policy(jax.tree.map(lambda x: x[0], elites))
        mode = self.to_policy(self.mode(dist))
        stack = lambda *trees: jax.tree.map(lambda *xs: jnp.stack(xs), *trees)  # noqa: E731
        if s.paired_best:  # winner, mode and the best so far on the same fresh rollouts
            v_winner, v_mode, v_best = jax.vmap(fresh_value, (None, 0))(
                k.best, stack(winner, mode, state.best_policy)
            )
        else:  # one batched program for both (vmap over keys draws what two calls would draw)
            v_winner, v_mode = jax.vmap(fresh_value)(
                jnp.stack([k.best, k.other]), stack(winner, mode)
            )
        mode_better = v_mode > v_winner
        candidate = select_tree(mode_better, mode, winner)
        value = jnp.maximum(v_mode, v_winner)
        progress, improved = state.progress.record(value)
        progress = progress.replace(threshold=elite_values[-1])
        if s.paired_best:
            improved = value > v_best
            progress = progress.replace(best_value=jnp.maximum(value, v_best))
        best_policy = select_tree(improved, candidate, state.best_policy)
        metrics = WeightsMetrics(
            value=value,
            best_value=progress.best_value,
            mean_value=values.mean(),
            winner_value=elite_values[0],
            threshold=elite_values[-1],
            kept=jnp.int32(s.elites),
            injected=jnp.bool_(False),
        )
        return WeightsState(distribution=dist, best_policy=best_policy, progress=progress), metrics


# ---------------------------------------------------------------------------------------------
# the registry entry: config -> algorithm, hyper-parameters
# ---------------------------------------------------------------------------------------------
def build(config, env, env_params, memory: int | None = None) -> CognetWeights:
    """The search of ``config`` (``[algorithm]`` with ``experiment.algorithm = "cognet-dice"``,
    ``[network]``) on ``env``; with ``standardize_inputs`` the input statistics are those of
    ``env_params`` (``input_statistics``)."""
    settings = fields_from(WeightsSettings, config.algorithm, config.network)
    pipeline, controller = neural_controller(
        env, settings.nodes, settings.hidden, build_pipeline(config, env)
    )
    stats = None
    if settings.standardize_inputs:
        stats = input_statistics(env, controller, pipeline, env_params, memory)
    return CognetWeights(env, settings, memory, pipeline, stats)


def hyper(config) -> WeightsHyper:
    """The dynamic hyper-parameters of ``config.algorithm``."""
    return fields_from(WeightsHyper, config.algorithm)


register_algorithm(
    "cognet-dice",
    CognetWeightsSection,
    build,
    hyper,
    dynamic=("algorithm.alpha", "algorithm.action_floor", "algorithm.category_floor"),
    reads=("network",),
    overwrite=False,
)
