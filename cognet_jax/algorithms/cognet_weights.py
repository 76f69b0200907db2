"""COGNet-DICE by cross-entropy over the node networks' weights: the default ``cognet-dice``.

The policy class is the one of SPEC section 5 (``controllers.neural``): per agent and node an
action distribution and a small MLP ``obs -> hidden (ReLU) -> logits over next nodes``. What
differs from the thesis algorithm (``cognet-dice-thesis``, ``algorithms.cognet_thesis``) is the
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
  ``vote_std``, the default vote's times ``default_vote_scale``). A threshold on the observation
  is one ReLU unit voting for a node, so the reactive controllers of the tagging problem are a
  few draws away, and a node's role (which next node an observation leads to) is a categorical
  choice the elites can agree on (a diagonal Gaussian over a dense output layer would average
  the roles of different elites).

**Default vote's scale** (``default_vote_scale``, **[choice]**, "auto": 10 where the horizon
is longer than the nodes, 1 otherwise, ``resolve_search``): a unit's vote is ``m_j`` times its
pre-activation, whose initial spread is about ``init_scale`` (10); a default vote of
``vote_mean`` (5) loses to any unit a tenth of an observation unit past its threshold, so "do
the default unless an observation is far enough out" -- stop near the beacon -- needs every
unit's threshold moved at once; at 10 (the units' scale) it is one draw away. Where every step
can run a node of its own (horizon <= nodes) the next node is the observation's to decide, and
the scale of 1 keeps the units in charge. ``vote_alternate`` alternates the exploring searches
between scale 1 (the first) and ``default_vote_scale``; ``vote_first`` starts with a search at
``default_vote_scale`` and ``vote_restart_tol`` ends those searches at their own tolerance;
``tied_vote_scale`` scales the default vote of tied (reactive) candidates only. None of the
three is on by default: the horizon decides instead (the measurements: experiments/NOTES.md).

**Tied structure** (``tie_structure``, **[choice]**, on by default): every candidate also
draws, per agent, whether all its nodes run node 0's network (``node_tie``: the next node then
depends on the observation only, the reactive controllers practitioners write) and whether
every agent runs agent 0's whole controller (``agent_tie``, when the agents have the same
actions). Both are categoricals refit to the elites like the others; the Gaussians are refit to
the weights the candidates ran, so a tied elite teaches every node. A problem that needs
memory or asymmetric agents unties them (the Dec-Tiger counters do).

**Distinct actions** (``distinct_actions``, **[choice]**, "auto": ``covers_rarely``): where
the controller has as many nodes as an agent has actions and independent draws rarely give a
candidate every action (5 nodes, 5 actions: 1 in 26), every candidate also draws, per agent,
whether its nodes' actions are drawn without repeats until every action has a node
(``weight_space.distinct_draw``, on the same uniforms); the flag is a categorical refit to the
elites like the tie flags. A reactive controller that moves four ways and stays is then one
draw away.

**Restarts** (``restart_tol``, **[choice]**, "auto": 0.1 where the horizon is longer than
the nodes, 0.02 otherwise, with ``default_vote_scale``): once the hidden layer's Gaussians
have shrunk below ``restart_tol`` of their initial spread the distribution has converged (the
elites agree and the search draws nearly one controller); the next iteration starts from the
initial distribution again, the anytime best kept. A larger budget then buys further
independent searches instead of iterations of a frozen one; a seed stuck in a poor optimum gets
another start (metrics ``restarted`` marks the iterations that restarted; results.json
``restarts`` counts them). Shorter searches fit
more of them before the refine phase, which the long-horizon problems need and tagging's
thesis setting does not (experiments/NOTES.md).

**Refine** (``refine``, ``refine_scale``, **[choice]**): the last ``refine`` share of the
iterations searches around the kept policy: the distribution restarts centred on it (Gaussian
means at its weights, spreads ``refine_scale`` of the initial ones, categoricals on its choices
mixed with ``refine_scale`` of the uniform), and a converged distribution restarts there again,
around the policy kept by then (converged: below ``refine_tol`` of the spread it started
from; "auto" as ``restart_tol``: 0.1 or 0.2). Candidates close to the kept policy share most
rollouts' trajectories under common random numbers, so small improvements of its thresholds
show.
``starts`` (1 by default) splits the iterations before it into that many independent searches
of equal length, each from the initial distribution.

**Redrawn units** (``refine_redraw``, **[choice]**, "auto": 0.5 on a scalar observation, 0
otherwise, ``redraw_share``): in the refine phase that share of the candidates redraws one
hidden unit (input weights, bias, target node, vote) from the initial distribution
(``weight_space.redraw_unit``). Narrow Gaussians around the kept policy
tune its thresholds but cannot add a region it lacks; most of a converged controller's units
have no say, and a broad redraw of one of them can give it one (the chase's "step back along
x" at both ends of the bearing's range: 8-seed sweeps in experiments/NOTES.md).
``refine_levels`` (1) splits the refine phase into that many parts, each centred on the kept
policy at ``refine_tol`` of the spread of the one before (coarse to fine).

**Kept policies decide** (``kept_sharpness``, **[choice]**, 10): the policies the anytime
best keeps (winner, mode, pool) have their votes multiplied, so the controller handed back
takes the argmax next node where a candidate's softmax still draws near a threshold (about
a tenth of an observation unit): the thresholds a hand-written controller puts exactly at an
integer distance (tagging's paper setting) then hold. ``vote_sharpness`` does the same for
every candidate (off: it changes the search's landscape, experiments/NOTES.md).

**Polish** (``polish_share``, **[choice]**, 0.25): after the last iteration the kept policy
is improved one change at a time (a threshold, a vote's next node, an action, a unit made a
threshold on one feature, the start node's role), each valued on the policy's own rollouts and
applied when it also wins on fresh ones, within that share of the search's rollouts, up to
twice it while every sweep moves (``algorithms.weight_polish``; experiments/NOTES.md).

**Input standardisation** (``standardize_inputs``, **[choice]**, "auto": on where the inputs
are narrow or far off centre, ``missed_inputs``; experiments/NOTES.md): the Gaussians are then
over a network that reads ``(x - mean) / scale`` per input feature, ``mean`` and ``scale
[agents, F]`` the features' mean and standard deviation over ``STATS_ROLLOUTS`` rollouts of the
uniformly random controller (fixed key: every seed of a run sees the same constants).
``to_policy`` folds them into the first layer (``W1 / scale``, ``b1 - (mean / scale) . W1``),
so the policy still reads the raw features. Without it a hidden unit's threshold ``-b / w`` is
spread over the scale of ``init_scale`` around 0; on the raw heatmap patch (pixels in [0, 1],
most positions differing by a few hundredths) almost no sampled unit then splits the positions
that matter, and on a reading offset far from 0 none does.

**Whitened inputs** (``whiten_inputs``, off by default): the network reads ``(x - mean) @
transform`` instead, the PCA whitening of the features' covariance under the random
controller (``input_whitening``), folded the same way (``W1 -> transform @ W1``): a patch's
mean level and gradients become features. **[choice]** Off: on the plume it gave 17.952
(worst 16.717) against 17.732 (worst 16.557), within the seeds' spread; the search's diagonal
Gaussians depend on the basis, and the principal basis is fixed only up to rotations among
equal variances (experiments/NOTES.md, "Whitened inputs").

The sampled network is an ordinary ``NeuralPolicy`` (softmax over the logits), so evaluation,
``controller_step`` and saved policies are those of the thesis algorithm.

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
5. anytime best (**[choice]**): the iteration's winner and the distribution's mode are
   evaluated on ``best_rollouts`` fresh rollouts; the better of the two is the challenger.
   With ``best_pool = P > 0`` (default) it races a pool of the P best policies seen, all
   re-evaluated on the same fresh rollouts every iteration (``algorithms.best_pool``: the kept
   policy is the member with the largest lower confidence bound, so the winner's curse of a
   maximum over hundreds of noisy means does not decide). With ``best_pool = 0`` (or with
   ``paired_best``, which replaces the pool: older configs run as they did) the challenger
   replaces the best policy when its fresh value beats the best fresh value so far (the
   winner on the ``fresh`` stream, the mode on the ``other``); ``paired_best`` compares on
   the challengers' rollouts instead. The value recorded per iteration is the challenger's
   fresh value, never an in-loop mean.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
from flax import struct

from cognet_jax.algorithms.best_pool import BestPool, race
from cognet_jax.algorithms.cognet_weights_settings import (
    WeightsHyper,
    fresh_start,
    pool_size,
    refine_start,
    resolve_search,
    rollouts_per_iteration,
)
from cognet_jax.algorithms.cross_entropy import Progress, select_tree
from cognet_jax.algorithms.engine import SearchParams, streams
from cognet_jax.algorithms.neural_search import NeuralSearch
from cognet_jax.algorithms.sizing import sized
from cognet_jax.algorithms.weight_polish import PolishFinish, polish_seed
from cognet_jax.algorithms.weight_space import (
    WeightDistribution,
    WeightSample,
    centered,
    draw_actions,
    fold_inputs,
    mode_of,
    redraw_unit,
    refit,
    sample_of,
    started,
    tie,
    unfold_inputs,
)
from cognet_jax.controllers.base import action_support, sample_categorical, uniform_distribution
from cognet_jax.controllers.neural import NeuralPolicy
from cognet_jax.observations import (
    ObservationPipeline,
    neural_controller,
)
from cognet_jax.prng import fast_key

#: the stream of the ``distinct_actions`` flags: the iteration's key folded with this number
#: (with partitionable threefry, folding with ``i`` gives ``split(key, n)[i]``: a small number
#: would reuse a stream of ``draw``)
DISTINCT_STREAM = 0x64697374
#: the streams of the refine phase's unit redraws (``refine_redraw``) and of the start
#: roles (``start_draw``), likewise
REDRAW_STREAM, START_STREAM = 0x72647277, 0x73747274


@struct.dataclass
class WeightsState:
    distribution: WeightDistribution
    best_policy: NeuralPolicy
    progress: Progress
    pool: BestPool | None = None  # the race of the best policies (``best_pool`` > 0)
    searches: jax.Array | None = None  # [] int32 restarts so far (``vote_alternate``)
    # [2] uint32: the polish's key, as bits (a checkpoint holds no typed key; ``polish_key``)
    polish_seed: jax.Array | None = None


@struct.dataclass
class WeightsMetrics:
    value: jax.Array  # [] fresh value of the better of (winner, mode) this iteration
    in_loop_best: jax.Array  # [] the kept policy's estimate: best fresh value so far, or with a
    # pool the kept member's mean over its evaluations (not monotone)
    mean_value: jax.Array  # [] mean candidate value (in-loop)
    top_value: jax.Array  # [] largest candidate value (in-loop, optimistic)
    threshold: jax.Array  # [] smallest elite value
    kept: jax.Array  # [] number of elites
    restarted: jax.Array  # [] the distribution converged: restarted (``restart_tol``)


@dataclasses.dataclass(frozen=True, eq=False)
class CognetWeights(PolishFinish, NeuralSearch):
    """COGNet-DICE with cross-entropy over node-network weights; ``init`` / ``ask`` /
    ``evaluate`` / ``tell`` / ``step`` are pure (the protocol of ``algorithms.engine``).

    ``pipeline`` maps the environment's observations to the networks' input (identity, or the
    patch VAE's encoder mean; ``cognet_jax.observations``). ``input_stats``: ``(mean, scale)
    [agents, F]`` of the input features (``input_statistics``), or with ``whiten_inputs``
    ``(mean [agents, F], transform [agents, F, F])`` (``input_whitening``), needed with
    ``standardize_inputs`` -- a fixed reparametrisation of the search space, computed once
    under the config's env params (``build``), not a function of the params a search runs
    with. ``feature_scale [agents, F]``: the input features' spread the polish measures its
    threshold shifts in (``input_statistics``' scale; None: 1), ``feature_mean [agents, F]``
    their mean, where its AXIS moves put thresholds (None: 0).
    """

    pipeline: ObservationPipeline | None = None
    input_stats: tuple | None = None
    feature_scale: jax.Array | None = None
    feature_mean: jax.Array | None = None

    def __post_init__(self):
        s = resolve_search(sized(self.settings, self.env), self.env)  # settings made in code
        if s.standardize_inputs == "auto":  # made in code without a decision: as the stats say
            s = dataclasses.replace(s, standardize_inputs=self.input_stats is not None)
        pipeline, controller = neural_controller(self.env, s.nodes, s.hidden, self.pipeline)
        if s.standardize_inputs and self.input_stats is None:
            raise ValueError("standardize_inputs needs input_stats (input_statistics)")
        self._set(settings=s, pipeline=pipeline, controller=controller)

    # ---------------------------------------------------------------- distribution
    def init_distribution(self, vote_scale=None) -> WeightDistribution:
        """The initial distribution; ``vote_scale`` (``[]``, default ``default_vote_scale``)
        scales the default vote's Gaussian."""
        s, c = self.settings, self.controller
        vote_scale = s.default_vote_scale if vote_scale is None else vote_scale
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
            bias_mean=full((a, q), s.vote_mean) * vote_scale,
            bias_std=full((a, q), s.vote_std) * vote_scale,
            node_tie_probs=full((a, 2), 0.5 if s.tie_structure else 0.0)
            .at[:, 0]
            .set(0.5 if s.tie_structure else 1.0),
            agent_tie_probs=jnp.array(
                [0.5, 0.5] if self._agents_can_tie else [1.0, 0.0], jnp.float32
            ),
            distinct_probs=full((a, 2), 0.5) if s.distinct_actions else None,
            redraw=full((), 0.0) if s.refine_redraw > 0 and s.refine > 0 else None,
            start_probs=self._first_start_probs() if s.start_draw else None,
        )

    def _first_start_probs(self) -> jax.Array:
        """``[agents, nodes]``: ``start_spread`` of the mass evenly on every node, the rest
        on node 0 (where a controller starts without ``start_draw``)."""
        a, q, spread = self.controller.num_agents, self.settings.nodes, self.settings.start_spread
        probs = jnp.full((a, q), spread / q, jnp.float32)
        return probs.at[:, 0].add(1.0 - spread)

    @property
    def _agents_can_tie(self) -> bool:
        """Agent tying is searched over (``tie_structure``) when every agent has the same
        actions and there is more than one agent."""
        counts = self.env.action_counts
        return self.settings.tie_structure and len(counts) > 1 and len(set(counts)) == 1

    def draw(self, key: jax.Array, dist: WeightDistribution, num: int) -> WeightSample:
        """``num`` candidates (leaves with a leading ``[num]`` axis). The draws go through
        ``prng.fast_key`` (the same numbers; JAX's own CPU threefry compiles this iteration
        more slowly). The flags of ``distinct_actions`` have a stream of their own (the
        key folded with ``DISTINCT_STREAM``: folding with a small number gives a key of the
        split above), so the other draws are those of a search without them."""
        ties = self.settings.tie_structure
        ks = jax.random.split(fast_key(key), 9 if ties else 7)  # untied: the draws of before

        def normal(k, mean, std):
            return mean + std * jax.random.normal(k, (num,) + mean.shape, jnp.float32)

        def categorical(k, probs):
            return sample_categorical(jax.random.uniform(k, (num,) + probs.shape[:-1]), probs)

        distinct = None
        if dist.distinct_probs is not None:
            flag_key = jax.random.fold_in(fast_key(key), DISTINCT_STREAM)
            distinct = categorical(flag_key, dist.distinct_probs)
        untied = (jnp.zeros((num, self.env.num_agents), jnp.int32), jnp.zeros(num, jnp.int32))
        sample = WeightSample(
            actions=draw_actions(ks[0], dist.action_probs, num, distinct, action_support(self.env)),
            w1=normal(ks[1], dist.w1_mean, dist.w1_std),
            b1=normal(ks[2], dist.b1_mean, dist.b1_std),
            unit_targets=categorical(ks[3], dist.unit_target_probs),
            m=normal(ks[4], dist.m_mean, dist.m_std),
            default=categorical(ks[5], dist.default_probs),
            bias=normal(ks[6], dist.bias_mean, dist.bias_std),
            node_tie=categorical(ks[7], dist.node_tie_probs) if ties else untied[0],
            agent_tie=categorical(ks[8], dist.agent_tie_probs) if ties else untied[1],
            distinct=distinct,
        )
        if dist.start_probs is not None:  # the start roles, on their own stream
            start_key = jax.random.fold_in(fast_key(key), START_STREAM)
            sample = sample.replace(start=categorical(start_key, dist.start_probs))
        if dist.redraw is not None:  # the refine phase's redrawn units, on their own stream
            redraw_key = jax.random.fold_in(fast_key(key), REDRAW_STREAM)
            sample = redraw_unit(redraw_key, sample, self.init_distribution(), dist.redraw)
        return tie(sample) if ties else sample

    def mode(self, dist: WeightDistribution) -> WeightSample:
        """The most likely controller (``weight_space.mode_of``)."""
        return mode_of(dist, action_support(self.env), self.settings.tie_structure)

    def to_policy(self, sample: WeightSample) -> NeuralPolicy:
        """The ``NeuralPolicy`` of one sample (works on a leading candidate axis too): one-hot
        actions, ``W2 = m * onehot(unit_targets)``, ``b2 = bias * onehot(default)``, each
        agent started in the role its ``start`` draws (``started``)."""
        q, na, sample = self.settings.nodes, self.env.num_actions, started(sample)
        w1, b1 = sample.w1, sample.b1
        if self.settings.standardize_inputs:  # the network reads the raw features
            w1, b1 = fold_inputs(w1, b1, self.input_stats, self.settings.whiten_inputs)
        m, bias = sample.m, sample.bias
        if self.settings.tied_vote_scale != 1.0:  # else the same numbers as without the field
            bias = bias * self.tied_scale(sample.node_tie)
        if self.settings.vote_sharpness != 1.0:  # likewise
            m, bias = m * self.settings.vote_sharpness, bias * self.settings.vote_sharpness
        w2 = m[..., None] * jax.nn.one_hot(sample.unit_targets, q, dtype=jnp.float32)
        b2 = bias[..., None] * jax.nn.one_hot(sample.default, q, dtype=jnp.float32)
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

    def kept_policy(self, sample: WeightSample) -> NeuralPolicy:
        """The policy of ``sample`` as the anytime best may keep it: ``to_policy`` with its
        votes times ``kept_sharpness`` (the controller handed back picks the argmax next
        node where the candidates' softmax still draws near a threshold; the same policy
        otherwise)."""
        policy = self.to_policy(sample)
        k = self.settings.kept_sharpness
        if k == 1.0:
            return policy
        layers = policy.net_params["params"]
        out = {name: value * k for name, value in layers["Dense_1"].items()}
        return policy.replace(net_params={"params": {**layers, "Dense_1": out}})

    def tied_scale(self, node_tie: jax.Array) -> jax.Array:
        """``[..., agents, 1]``: the factor of each agent's default votes, ``tied_vote_scale``
        where its nodes are tied (``node_tie [..., agents]`` 1), else 1."""
        s = jnp.float32(self.settings.tied_vote_scale)
        return jnp.where(node_tie == 1, s, jnp.float32(1.0))[..., None]

    def update_distribution(
        self, dist: WeightDistribution, elites: WeightSample, hyper: WeightsHyper
    ) -> WeightDistribution:
        """Refit to ``elites`` (leading ``[E]`` axis) with smoothing, then the uniform floors
        (``weight_space.refit``); the tie flags' floors are 0 where tying is not searched."""
        floor = hyper.category_floor
        return refit(
            dist,
            elites,
            hyper.alpha,
            (hyper.action_floor, floor, floor * self.settings.tie_structure),
            floor * self._agents_can_tie,
            action_support(self.env),
        )

    # ---------------------------------------------------------------- protocol
    def init(self, key: jax.Array, params: SearchParams) -> WeightsState:
        """Initial state; its ``best_policy`` is one draw of the initial distribution."""
        searches = jnp.int32(0) if self.settings.vote_alternate else None
        dist = self.search_distribution(searches)
        first = self.kept_policy(jax.tree.map(lambda x: x[0], self.draw(key, dist, 1)))
        size = pool_size(self.settings)
        polishing = self.polish_sweeps > 0
        return WeightsState(
            distribution=dist,
            best_policy=first,
            progress=Progress.create(1),
            pool=BestPool.create(first, size) if size else None,
            searches=searches,
            polish_seed=polish_seed(key) if polishing else None,
        )

    def search_distribution(self, searches) -> WeightDistribution:
        """The initial distribution of exploring search number ``searches`` (``[]`` int32, or
        ``None``): with ``vote_alternate`` every other one draws default votes at
        ``default_vote_scale`` (``voting_search``) and the others at 1."""
        if searches is None:
            return self.init_distribution()
        scale = jnp.where(self.voting_search(searches), self.settings.default_vote_scale, 1.0)
        return self.init_distribution(scale)

    def voting_search(self, searches) -> jax.Array:
        """Whether exploring search number ``searches`` (``[]`` int32) draws its default votes
        at ``default_vote_scale`` (``vote_alternate``): the odd ones, or the even ones with
        ``vote_first``."""
        return (searches % 2 == 1) != self.settings.vote_first

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
        WeightsMetrics)``. The winner is valued on the ``fresh`` stream, the mode on the
        ``other`` one; ``fresh_value(key, policy) -> value`` replaces their ``best_rollouts``
        fresh rollouts of the simulator. With a pool (``best_pool``) every fresh value is on
        the ``fresh`` stream and ``in_loop_best`` is the kept member's mean."""
        hyper = params.hyper
        if fresh_value is None:
            fresh_value = lambda k, p: self.fresh_value(k, p, params)  # noqa: E731
        s = self.settings
        k = streams(key)
        elite_values, elite_idx = jax.lax.top_k(values, s.elites)
        elites = jax.tree.map(lambda x: x[elite_idx], samples)
        dist = self.update_distribution(state.distribution, elites, hyper)

        winner = self.kept_policy(jax.tree.map(lambda x: x[0], elites))
        mode = self.kept_policy(self.mode(dist))
        stack = lambda *trees: jax.tree.map(lambda *xs: jnp.stack(xs), *trees)  # noqa: E731
        pool = state.pool
        if pool is not None:  # winner, mode and the pool's members on the same fresh rollouts
            both = jax.tree.map(
                lambda a, b: jnp.concatenate([a, b]), stack(winner, mode), pool.policies
            )
            fresh = jax.vmap(fresh_value, (None, 0))(k.fresh, both)
            v_winner, v_mode = fresh[0], fresh[1]
        elif s.paired_best:  # winner, mode and the best so far on the same fresh rollouts
            v_winner, v_mode, v_best = jax.vmap(fresh_value, (None, 0))(
                k.fresh, stack(winner, mode, state.best_policy)
            )
        else:  # one batched program for both (vmap over keys draws what two calls would draw)
            v_winner, v_mode = jax.vmap(fresh_value)(
                jnp.stack([k.fresh, k.other]), stack(winner, mode)
            )
        mode_better = v_mode > v_winner
        candidate = select_tree(mode_better, mode, winner)
        value = jnp.maximum(v_mode, v_winner)
        progress, improved = state.progress.record(value)
        progress = progress.replace(threshold=elite_values[-1])
        if s.paired_best:
            improved = value > v_best
            progress = progress.replace(in_loop_best=jnp.maximum(value, v_best))
        best_policy = select_tree(improved, candidate, state.best_policy)
        if pool is not None:
            pool = race(pool, fresh[2:], candidate, value)
            best_policy = pool.member(pool.best())
            progress = progress.replace(in_loop_best=pool.means()[pool.best()])
        start, done = refine_start(s), progress.iteration
        level = self.refine_level(done - 1)  # the level of the distribution just refit
        converged = self.converged(dist, done > start, state.searches, level)
        metrics = WeightsMetrics(
            value=value,
            in_loop_best=progress.in_loop_best,
            mean_value=values.mean(),
            top_value=elite_values[0],
            threshold=elite_values[-1],
            kept=jnp.int32(s.elites),
            restarted=converged,
        )
        restart = converged if s.restart_tol > 0 else jnp.bool_(False)
        if s.starts > 1:  # independent searches before the refine phase
            restart = restart | fresh_start(s, progress.iteration)
        searches = state.searches
        if searches is not None:
            searches = searches + restart.astype(jnp.int32)
        if s.restart_tol > 0 or s.starts > 1:  # afresh; the anytime best stays
            dist = select_tree(restart, self.search_distribution(searches), dist)
        if start < s.iterations:  # the last iterations search around the kept policy
            recentre = (done == start) | ((done > start) & converged)
            if s.refine_levels > 1:  # and each finer level starts around it
                finer = self.refine_level(done) != level
                recentre = recentre | ((done > start) & finer)
            centred = self.centered_distribution(best_policy, self.refine_level(done))
            dist = select_tree(recentre, centred, dist)
        state = WeightsState(dist, best_policy, progress, pool, searches, state.polish_seed)
        return state, metrics

    def refine_level(self, done) -> jax.Array | int:
        """The level of the refine phase's distribution after ``done`` iterations (``[]``
        int32): its iterations in ``refine_levels`` equal parts, part ``l`` searching at
        ``refine_tol ** l`` of the first's spread (coarse to fine); 0 with one level."""
        s = self.settings
        if s.refine_levels == 1:
            return 0
        start = refine_start(s)
        length = max(1, s.iterations - start)
        return jnp.clip((done - start) * s.refine_levels // length, 0, s.refine_levels - 1)

    def refine_scale_at(self, level) -> jax.Array | float:
        """The spread, as a share of the initial one, the refine phase starts from at
        ``level`` (``refine_level``)."""
        s = self.settings
        if isinstance(level, int) and level == 0:
            return s.refine_scale
        return s.refine_scale * jnp.float32(s.refine_tol) ** level

    def centered_distribution(self, policy: NeuralPolicy, level=0) -> WeightDistribution:
        """A distribution around ``policy`` (the refine phase): Gaussian means at its weights
        and votes with ``refine_scale`` times the initial spreads (times ``refine_tol ** level``
        at a finer ``level``, ``refine_levels``), and every categorical on the policy's choice
        mixed with that share of the uniform one (the tie flags on whether the policy is
        tied)."""
        s = self.settings
        layers = policy.net_params["params"]
        w1, b1 = layers["Dense_0"]["kernel"], layers["Dense_0"]["bias"]
        if s.standardize_inputs:  # unfold ``to_policy``'s folding
            w1, b1 = unfold_inputs(w1, b1, self.input_stats, s.whiten_inputs)
        sample = sample_of(
            w1,
            b1,
            layers["Dense_1"]["kernel"],
            layers["Dense_1"]["bias"],
            policy.action_probs,
        )
        factor = s.vote_sharpness * s.kept_sharpness
        if factor != 1.0:  # the draws of its votes, before the factors
            sample = sample.replace(m=sample.m / factor, bias=sample.bias / factor)
        if s.tied_vote_scale != 1.0:
            sample = sample.replace(bias=sample.bias / self.tied_scale(sample.node_tie))
        return centered(
            sample,
            self.init_distribution(),
            self.refine_scale_at(level),
            action_support(self.env),
            s.tie_structure,
            self._agents_can_tie,
            s.refine_redraw,
        )

    def converged(self, dist: WeightDistribution, refining: jax.Array, searches=None, level=0):
        """Whether the hidden layer's Gaussians shrank below ``restart_tol`` of their initial
        spread (``vote_restart_tol`` in a search at ``default_vote_scale`` when set; the
        search's number ``searches``, ``[]`` int32, or ``None``), or in the refine phase
        (``refining``, ``[]`` bool) below ``refine_tol`` of the spread it started from
        (``refine_scale`` of the initial one); mean over agents, nodes and weights."""
        s = self.settings
        initial = s.init_scale / math.sqrt(self.controller.in_features)
        tol = jnp.float32(s.restart_tol)
        if searches is not None and s.vote_restart_tol > 0:
            tol = jnp.where(self.voting_search(searches), s.vote_restart_tol, tol)
        tol = jnp.where(refining, s.refine_tol * self.refine_scale_at(level), tol)
        return jnp.mean(dist.w1_std) < tol * initial
