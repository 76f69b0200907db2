"""G-DICE (SPEC section 3, thesis Algorithm 1): cross-entropy search over deterministic FSCs
with discrete observations.

Search distribution per agent: ``action_probs [agents, nodes, actions]`` (theta) and
``transition_probs [agents, nodes, obs, nodes]`` (phi), uniform at the start. One iteration
(``GDice.step``, compiled once; the protocol of ``algorithms.engine``), values are returns to
**maximise**:

1. draw ``samples`` deterministic joint controllers (one action per node, one next node per
   (node, observation)) in one block;
2. evaluate each with ``eval_rollouts`` rollouts, all samples at once (common random numbers
   across samples by default);
3. elite threshold (SPEC section 2): keep the best ``elites`` samples above V_w;
4. count MLE over the elites' *tables* (frequency over elites, not over visits), smoothing with
   ``alpha``, optional entropy injection;
5. keep the best sample seen so far (anytime).

**[option]** ``evaluator="exact"`` (tabular models only) replaces step 2's Monte Carlo means by
the exact expected return over the horizon (:mod:`cognet_jax.exact_jax`). SPEC evaluates by
rollouts; exact values matter when the gaps between controllers are below the Monte Carlo
noise: on Recycling (gamma 0.9) the best controller beats the reactive one by 0.43 only when
*both* agents change their first action, and with noisy values the threshold V_w, set by a
lucky mean, sits above that gain, so the one rare sample that has both changes never becomes
an elite.

**[option]** ``evaluator="hybrid"`` (tabular models too large for exact values of every sample):
step 2's Monte Carlo means pick the ``exact_top`` most promising samples, and only those get
exact values; the others get ``-inf``, so the elites, the threshold V_w and the anytime best
are all ranked by exact values, at ``exact_top / samples`` of the exact evaluator's cost:
with rollouts alone a lucky Monte Carlo mean can set V_w and draw the elites to a poor
controller (experiments/NOTES.md, box pushing).

**[option]** ``shared_controller=True`` (identical agents: the same action and observation
counts): each sample is one controller used by every agent (``TabularController.shared``), so
the search runs over symmetric joint controllers. SPEC's G-DICE keeps independent per-agent
distributions; their product cannot move towards an optimum that needs all agents to change
the same entry at once, because each change alone loses value (Recycling with gamma 0.9: both
agents must first take action 2, the joint action that pays 5; experiments/README.md). Tied
sampling makes such a joint change a single draw. It is a restriction of the policy space: on
a problem whose optimum is asymmetric it can only find the best symmetric controller.

**[option]** ``layered=True`` (finite horizons): a time-layered controller of ``horizon`` layers
of ``nodes`` nodes each (``TabularController(layers=...)``); node q of layer t acts at step t
and moves to layer t + 1 only. The exact evaluator then runs over one layer's joint nodes per
step (:func:`cognet_jax.exact_jax.exact_value_layered`).

**[option]** ``polish_sweeps > 0`` (exact or hybrid evaluator): after the last iteration,
``finish`` improves the best controller by exact steepest ascent over single-entry changes
(:mod:`cognet_jax.algorithms.polish`), at most ``polish_sweeps`` changes. The search ends near
an optimum, often a few entries away from it; the polish is a local search, so it cannot lift a
search that ended in another basin.

**[option]** ``best_response_rounds > 0`` (with the polish, layered controllers): the polish
then alternates rounds of every agent's exact best response to the others' controllers
(:mod:`cognet_jax.algorithms.best_response`, JESP's step over policy trees, kept when it fits
the layers and improves the exact value) with the single-entry polish. A best response
changes a node's action and its transitions together, which single-entry moves cannot (box
pushing h 4: the polish alone stops at 97.28 on most seeds, the best responses lift them to
97.69); its cost grows as ``(actions * observations)^(horizon - 1)``, so
``build`` drops it above ``POLISH_SWEEP_LIMIT``.

**[choice]** The value an iteration records for the entropy-injection triggers and the best-value
curve is its best sample's value (the in-loop, optimistic estimate).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Literal

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from cognet_jax.algorithms.best_response import best_response, best_response_cost
from cognet_jax.algorithms.cross_entropy import (
    ENTROPY_SECTION_FIELDS,
    Progress,
    count_table,
    inject_entropy,
    select_tree,
    smooth,
)
from cognet_jax.algorithms.engine import (
    SearchParams,
    ThresholdSearch,
    ThresholdSection,
)
from cognet_jax.algorithms.gdice_reports import TabularReports
from cognet_jax.algorithms.polish import (
    BUDGET_CAP,
    Polish,
    PolishState,
    count_moves,
    improves,
    neighbour_moves,
    values_by_evaluation,
)
from cognet_jax.config import (
    ConfigError,
    require,
    require_positive,
    require_probability,
    settings_class,
)
from cognet_jax.controllers.base import action_support
from cognet_jax.controllers.tabular import (
    DeterministicTabularPolicy,
    TabularController,
    TabularDistribution,
)
from cognet_jax.envs.tabular import TabularEnv
from cognet_jax.exact_jax import (
    exact_cost,
    exact_value,
    exact_value_layered,
    layered_move_values,
)

#: Largest exact evaluation one G-DICE iteration may do (multiply-adds over all samples).
EXACT_EVALUATOR_LIMIT = 2_000_000_000


#: ``evaluator = "auto"`` ranks samples exactly up to this many multiply-adds per iteration
#: (a short exact part beside the iteration's rollouts), by rollouts above it.
EXACT_AUTO_LIMIT = 300_000_000


#: ``exact_top = "auto"``: the hybrid evaluator values at most ``EXACT_TOP_MAX`` samples
#: exactly, fewer where they would cost more than ``HYBRID_EXACT_LIMIT`` multiply-adds per
#: iteration: the exact values of a hybrid model are gather-bound, far slower per multiply-add
#: than a fully exact small model's, and dominated its iterations (experiments/README.md,
#: "G-DICE defaults in a minute": the time and the 8-seed values behind the limit)
EXACT_TOP_MAX = 50
HYBRID_EXACT_LIMIT = 40_000_000
#: ``evaluator = "auto"`` is hybrid where at least this many samples per iteration fit
#: ``HYBRID_EXACT_LIMIT`` (``exact_top = "auto"``), rollouts where fewer do. **[choice]**
#: Even a few exact values per iteration keep the elites off lucky Monte Carlo means
#: (Mars rovers at h 5: experiments/NOTES.md)
HYBRID_MIN_TOP = 5


#: Largest exact cost of one polish sweep (every single-entry change of the best controller,
#: ``GDice.polish_moves``); above it the polish is skipped. **[choice]** 1e10 keeps the polish
#: of every model of the minute table at h 4 and 5 (Mars rovers at h 5: 6.2e9, 5 - 8 s of
#: polish, which lifts three seeds of eight from 11.56 - 12.0 to the optimum; the meeting grid
#: at h 4: 2.0e9, 10 s), while its budget (``polish_budget``) bounds what it spends
#: (experiments/NOTES.md)
POLISH_SWEEP_LIMIT = 10_000_000_000


#: ``repeats = "auto"`` runs every search at most this many times (Dec-Tiger h 8-10: a single
#: search ends at the optimum in 5-13% (independent) and 23-45% (shared) of 64 tries, so
#: one of each leaves seeds below it; experiments/results/gdice-members/)
AUTO_REPEATS_MAX = 8


#: Largest working set (float32 numbers) of one agent's best response in the polish
#: (``algorithms.best_response.best_response_cost``); above it, or above
#: ``POLISH_SWEEP_LIMIT`` multiply-adds, the best responses are skipped.
BEST_RESPONSE_FLOATS = 1 << 25


@dataclasses.dataclass
class GDiceSection(ThresholdSection):
    """``[algorithm]`` of G-DICE (SPEC 3): the shared fields of ``ThresholdSection`` and:"""

    nodes: int = 7
    #: "rollouts" (SPEC: mean of eval_rollouts returns), "exact" (tabular models only: the
    #: exact expected return over the horizon, computed inside the compiled iteration),
    #: "hybrid" (rollouts pick the ``exact_top`` best samples, which get exact values) or
    #: "auto" (exact when one iteration's exact values cost at most ``EXACT_AUTO_LIMIT``
    #: multiply-adds, else hybrid when its exact part fits: ``HYBRID_MIN_TOP`` samples with
    #: ``exact_top = "auto"``, a numeric ``exact_top`` within ``EXACT_AUTO_LIMIT``; else rollouts)
    evaluator: Literal["rollouts", "exact", "hybrid", "auto"] = "rollouts"
    #: evaluator "hybrid": the samples (best by rollouts) that get exact values; "auto": as many
    #: as keep one iteration's exact part within ``HYBRID_EXACT_LIMIT`` multiply-adds, at most
    #: ``EXACT_TOP_MAX`` (``gdice.resolve_exact_top``)
    exact_top: int | Literal["auto"] = "auto"
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
    #: every search above (``restarts``, ``shared_restarts``, ``explore_restarts``) runs this
    #: many times with its own keys; "auto": as many times as the exact values of one
    #: iteration stay within ``EXACT_AUTO_LIMIT`` multiply-adds, at most ``AUTO_REPEATS_MAX``
    #: (1 where the samples are not all valued exactly; ``auto_repeats``)
    repeats: int | Literal["auto"] = 1
    #: after the last iteration, at most this many single-entry changes of the best controller
    #: by exact steepest ascent (exact or hybrid evaluator only; 0: none, as in SPEC)
    polish_sweeps: int = 0
    #: with the polish of a layered controller: at most this many rounds of each agent's exact
    #: best response to the others (written into its layers when it fits), each followed by
    #: the single-entry polish (``algorithms.best_response``; 0: none)
    best_response_rounds: int = 0
    #: the polish (sweeps and best responses) values at most this many times as many
    #: controllers exactly as the search did (iterations * samples * searches); a sweep or a
    #: round that would go past it is not started, so a tiny search gets a tiny polish
    polish_budget: float = 1.0

    def rollouts_per_iteration(self) -> int:
        """Rollouts one iteration simulates at least: none when exact values may rank the
        samples (``exact``, ``auto``), else every search's samples (and fresh bests)."""
        if self.evaluator in ("exact", "auto"):
            return 0
        searches = self.restarts + self.shared_restarts + self.explore_restarts
        fresh = self.best_rollouts if self.evaluator == "rollouts" else 0
        return searches * (self.samples * self.eval_rollouts + fresh)

    def check(self, config) -> None:
        super().check(config)
        require_positive(self, "algorithm", "restarts")
        require(
            self.exact_top == "auto" or self.exact_top >= 1, "algorithm.exact_top", "must be >= 1"
        )
        require(self.repeats == "auto" or self.repeats >= 1, "algorithm.repeats", "must be >= 1")
        for name in ("shared_restarts", "explore_restarts", "polish_sweeps"):
            require(getattr(self, name) >= 0, f"algorithm.{name}", "must be >= 0")
        require(self.best_response_rounds >= 0, "algorithm.best_response_rounds", "must be >= 0")
        require(
            math.isfinite(self.polish_budget) and self.polish_budget >= 0,
            "algorithm.polish_budget",
            "must be a finite number >= 0",
        )
        require_probability(self, "algorithm", "explore_entropy_rate")


#: static settings: the fields of ``GDiceSection`` without the hyper-parameters
#: (``ThresholdHyper``) and the portfolio's own fields (``GDicePortfolio``)
GDiceSettings = settings_class(
    "GDiceSettings",
    GDiceSection,
    exclude=(
        "alpha",
        *ENTROPY_SECTION_FIELDS,
        "shared_restarts",
        "explore_restarts",
        "explore_entropy_rate",
    ),
)


@struct.dataclass
class GDiceState:
    distribution: TabularDistribution
    best_policy: DeterministicTabularPolicy
    progress: Progress


@struct.dataclass
class PolishInfo:
    """What ``finish`` did: exact values before and after, moves applied, best responses
    applied (``best_response_rounds``), exact evaluations spent, moves per sweep, and the
    budget of evaluations (``polish_budget``)."""

    before: jax.Array
    after: jax.Array
    moves_applied: jax.Array
    responses_applied: jax.Array
    evaluations: jax.Array
    moves_per_sweep: int = struct.field(pytree_node=False, default=0)
    budget: int = struct.field(pytree_node=False, default=0)


def _counts(env, name: str):
    counts = getattr(env, name, None)
    return tuple(counts) if counts is not None else None


def identical_agents(env) -> bool:
    """Whether every agent has the same number of actions and observations (the condition of
    ``shared_controller``); environments without per-agent counts have identical agents."""
    return all(
        (c := _counts(env, name)) is None or len(set(c)) <= 1
        for name in ("action_counts", "obs_counts")
    )


@dataclasses.dataclass(frozen=True, eq=False)
class GDice(TabularReports, ThresholdSearch):
    """G-DICE on an environment with discrete observations; ``init`` / ``ask`` / ``evaluate``
    / ``tell`` / ``step`` / ``finish`` are pure functions of explicit state and params
    (``algorithms.engine``)."""

    #: its polish branches between sweeps and best responses (``polish.Polish.advance``)
    finish_per_run = True

    def __post_init__(self):
        env, settings = self.env, self.settings
        if env.num_obs is None:
            raise ConfigError(
                "env.name",
                f"G-DICE needs discrete observations (env.num_obs); {type(env).__name__} has none",
            )
        if settings.evaluator not in ("rollouts", "exact", "hybrid"):
            raise ConfigError("algorithm.evaluator", f"unknown evaluator {settings.evaluator!r}")
        if settings.evaluator != "rollouts" and not isinstance(env, TabularEnv):
            raise ConfigError(
                "algorithm.evaluator",
                f"{settings.evaluator!r} needs a tabular .dpomdp model (env.name = 'dpomdp')",
            )
        if settings.shared_controller and not identical_agents(env):
            raise ConfigError(
                "algorithm.shared_controller",
                "needs agents with the same numbers of actions and observations; this problem "
                f"has actions {_counts(env, 'action_counts')} and observations "
                f"{_counts(env, 'obs_counts')}",
            )
        layers = env.horizon if settings.layered else 0
        controller = TabularController(
            num_agents=env.num_agents,
            num_nodes=settings.nodes * max(layers, 1),
            num_actions=env.num_actions,
            num_obs=env.num_obs,
            action_counts=env.action_counts,
            shared=settings.shared_controller,
            layers=layers,
        )
        self._set(controller=controller)

    def init(self, key: jax.Array, params: SearchParams) -> GDiceState:
        dist = self.controller.init_distribution()
        return GDiceState(
            distribution=dist,
            best_policy=self.controller.sample(key, dist),
            progress=Progress.create(self.settings.entropy_window),
        )

    def sample_policies(self, key: jax.Array, dist: TabularDistribution):
        """``samples`` deterministic controllers (leaves with a leading ``[samples]`` axis)."""
        return jax.vmap(lambda k: self.controller.sample(k, dist))(
            jax.random.split(key, self.settings.samples)
        )

    def evaluate(self, key: jax.Array, policies, params: SearchParams) -> jax.Array:
        """Value ``[samples]`` of each sampled controller: the mean return of
        ``eval_rollouts`` rollouts, or with ``evaluator="exact"`` the exact expected return
        over the horizon (:mod:`cognet_jax.exact_jax`, tabular models only), or with
        ``"hybrid"`` exact values of the ``exact_top`` best by rollouts (``-inf`` elsewhere)."""
        s = self.settings
        if s.evaluator == "exact":
            return self.exact_values(policies, params)
        means = super().evaluate(key, policies, params)
        if s.evaluator == "rollouts":
            return means
        top_k = EXACT_TOP_MAX if s.exact_top == "auto" else s.exact_top  # built: resolved
        _, top = jax.lax.top_k(means, min(top_k, s.samples))
        exact = self.exact_values(jax.tree.map(lambda x: x[top], policies), params)
        return jnp.full_like(means, -jnp.inf).at[top].set(exact)

    def exact_values(self, policies, params: SearchParams) -> jax.Array:
        """Exact expected returns ``[C]`` of controllers with a leading ``[C]`` axis."""
        s = self.settings
        value = exact_value_layered if s.layered else exact_value
        nodes = s.nodes if s.layered else self.controller.num_nodes
        return jax.vmap(lambda p: value(self.env, params.env, p, nodes))(policies)

    def exact_value_of(self, policy: DeterministicTabularPolicy, params) -> jax.Array:
        """Exact expected return ``[]`` of one controller (``exact_values`` of a batch of 1)."""
        return self.exact_values(jax.tree.map(lambda x: x[None], policy), params)[0]

    def update_distribution(self, dist: TabularDistribution, elites, kept, hyper):
        """Count MLE over the kept elites' tables + smoothing. ``elites``: policies with a
        leading ``[elites]`` axis, ``kept [elites]`` bool."""
        w = kept.astype(jnp.float32)
        n, a = self.controller.num_nodes, self.env.num_actions
        # [elites, agents, nodes] -> counts [agents, nodes, actions]
        act_counts = count_table(jnp.moveaxis(elites.actions, 0, -1), a, w)
        trans_counts = count_table(jnp.moveaxis(elites.transitions, 0, -1), n, w)
        return TabularDistribution(
            action_probs=smooth(dist.action_probs, act_counts, hyper.alpha),
            transition_probs=smooth(dist.transition_probs, trans_counts, hyper.alpha),
        )

    @property
    def rollouts_per_iteration(self) -> int:
        """Simulated rollouts in one ``step`` (the exact evaluator simulates none)."""
        s = self.settings
        if s.evaluator == "exact":  # exact values need neither rollouts nor a fresh best
            return 0
        return s.samples * s.eval_rollouts + self.best_rollouts

    def inject(self, dist: TabularDistribution, injected, hyper):
        """Entropy injection into actions and transitions where ``injected``."""
        rate = hyper.entropy.rate
        return TabularDistribution(
            action_probs=jnp.where(
                injected,
                inject_entropy(dist.action_probs, rate, action_support(self.env)),
                dist.action_probs,
            ),
            transition_probs=jnp.where(
                injected,
                inject_entropy(dist.transition_probs, rate, self.controller.transition_support()),
                dist.transition_probs,
            ),
        )

    @property
    def best_rollouts(self) -> int:
        """``best_rollouts`` with the rollout evaluator; exact values need no fresh best."""
        s = self.settings
        return s.best_rollouts if s.evaluator == "rollouts" else 0

    def mean_value(self, values: jax.Array) -> jax.Array:
        if self.settings.evaluator == "hybrid":  # only the exact ones are finite
            return jnp.mean(values, where=jnp.isfinite(values))
        return values.mean()

    # -- after the last iteration: the exact polish ---------------------------------------
    @property
    def polishes(self) -> bool:
        """Whether ``finish`` does anything: ``polish_sweeps > 0`` and exact values."""
        return self.settings.polish_sweeps > 0 and self.settings.evaluator in ("exact", "hybrid")

    def polish_moves(self, count: bool = False):
        """The moves one polish sweep tries, ``[moves, 5]`` (``polish.neighbour_moves``, listed
        once per search); with ``count``, only their number (``polish.count_moves``)."""
        if not count:
            return self._listed_moves
        env = self.env
        return count_moves(self.controller, env.action_counts, env.obs_counts, self._joint_moves)

    @property
    def _joint_moves(self) -> bool:
        """Whether moves that change every agent's entry at once are tried (identical agents)."""
        return identical_agents(self.env) and self.env.num_agents > 1

    @functools.cached_property
    def _listed_moves(self) -> np.ndarray:
        env = self.env
        return neighbour_moves(
            self.controller, env.action_counts, env.obs_counts, self._joint_moves
        )

    @property
    def best_responds(self) -> bool:
        """Whether the polish adds agents' best responses (``best_response_rounds > 0``, a
        layered controller, and the polish on)."""
        s = self.settings
        return self.polishes and s.layered and s.best_response_rounds > 0

    def respond(self, policy: DeterministicTabularPolicy, value: jax.Array, params):
        """One round: every agent in turn replaced by its exact best response to the others
        when that fits the layers and beats ``value`` (by its exact value). Returns
        ``(policy, value, responses applied)``."""
        applied = jnp.int32(0)
        for agent in range(self.env.num_agents):
            candidate, _, fits = best_response(
                self.env, params.env, policy, self.settings.nodes, agent
            )
            new = self.exact_value_of(candidate, params)
            better = fits & improves(new, value)
            policy = select_tree(better, candidate, policy)
            value = jnp.where(better, new, value)
            applied = applied + better
        return policy, value, applied

    @property
    def search_evaluations(self) -> int:
        """Controllers one search values in all its iterations (``iterations * samples``)."""
        return self.settings.iterations * self.settings.samples

    def polisher(self, budget: int) -> Polish:
        """The polish of this search's best controller (``algorithms.polish.Polish``) with at
        most ``budget`` exact evaluations; a round of best responses costs one evaluation per
        ``exact_cost`` multiply-adds of each agent's response, plus its exact value."""
        rounds, round_cost = 0, 0
        if self.best_responds:
            rounds = self.settings.best_response_rounds
            unit = max(exact_cost(self.env, self.settings.nodes), 1)
            for agent in range(self.env.num_agents):
                flops, _ = best_response_cost(self.env, self.settings.nodes, agent)
                round_cost += -(-flops // unit) + 1
        return Polish(
            moves=self.polish_moves(),
            sweeps=self.settings.polish_sweeps,
            rounds=rounds,
            budget=budget,
            round_cost=round_cost,
        )

    def polish_start(self, policy, params, polish: Polish) -> PolishState:
        return polish.start(policy, self.exact_value_of(policy, params))

    def polish_advance(self, s: PolishState, params, polish: Polish) -> PolishState:
        return polish.advance(s, *self._polish_functions(params))

    def polish_policy(self, policy, params, polish: Polish) -> PolishState:
        """``policy`` polished to the end (pure): ``polish_start``, then ``Polish.run``."""
        return polish.run(
            self.polish_start(policy, params, polish), *self._polish_functions(params)
        )

    def _polish_functions(self, params):
        """``(move_values, respond)`` of ``Polish.advance``: a layered controller values a
        sweep's moves by one-layer updates (``exact_jax.layered_move_values``, faster than
        evaluating every changed controller), a free one changed by changed."""
        if self.settings.layered:
            width = self.settings.nodes

            def move_values(policy, moves):
                return layered_move_values(self.env, params.env, policy, width, moves)

        else:
            move_values = values_by_evaluation(lambda ps: self.exact_values(ps, params))
        respond = lambda p, v: self.respond(p, v, params)  # noqa: E731
        return move_values, respond

    # -- finish as steps (algorithms.engine): a driver shows progress and stops between them --
    def finish_start(self, state: GDiceState, params: SearchParams):
        """The polish of the best policy (``None`` when ``polishes`` is false), with a budget
        of ``polish_budget`` times the search's evaluations."""
        if not self.polishes:
            return None
        return self.polish_start(state.best_policy, params, self._own_polish)

    def polish_budget(self, searches: int = 1, candidates: int = 1) -> int:
        """Exact evaluations each of ``candidates`` polishes may spend: ``polish_budget``
        times what ``searches`` searches valued, shared equally."""
        total = self.settings.polish_budget * self.search_evaluations * searches
        return int(min(total // candidates, BUDGET_CAP))

    @functools.cached_property
    def _own_polish(self) -> Polish:
        """The polish ``finish`` runs (this search's own budget), built once."""
        return self.polisher(self.polish_budget())

    def finish_advance(self, work: PolishState, params: SearchParams) -> PolishState:
        return self.polish_advance(work, params, self._own_polish)

    def finish_done(self, work: PolishState) -> jax.Array:
        return self._own_polish.done(work)

    def finish_end(self, state: GDiceState, work: PolishState):
        """``(state, PolishInfo)``: the polished policy kept, its value the better of the
        polished one and the search's best."""
        value = jnp.maximum(work.value, state.progress.in_loop_best)
        progress = state.progress.replace(in_loop_best=value)
        info = polish_info(work, len(self.polish_moves()), self.polish_budget())
        return state.replace(best_policy=work.policy, progress=progress), info


def repeats_an_earlier(policies) -> jax.Array:
    """``[C]`` bool: whether policy c (leaves with a leading ``[C]`` axis) equals one before it."""
    flat = jnp.concatenate(
        [x.reshape(x.shape[0], -1) for x in jax.tree.leaves(policies)], axis=1
    )  # [C, entries]
    same = jnp.all(flat[:, None, :] == flat[None, :, :], axis=-1)  # [C, C]
    return jnp.any(jnp.tril(same, k=-1), axis=1)


def polish_info(work: PolishState, moves_per_sweep: int, budget: int) -> PolishInfo:
    return PolishInfo(
        before=work.before,
        after=work.value,
        moves_applied=work.moves_applied,
        responses_applied=work.responses_applied,
        evaluations=work.spent,
        moves_per_sweep=moves_per_sweep,
        budget=budget,
    )
