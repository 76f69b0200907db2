"""G-DICE (SPEC section 3, thesis Algorithm 1): cross-entropy search over deterministic FSCs
with discrete observations.

Search distribution per agent: ``action_probs [agents, nodes, actions]`` (theta) and
``transition_probs [agents, nodes, obs, nodes]`` (phi), uniform at the start. One iteration
(``GDice.step``, compiled once), values are returns to **maximise**:

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
are all ranked by exact values, at ``exact_top / samples`` of the exact evaluator's cost. On
the 100-state box-pushing benchmark at h 3, rollouts alone left one seed of two at 19.2 (the
optimum is 66.081): a lucky Monte Carlo mean set V_w and the elites drifted to pushing the
small boxes.

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
``build_from_config`` drops it above ``api.POLISH_SWEEP_LIMIT``.

**[choice]** The value an iteration records for the entropy-injection triggers and the best-value
curve is its best sample's value (the in-loop, optimistic estimate).
"""

from __future__ import annotations

import copy
import dataclasses

import jax
import jax.numpy as jnp
from flax import struct

from cognet_jax.algorithms.best_response import best_response, best_response_cost
from cognet_jax.algorithms.cross_entropy import (
    ENTROPY_FIELDS,
    Progress,
    count_table,
    entropy_config,
    inject_entropy,
    select_tree,
    smooth,
)
from cognet_jax.algorithms.engine import SearchMetrics, ThresholdHyper, ThresholdSearch
from cognet_jax.algorithms.polish import RELATIVE_TOLERANCE, neighbour_moves, polish
from cognet_jax.config import (
    ENTROPY_SECTION_FIELDS,
    ConfigError,
    GDiceAlgorithmSection,
    settings_class,
)
from cognet_jax.controllers.base import action_support
from cognet_jax.controllers.tabular import (
    DeterministicTabularPolicy,
    TabularController,
    TabularDistribution,
)
from cognet_jax.envs.tabular import TabularEnv
from cognet_jax.exact_jax import exact_value, exact_value_layered

#: dynamic (sweepable) hyper-parameters: the engine's, shared with COG-DICE
GDiceHyper = ThresholdHyper


#: static settings: the fields of ``config.GDiceAlgorithmSection`` (documented there) without the
#: hyper-parameters (``GDiceHyper``) and the portfolio's own fields (``GDicePortfolio``)
GDiceSettings = settings_class(
    "GDiceSettings",
    GDiceAlgorithmSection,
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
    applied (``best_response_rounds``), moves per sweep."""

    before: jax.Array
    after: jax.Array
    moves_applied: jax.Array
    responses_applied: jax.Array
    moves_per_sweep: int = struct.field(pytree_node=False, default=0)


#: an iteration's figures (the engine's, shared with COG-DICE)
GDiceMetrics = SearchMetrics


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


class GDice(ThresholdSearch):
    """G-DICE on an environment with discrete observations; ``init`` / ``ask`` / ``tell`` /
    ``step`` are pure (``algorithms.engine``)."""

    def __init__(self, env, env_params, settings: GDiceSettings, hyper: GDiceHyper | None = None):
        if env.num_obs is None:
            raise ValueError("G-DICE needs discrete observations (env.num_obs is None)")
        if settings.evaluator not in ("rollouts", "exact", "hybrid"):
            raise ValueError(f"unknown evaluator {settings.evaluator!r}")
        if settings.evaluator != "rollouts" and not isinstance(env, TabularEnv):
            raise ValueError(f"evaluator={settings.evaluator!r} needs a tabular (.dpomdp) model")
        if settings.shared_controller and not identical_agents(env):
            raise ConfigError(
                "algorithm.shared_controller",
                "needs agents with the same numbers of actions and observations; this problem "
                f"has actions {_counts(env, 'action_counts')} and observations "
                f"{_counts(env, 'obs_counts')}",
            )
        self.env = env
        self.env_params = env_params
        self.settings = settings
        self.hyper = hyper if hyper is not None else GDiceHyper()
        layers = env.horizon if settings.layered else 0
        self.controller = TabularController(
            num_agents=env.num_agents,
            num_nodes=settings.nodes * max(layers, 1),
            num_actions=env.num_actions,
            num_obs=env.num_obs,
            action_counts=env.action_counts,
            shared=settings.shared_controller,
            layers=layers,
        )

    def init(self, key: jax.Array) -> GDiceState:
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

    def evaluate_samples(self, key: jax.Array, policies) -> jax.Array:
        """Value ``[samples]`` of each sampled controller: the mean return of
        ``eval_rollouts`` rollouts, or with ``evaluator="exact"`` the exact expected return
        over the horizon (:mod:`cognet_jax.exact_jax`, tabular models only)."""
        s = self.settings
        if s.evaluator == "exact":
            return self.exact_values(policies)
        means = self.mean_returns(key, policies)
        if s.evaluator == "rollouts":
            return means
        _, top = jax.lax.top_k(means, min(s.exact_top, s.samples))
        exact = self.exact_values(jax.tree.map(lambda x: x[top], policies))
        return jnp.full_like(means, -jnp.inf).at[top].set(exact)

    def exact_values(self, policies) -> jax.Array:
        """Exact expected returns ``[C]`` of controllers with a leading ``[C]`` axis."""
        s = self.settings
        value = exact_value_layered if s.layered else exact_value
        nodes = s.nodes if s.layered else self.controller.num_nodes
        return jax.vmap(lambda p: value(self.env, self.env_params, p, nodes))(policies)

    def exact_value_of(self, policy: DeterministicTabularPolicy) -> jax.Array:
        """Exact expected return ``[]`` of one controller (:meth:`exact_values` of a batch of 1)."""
        return self.exact_values(jax.tree.map(lambda x: x[None], policy))[0]

    def update_distribution(self, dist: TabularDistribution, elites, kept, hyper: GDiceHyper):
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
        if s.evaluator == "hybrid":  # the winner's value is exact: no fresh best
            return s.samples * s.eval_rollouts
        return s.samples * s.eval_rollouts + s.best_rollouts

    def inject(self, dist: TabularDistribution, injected, hyper: GDiceHyper):
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
    def fresh_rollouts(self) -> int:
        """``best_rollouts`` with the rollout evaluator; exact values need no fresh best."""
        s = self.settings
        return s.best_rollouts if s.evaluator == "rollouts" else 0

    def mean_value(self, values: jax.Array) -> jax.Array:
        if self.settings.evaluator == "hybrid":  # only the exact ones are finite
            return jnp.mean(values, where=jnp.isfinite(values))
        return values.mean()

    @staticmethod
    def best_policy(state: GDiceState) -> DeterministicTabularPolicy:
        return state.best_policy

    @property
    def polishes(self) -> bool:
        """Whether ``finish`` does anything: ``polish_sweeps > 0`` and exact values."""
        return self.settings.polish_sweeps > 0 and self.settings.evaluator in ("exact", "hybrid")

    def polish_moves(self):
        """The moves one polish sweep tries, ``[moves, 5]`` (``polish.neighbour_moves``)."""
        env = self.env
        return neighbour_moves(
            self.controller,
            env.action_counts,
            env.obs_counts,
            joint_moves=identical_agents(env) and env.num_agents > 1,
        )

    @property
    def best_responds(self) -> bool:
        """Whether the polish adds agents' best responses (``best_response_rounds > 0``, a
        layered controller, and the polish on)."""
        s = self.settings
        return self.polishes and s.layered and s.best_response_rounds > 0

    def respond(self, policy: DeterministicTabularPolicy, value: jax.Array):
        """One round: every agent in turn replaced by its exact best response to the others
        when that fits the layers and beats ``value`` (by its exact value). Returns
        ``(policy, value, responses applied)``."""
        applied = jnp.int32(0)
        for agent in range(self.env.num_agents):
            candidate, _, fits = best_response(
                self.env, self.env_params, policy, self.settings.nodes, agent
            )
            new = self.exact_value_of(candidate)
            better = fits & (new > value + RELATIVE_TOLERANCE * jnp.maximum(1.0, jnp.abs(value)))
            policy = select_tree(better, candidate, policy)
            value = jnp.where(better, new, value)
            applied = applied + better
        return policy, value, applied

    def polish_best(self, policy: DeterministicTabularPolicy, best_value: jax.Array):
        """``(policy, value, PolishInfo)``: ``policy`` improved by exact steepest ascent, then
        (``best_responds``) by rounds of best responses, each followed by steepest ascent,
        until a round changes nothing or ``best_response_rounds`` rounds."""
        moves = self.polish_moves()
        sweeps = self.settings.polish_sweeps
        before = self.exact_value_of(policy)
        policy, value, applied = polish(self.exact_values, policy, moves, sweeps)
        responses = jnp.int32(0)
        if self.best_responds:

            def one_round(carry):
                policy, value, applied, responses, rounds, _ = carry
                policy, value, answered = self.respond(policy, value)
                policy, value, more = polish(self.exact_values, policy, moves, sweeps)
                return policy, value, applied + more, responses + answered, rounds + 1, answered > 0

            def keep_going(carry):
                return carry[5] & (carry[4] < self.settings.best_response_rounds)

            start = (policy, value, applied, responses, jnp.int32(0), jnp.bool_(True))
            policy, value, applied, responses, _, _ = jax.lax.while_loop(
                keep_going, one_round, start
            )
        info = PolishInfo(
            before=before,
            after=value,
            moves_applied=applied,
            responses_applied=responses,
            moves_per_sweep=len(moves),
        )
        return policy, jnp.maximum(value, best_value), info

    def finish(self, state: GDiceState) -> tuple[GDiceState, PolishInfo | None]:
        """After the last iteration (pure, jit-able): the best policy polished by exact local
        search when ``polishes``; ``(state, PolishInfo)``, or ``(state, None)``."""
        if not self.polishes:
            return state, None
        policy, value, info = self.polish_best(state.best_policy, state.progress.best_value)
        progress = state.progress.replace(best_value=value)
        return state.replace(best_policy=policy, progress=progress), info


@struct.dataclass
class PortfolioState:
    """``members``: one :class:`GDiceState` per member search, leaves with a leading
    ``[restarts]`` axis; ``best_policy`` and ``progress`` (iteration, best value) of them all."""

    members: tuple
    best_policy: DeterministicTabularPolicy
    progress: Progress


class GDicePortfolio:
    """Several independent G-DICE searches run side by side in one compiled ``step``: ``restarts``
    searches as ``settings`` says (independent per-agent controllers unless
    ``shared_controller``) and ``shared_restarts`` with one shared controller (identical agents
    only; skipped otherwise). Each search keeps its own
    distributions, elite threshold and entropy injection; the portfolio keeps the best policy
    of all of them by their own best values (exact values with the exact evaluator, fresh means
    with ``best_rollouts``).

    ``explore_restarts`` more independent searches inject entropy at ``explore_rate`` instead
    of the hyper's rate: a strong injection lets a converged search leave a local optimum (box
    pushing h 3: the independent search stays at 19.2 where the optimum is 66.081) but keeps
    the search from settling on a fine optimum (Dec-Tiger h 5, GridSmall h 5), so both run.

    Why: a shared controller finds optima that need every agent to change the same entry at
    once (Recycling with gamma 0.9, Dec-Tiger h 5), but can only find symmetric controllers;
    running both and keeping the better one needs no guess of which problem is which.
    """

    def __init__(
        self,
        env,
        env_params,
        settings: GDiceSettings,
        hyper=None,
        shared_restarts=0,
        explore_restarts=0,
        explore_rate=0.2,
    ):
        self.members = [GDice(env, env_params, settings, hyper)]
        self.restarts = [settings.restarts]
        #: per member: the entropy-injection rate that replaces the hyper's (None: keep it)
        self.rates: list[float | None] = [None]
        if shared_restarts and identical_agents(env) and env.num_agents > 1:
            shared = dataclasses.replace(settings, shared_controller=True)
            self.members.append(GDice(env, env_params, shared, hyper))
            self.restarts.append(shared_restarts)
            self.rates.append(None)
        if explore_restarts:
            self.members.append(GDice(env, env_params, settings, hyper))
            self.restarts.append(explore_restarts)
            self.rates.append(explore_rate)
        self.explore_restarts, self.explore_rate = explore_restarts, explore_rate
        self.env, self.env_params, self.settings = env, env_params, settings
        self.memory = None
        self.hyper = self.members[0].hyper
        self.controller = self.members[0].controller

    @property
    def env_params(self):
        return self._env_params

    @env_params.setter
    def env_params(self, value):
        """Setting the params (``sweep.with_env_params`` on a shallow copy) gives every member
        search the same params, on copies, so the original portfolio is left as it was."""
        self._env_params = value
        self.members = [copy.copy(m) for m in self.members]
        for m in self.members:
            m.env_params = value

    @property
    def memory(self) -> int | None:
        return self._memory

    @memory.setter
    def memory(self, value: int | None):
        """The budget of the whole portfolio; each member search (``vmap``-ed over its
        restarts) gets ``value / total restarts`` per restart."""
        from cognet_jax.memory import budget_bytes

        self._memory = value
        per_lane = (budget_bytes() if value is None else value) // sum(self.restarts)
        self.members = [copy.copy(m) for m in self.members]
        for m in self.members:
            m.memory = per_lane

    def init(self, key: jax.Array) -> PortfolioState:
        members = tuple(
            jax.vmap(m.init)(jax.random.split(jax.random.fold_in(key, i), r))
            for i, (m, r) in enumerate(zip(self.members, self.restarts))
        )
        first = jax.tree.map(lambda x: x[0], members[0].best_policy)
        return PortfolioState(
            members=members,
            best_policy=first,
            progress=Progress.create(self.settings.entropy_window),
        )

    @property
    def rollouts_per_iteration(self) -> int:
        return sum(m.rollouts_per_iteration * r for m, r in zip(self.members, self.restarts))

    # -- ask / evaluate / tell (algorithms.engine's protocol, one entry per member search) --
    def _member_keys(self, key: jax.Array, i: int) -> jax.Array:
        """Keys ``[restarts]`` of member search ``i`` for the iteration key ``key``."""
        return jax.random.split(jax.random.fold_in(key, i), self.restarts[i])

    def ask(self, key: jax.Array, state: PortfolioState) -> tuple[tuple, tuple]:
        """``(samples, policies)``: one entry per member search, each with leading axes
        ``[restarts, samples]`` (see ``members`` and ``restarts``)."""
        asked = [
            jax.vmap(m.ask)(self._member_keys(key, i), state.members[i])
            for i, m in enumerate(self.members)
        ]
        return tuple(a[0] for a in asked), tuple(a[1] for a in asked)

    def evaluate(self, key: jax.Array, policies: tuple) -> tuple:
        """Values ``[restarts, samples]`` per member search (each member's own evaluator)."""
        return tuple(
            jax.vmap(m.evaluate)(self._member_keys(key, i), policies[i])
            for i, m in enumerate(self.members)
        )

    def tell(
        self,
        key: jax.Array,
        state: PortfolioState,
        samples: tuple,
        values: tuple,
        *,
        hyper: GDiceHyper | None = None,
        fresh=None,
    ):
        """Every member search told its values (``ThresholdSearch.tell``), then the best of
        them all kept; returns ``(state, GDiceMetrics)``. ``fresh(key, policy) -> value`` as in
        ``ThresholdSearch.tell`` (one policy; the portfolio ``vmap``s it over restarts)."""
        hyper = self.hyper if hyper is None else hyper
        members, metrics = [], []
        for i, (m, rate) in enumerate(zip(self.members, self.rates)):
            h = hyper if rate is None else hyper.replace(entropy=hyper.entropy.replace(rate=rate))

            def tell_one(k, s, smp, v, m=m, h=h):
                return m.tell(k, s, smp, v, hyper=h, fresh=fresh)

            new, met = jax.vmap(tell_one)(
                self._member_keys(key, i), state.members[i], samples[i], values[i]
            )
            members.append(new)
            metrics.append(met)
        bests = jnp.concatenate([s.progress.best_value for s in members])
        policies = jax.tree.map(lambda *xs: jnp.concatenate(xs), *[s.best_policy for s in members])
        winner = jnp.argmax(bests)
        progress, improved = state.progress.record(bests[winner])
        best_policy = select_tree(
            improved, jax.tree.map(lambda x: x[winner], policies), state.best_policy
        )
        met = jax.tree.map(lambda *xs: jnp.concatenate(xs), *metrics)
        out = GDiceMetrics(
            value=met.value.max(),
            best_value=progress.best_value,
            mean_value=met.mean_value.mean(),
            threshold=met.threshold.max(),
            kept=met.kept.sum(),
            injected=met.injected.any(),
        )
        return PortfolioState(tuple(members), best_policy, progress), out

    def step(self, key: jax.Array, state: PortfolioState, hyper: GDiceHyper | None = None):
        """One iteration of every member search (``ask``, ``evaluate``, ``tell``); returns
        ``(state, GDiceMetrics)``."""
        samples, policies = self.ask(key, state)
        return self.tell(key, state, samples, self.evaluate(key, policies), hyper=hyper)

    def policy_returns(self, key, policy, num: int, batch: int = 10_000):
        return self.members[0].policy_returns(key, policy, num, batch)

    @staticmethod
    def best_policy(state: PortfolioState) -> DeterministicTabularPolicy:
        return state.best_policy

    @property
    def polishes(self) -> bool:
        return self.members[0].polishes

    def finish(self, state: PortfolioState) -> tuple[PortfolioState, PolishInfo | None]:
        """Every member search's best policy polished as in :meth:`GDice.finish`, and the best
        polished one kept: the searches often end in different basins, and the one with the
        best value before the polish is not always the one whose basin holds the best local
        optimum (box pushing h 4: a search ending at 75.7 polishes to 97.27 where another
        member's polishes higher). ``PolishInfo`` describes the kept one."""
        if not self.polishes:
            return state, None
        search = self.members[0]
        candidates = jax.tree.map(
            lambda *xs: jnp.concatenate(xs),
            *[jax.tree.map(lambda x: x[None], state.best_policy)],
            *[s.best_policy for s in state.members],
        )  # [1 + all restarts, ...]: the portfolio's best first
        polished, values, infos = jax.lax.map(
            lambda p: search.polish_best(p, jnp.float32(-jnp.inf)), candidates
        )
        winner = jnp.argmax(values)  # the first of equal values: the portfolio's best
        take = lambda tree: jax.tree.map(lambda x: x[winner], tree)  # noqa: E731
        policy, info = take(polished), take(infos)
        value = jnp.maximum(values[winner], state.progress.best_value)
        progress = state.progress.replace(best_value=value)
        return state.replace(best_policy=policy, progress=progress), info


# ---------------------------------------------------------------------------------------------
# registration (cognet_jax.registry): config -> algorithm
# ---------------------------------------------------------------------------------------------
def build_from_config(config, env, env_params) -> GDice | GDicePortfolio:
    """The search of ``config`` (``experiment.algorithm = "gdice"``): ``evaluator = "auto"``
    resolved from the model's exact cost (``api.EXACT_AUTO_LIMIT``), the polish dropped when
    one sweep costs more than ``api.POLISH_SWEEP_LIMIT``, a portfolio when more than one
    search runs."""
    from cognet_jax.api import (
        BEST_RESPONSE_FLOATS,
        EXACT_AUTO_LIMIT,
        POLISH_SWEEP_LIMIT,
        check_exact_cost,
        exact_iteration_cost,
    )
    from cognet_jax.exact_jax import exact_cost
    from cognet_jax.registry import fields_from

    a = config.algorithm
    if env.num_obs is None:
        raise ConfigError(
            "env.name", f"G-DICE needs discrete observations; {config.env.name!r} has none"
        )
    evaluator = a.evaluator
    if evaluator == "auto":
        cost = exact_iteration_cost(env, a, env_params)
        hybrid_cost = cost * min(a.exact_top, a.samples) // a.samples
        evaluator = (
            "exact"
            if cost <= EXACT_AUTO_LIMIT
            else "hybrid"
            if hybrid_cost <= EXACT_AUTO_LIMIT
            else "rollouts"
        )
    settings = fields_from(GDiceSettings, a, evaluator=evaluator)
    if evaluator in ("exact", "hybrid"):
        check_exact_cost(env, a, env_params, evaluator)
    if settings.polish_sweeps and evaluator in ("exact", "hybrid"):
        moves = len(GDice(env, env_params, settings).polish_moves())
        if moves * exact_cost(env, a.nodes, env_params) > POLISH_SWEEP_LIMIT:
            # too costly for this model: no polish (results.json's "resolved" shows it)
            settings = dataclasses.replace(settings, polish_sweeps=0)
    if settings.best_response_rounds and not (settings.polish_sweeps and settings.layered):
        settings = dataclasses.replace(settings, best_response_rounds=0)
    if settings.best_response_rounds:
        costs = [best_response_cost(env, a.nodes, i, env_params) for i in range(env.num_agents)]
        if (
            max(c[0] for c in costs) > POLISH_SWEEP_LIMIT
            or max(c[1] for c in costs) > BEST_RESPONSE_FLOATS
        ):
            # too costly for this model: no best responses (results.json's "resolved")
            settings = dataclasses.replace(settings, best_response_rounds=0)
    hyper = fields_from(GDiceHyper, a, entropy=entropy_config(a))
    if a.restarts > 1 or a.shared_restarts > 0 or a.explore_restarts > 0:
        return GDicePortfolio(
            env,
            env_params,
            settings,
            hyper,
            a.shared_restarts,
            a.explore_restarts,
            a.explore_entropy_rate,
        )
    return GDice(env, env_params, settings, hyper)


def _register() -> None:
    from cognet_jax.config import GDiceAlgorithmSection
    from cognet_jax.registry import register_algorithm

    register_algorithm(
        "gdice",
        GDiceAlgorithmSection,
        build_from_config,
        dynamic=(*ENTROPY_FIELDS, "algorithm.alpha"),
        discrete=True,
        overwrite=False,
    )


_register()
