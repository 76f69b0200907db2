"""Several independent G-DICE searches side by side in one compiled ``step``
(``GDicePortfolio``): the searches ``algorithm.restarts``, ``shared_restarts`` and
``explore_restarts`` ask for, the best policy of all kept, one polish of the best."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from flax import struct

from cognet_jax.algorithms.cross_entropy import (
    Progress,
    select_tree,
)
from cognet_jax.algorithms.engine import (
    Search,
    SearchMetrics,
    SearchParams,
)
from cognet_jax.algorithms.gdice_reports import TabularReports
from cognet_jax.algorithms.gdice_search import (
    GDice,
    identical_agents,
    polish_info,
    repeats_an_earlier,
)
from cognet_jax.algorithms.polish import (
    PolishState,
)
from cognet_jax.controllers.tabular import (
    DeterministicTabularPolicy,
)
from cognet_jax.memory import budget_bytes


@struct.dataclass
class PortfolioState:
    """``members``: one :class:`GDiceState` per member search, leaves with a leading
    ``[restarts]`` axis; ``best_policy`` and ``progress`` (iteration, best value) of them all."""

    members: tuple
    best_policy: DeterministicTabularPolicy
    progress: Progress


@dataclasses.dataclass(frozen=True, eq=False)
class GDicePortfolio(TabularReports, Search):
    """Several independent G-DICE searches run side by side in one compiled ``step``:
    ``settings.restarts`` searches as ``settings`` says (independent per-agent controllers
    unless ``shared_controller``) and ``shared_restarts`` with one shared controller (identical
    agents only; skipped otherwise). Each search keeps its own distributions, elite threshold
    and entropy injection; the portfolio keeps the best policy of all of them by their own best
    values (exact values with the exact evaluator, fresh means with ``best_rollouts``).

    ``explore_restarts`` more independent searches inject entropy at ``explore_rate`` instead
    of the hyper's rate: a strong injection lets a converged search leave a local optimum (box
    pushing h 3, where the independent search stays far below the optimum) but keeps
    the search from settling on a fine optimum (Dec-Tiger h 5, GridSmall h 5), so both run.

    Why: a shared controller finds optima that need every agent to change the same entry at
    once (Recycling with gamma 0.9, Dec-Tiger h 5), but can only find symmetric controllers;
    running both and keeping the better one needs no guess of which problem is which.

    Derived (``__post_init__``): ``members`` (one ``GDice`` per member search), ``restarts``
    (searches per member), ``rates`` (the entropy rate replacing the hyper's, or ``None``).
    The memory budget is shared: each member search gets ``memory / total restarts`` per
    search.
    """

    #: its polish branches between sweeps and best responses (``polish.Polish.advance``)
    finish_per_run = True

    shared_restarts: int = 0
    explore_restarts: int = 0
    explore_rate: float = 0.2

    def __post_init__(self):
        env, settings = self.env, self.settings
        plan = [(settings, settings.restarts, None)]
        if self.shared_restarts and identical_agents(env) and env.num_agents > 1:
            shared = dataclasses.replace(settings, shared_controller=True)
            plan.append((shared, self.shared_restarts, None))
        if self.explore_restarts:
            plan.append((settings, self.explore_restarts, self.explore_rate))
        total = sum(r for _, r, _ in plan)
        per_search = (budget_bytes() if self.memory is None else self.memory) // total
        members = tuple(GDice(env, s, per_search) for s, _, _ in plan)
        self._set(
            members=members,
            restarts=tuple(r for _, r, _ in plan),
            rates=tuple(rate for _, _, rate in plan),
            controller=members[0].controller,
        )

    def init(self, key: jax.Array, params: SearchParams) -> PortfolioState:
        members = tuple(
            jax.vmap(m.init, (0, None))(jax.random.split(jax.random.fold_in(key, i), r), params)
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

    def _member_params(self, params: SearchParams, i: int) -> SearchParams:
        rate = self.rates[i]
        if rate is None:
            return params
        entropy = params.hyper.entropy.replace(rate=rate)
        return params.replace(hyper=params.hyper.replace(entropy=entropy))

    def ask(self, key: jax.Array, state: PortfolioState, params: SearchParams):
        """``(samples, policies)``: one entry per member search, each with leading axes
        ``[restarts, samples]`` (see ``members`` and ``restarts``)."""
        asked = [
            jax.vmap(m.ask, (0, 0, None))(self._member_keys(key, i), state.members[i], params)
            for i, m in enumerate(self.members)
        ]
        return tuple(a[0] for a in asked), tuple(a[1] for a in asked)

    def evaluate(self, key: jax.Array, policies: tuple, params: SearchParams) -> tuple:
        """Values ``[restarts, samples]`` per member search (each member's own evaluator)."""
        return tuple(
            jax.vmap(m.evaluate, (0, 0, None))(self._member_keys(key, i), policies[i], params)
            for i, m in enumerate(self.members)
        )

    def tell(self, key, state: PortfolioState, samples, values, params, *, fresh_value=None):
        """Every member search told its values (``ThresholdSearch.tell``), then the best of
        them all kept; returns ``(state, SearchMetrics)``. ``fresh_value(key, policy)`` as in
        ``ThresholdSearch.tell`` (one policy; the portfolio ``vmap``s it over restarts)."""
        members, metrics = [], []
        for i, m in enumerate(self.members):

            def tell_one(k, s, smp, v, p, m=m):
                return m.tell(k, s, smp, v, p, fresh_value=fresh_value)

            new, met = jax.vmap(tell_one, (0, 0, 0, 0, None))(
                self._member_keys(key, i),
                state.members[i],
                samples[i],
                values[i],
                self._member_params(params, i),
            )
            members.append(new)
            metrics.append(met)
        bests = jnp.concatenate([s.progress.in_loop_best for s in members])
        policies = jax.tree.map(lambda *xs: jnp.concatenate(xs), *[s.best_policy for s in members])
        winner = jnp.argmax(bests)
        progress, improved = state.progress.record(bests[winner])
        best_policy = select_tree(
            improved, jax.tree.map(lambda x: x[winner], policies), state.best_policy
        )
        met = jax.tree.map(lambda *xs: jnp.concatenate(xs), *metrics)
        out = SearchMetrics(
            value=met.value.max(),
            in_loop_best=progress.in_loop_best,
            mean_value=met.mean_value.mean(),
            threshold=met.threshold.max(),
            kept=met.kept.sum(),
            injected=met.injected.any(),
        )
        return PortfolioState(tuple(members), best_policy, progress), out

    @property
    def polishes(self) -> bool:
        return self.members[0].polishes

    def _polish(self):
        """``(member search, Polish)`` of every candidate: the budget of all the searches,
        shared by the ``1 + restarts`` candidates."""
        search = self.members[0]
        searches = sum(self.restarts)
        return search, search.polisher(search.polish_budget(searches, 1 + searches))

    def finish_start(self, state: PortfolioState, params: SearchParams):
        """Every member search's best policy polished as in :meth:`GDice.finish`, and the best
        polished one kept: the searches often end in different basins, and the one with the
        best value before the polish is not always the one whose basin holds the best local
        optimum (box pushing h 4: a search ending at 75.7 polishes to 97.27 where another
        member's polishes higher). The candidates, ``[1 + all restarts]`` (the portfolio's
        best first), advance together, each by its own steps. A candidate equal to an earlier
        one (the portfolio's best is always some member's) starts done: its twin's polish is
        the same, and the twin, coming first, is the one kept."""
        if not self.polishes:
            return None
        search, polish = self._polish()
        candidates = jax.tree.map(
            lambda *xs: jnp.concatenate(xs),
            *[jax.tree.map(lambda x: x[None], state.best_policy)],
            *[s.best_policy for s in state.members],
        )
        work = jax.lax.map(lambda p: search.polish_start(p, params, polish), candidates)
        copy = repeats_an_earlier(candidates)
        return work.replace(sweeping=work.sweeping & ~copy, answered=work.answered & ~copy)

    def finish_advance(self, work: PolishState, params: SearchParams) -> PolishState:
        search, polish = self._polish()
        return jax.lax.map(lambda w: search.polish_advance(w, params, polish), work)

    def finish_done(self, work: PolishState) -> jax.Array:
        return jnp.all(jax.vmap(self._polish()[1].done)(work))

    def finish_end(self, state: PortfolioState, work: PolishState):
        """``PolishInfo`` describes the kept candidate (its own evaluations)."""
        search, polish = self._polish()
        winner = jnp.argmax(work.value)  # the first of equal values: the portfolio's best
        kept = jax.tree.map(lambda x: x[winner], work)
        value = jnp.maximum(kept.value, state.progress.in_loop_best)
        progress = state.progress.replace(in_loop_best=value)
        info = polish_info(kept, len(polish.moves), polish.budget)
        return state.replace(best_policy=kept.policy, progress=progress), info

    def settings_record(self) -> dict:
        """The settings as built, with every member search (``searches``)."""
        return {**super().settings_record(), "searches": self.searches}

    @property
    def searches(self) -> list[dict]:
        """What each member search is (for results.json's ``resolved``)."""
        return [
            {"shared_controller": m.settings.shared_controller, "restarts": r, "entropy_rate": e}
            for m, r, e in zip(self.members, self.restarts, self.rates)
        ]
