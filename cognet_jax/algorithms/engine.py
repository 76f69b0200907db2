"""The cross-entropy search engine of G-DICE and COG-DICE (SPEC sections 2-4): ``init / ask /
tell`` on explicit state pytrees, the iteration skeleton written once.

One iteration with the iteration key ``key`` (values are returns to **maximise**)::

    samples, policies = search.ask(key, state)        # draw `samples` controllers
    values = search.evaluate(key, policies)           # [samples]: mean returns (or your own)
    state, metrics = search.tell(key, state, samples, values)

``step(key, state)`` is exactly these three calls. ``tell`` keeps the elites above the rising
threshold V_w (``cross_entropy.elite_selection``), refits the distribution (the algorithm's
``update_distribution``: count MLE + smoothing, Beta refits), injects entropy when a trigger
fires (``Progress.should_inject`` and the algorithm's ``inject``), and tracks the anytime best:
the iteration's winner replaces the best policy when its value -- its in-loop value, or with
``best_rollouts > 0`` a fresh mean (``rollout.iteration_best``), or ``fresh(key, policy)`` when
given -- beats the best so far. Pass the same iteration key to all three calls: each derives its
own sub-keys from it (``ask`` and ``evaluate`` the two halves of ``split(key)``, ``tell``
``fold_in(key, 1)``), so a search driven by hand draws exactly what ``step`` draws.

Your own fitness function: evaluate ``policies`` (leading ``[samples]`` axis; e.g. ``vmap`` a
JAX simulation that runs ``cognet_jax.controller_step``) and pass the values to ``tell``.

A subclass provides ``settings`` (``samples``, ``elites``), ``hyper`` (``alpha``, ``entropy``),
``sample_policies(key, dist)``, ``evaluate_samples(key, policies)``,
``update_distribution(dist, elites, kept, hyper)`` and ``inject(dist, injected, hyper)``; and
``policies_of(samples)`` when a sample carries more than its policy (COG-DICE's unit points).

The other searches speak the same protocol with the same iteration key: the default
COGNet-DICE (``cognet_weights.CognetWeights``), a G-DICE portfolio (``gdice.GDicePortfolio``:
one entry per member search, leading axes ``[restarts, samples]``) and the thesis COGNet-DICE
(``cognet_dice.CognetDice``: ``ask`` rolls out the current policy on the algorithm's simulator
and returns the trajectories with the ``[top]`` candidates; ``tell`` takes the candidates'
values and trains the networks on those trajectories).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from flax import struct

from cognet_jax.algorithms.cross_entropy import EntropyConfig, elite_selection, select_tree
from cognet_jax.config import CogDiceAlgorithmSection
from cognet_jax.rollout import evaluate_candidates, iteration_best, many_returns


@struct.dataclass
class ThresholdHyper:
    """Dynamic (sweepable) hyper-parameters of G-DICE and COG-DICE: the smoothing rate and the
    entropy injection (defaults of their config sections; injection off as in SPEC)."""

    alpha: jax.Array | float = CogDiceAlgorithmSection.alpha  # = G-DICE's
    entropy: EntropyConfig = EntropyConfig(enabled=False)


@struct.dataclass
class SearchMetrics:
    """One iteration's figures (scalars; a leading ``[iterations]`` axis after a scan)."""

    value: jax.Array  # [] best sample value of this iteration
    best_value: jax.Array  # [] value of the anytime best so far
    mean_value: jax.Array  # [] mean sample value
    threshold: jax.Array  # [] V_w after this iteration
    kept: jax.Array  # [] number of elites
    injected: jax.Array  # [] bool: entropy injected this iteration


class RolloutValues:
    """Values by rollouts of the algorithm's simulator (``env``, ``env_params``,
    ``controller``, ``settings.eval_rollouts``, ``settings.common_random_numbers``), shared by
    every search."""

    #: bytes one search may hold in rollouts in flight (``memory.budget_bytes``; None: half
    #: the machine); candidates are evaluated in chunks when they do not fit
    memory: int | None = None

    def mean_returns(self, key: jax.Array, policies) -> jax.Array:
        """Mean return ``[C]`` of candidate policies (leading ``[C]`` axis), each over
        ``eval_rollouts`` rollouts, all with the same key (common random numbers) unless
        ``common_random_numbers`` is off."""
        s = self.settings
        return evaluate_candidates(
            self.env,
            self.controller,
            key,
            s.eval_rollouts,
            self.env_params,
            policies,
            memory=self.memory,
            common_random_numbers=s.common_random_numbers,
        )

    def policy_returns(self, key: jax.Array, policy, num: int, batch: int = 10_000):
        """Returns ``[num]`` of one ``policy`` (honest evaluation: pass a fresh key)."""
        return many_returns(self.env, self.controller, key, self.env_params, policy, num, batch)


class ThresholdSearch(RolloutValues):
    """The shared ``ask`` / ``evaluate`` / ``tell`` / ``step`` of G-DICE and COG-DICE."""

    @staticmethod
    def policies_of(samples):
        """The policies (leading ``[samples]`` axis) of what ``sample_policies`` drew."""
        return samples

    @property
    def fresh_rollouts(self) -> int:
        """Fresh rollouts that value the iteration's winner (0: its in-loop value)."""
        return self.settings.best_rollouts

    def mean_value(self, values: jax.Array) -> jax.Array:
        return values.mean()

    def ask(self, key: jax.Array, state):
        """``(samples, policies)``: ``settings.samples`` controllers drawn from the state's
        distribution (leading ``[samples]`` axis)."""
        k_sample, _ = jax.random.split(key)
        samples = self.sample_policies(k_sample, state.distribution)
        return samples, self.policies_of(samples)

    def evaluate(self, key: jax.Array, policies) -> jax.Array:
        """Values ``[samples]`` of the asked policies (the algorithm's own evaluator)."""
        _, k_eval = jax.random.split(key)
        return self.evaluate_samples(k_eval, policies)

    def tell(
        self,
        key: jax.Array,
        state,
        samples,
        values: jax.Array,
        *,
        hyper=None,
        fresh: Callable[[jax.Array, object], jax.Array] | None = None,
    ):
        """The state after ``values [samples]`` of ``samples`` (as ``ask`` returned them);
        returns ``(state, SearchMetrics)``. ``fresh(key, policy) -> value``: how to value the
        iteration's winner for the anytime best (default: ``fresh_rollouts`` rollouts of the
        algorithm's simulator, or the in-loop value when that is 0)."""
        hyper = self.hyper if hyper is None else hyper
        progress = state.progress
        idx, kept, threshold = elite_selection(values, progress.threshold, self.settings.elites)
        elites = jax.tree.map(lambda x: x[idx], samples)
        dist = self.update_distribution(state.distribution, elites, kept, hyper)
        injected = progress.should_inject(hyper.entropy)
        dist = self.inject(dist, injected, hyper)
        progress = progress.replace(threshold=threshold).after_injection(injected)
        policies = self.policies_of(samples)
        k_best = jax.random.fold_in(key, 1)
        if fresh is None:
            best_idx, winner, winner_value = iteration_best(
                self.env,
                self.controller,
                k_best,
                self.env_params,
                policies,
                values,
                self.fresh_rollouts,
            )
        else:
            best_idx = jnp.argmax(values)
            winner = jax.tree.map(lambda x: x[best_idx], policies)
            winner_value = fresh(k_best, winner)
        progress, improved = progress.record(winner_value)
        best_policy = select_tree(improved, winner, state.best_policy)
        metrics = SearchMetrics(
            value=values[best_idx],
            best_value=progress.best_value,
            mean_value=self.mean_value(values),
            threshold=progress.threshold,
            kept=kept.sum(),
            injected=injected,
        )
        return state.replace(distribution=dist, best_policy=best_policy, progress=progress), metrics

    def step(self, key: jax.Array, state, hyper=None):
        """One iteration: ``ask``, the algorithm's ``evaluate``, ``tell``."""
        samples, policies = self.ask(key, state)
        return self.tell(key, state, samples, self.evaluate(key, policies), hyper=hyper)
