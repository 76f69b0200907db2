"""The search protocol every algorithm speaks, and the cross-entropy engine of G-DICE and
COG-DICE (SPEC sections 2-4).

**Protocol** (evosax style; values are returns to **maximise**). An algorithm object is
immutable configuration: the simulator's static description, the controller kind, static
settings and a memory budget. Everything numeric that one may ``vmap`` over -- the simulator's
params pytree and the algorithm's hyper-parameters -- is one :class:`SearchParams` argument::

    state = search.init(key, params)
    samples, policies = search.ask(key, state, params)         # draw the candidates
    values = search.evaluate(key, policies, params)            # [candidates] (or your own)
    state, metrics = search.tell(key, state, samples, values, params)
    state, info = search.finish(state, params)                 # after the last iteration
    policy = search.best_policy(state)

``step(key, state, params)`` is exactly ``ask``, ``evaluate`` and ``tell`` with one iteration
key. What the orchestration reads besides: ``state.progress.iteration`` (the iteration
count, ``cross_entropy.Progress``; the loop, ``cognet_jax.loop``), the metrics fields
``value``, ``in_loop_best`` and ``mean_value`` (``SearchMetrics``; a cross-entropy search also
fills ``threshold``, ``kept`` and ``injected``, which ``cognet_jax.records`` writes when they
are there), and the algorithm's ``rollouts_per_iteration``.

**Random streams**: each of ``ask``, ``evaluate`` and ``tell`` derives what it draws from the
iteration key through :func:`streams`, which splits it once into independent named keys --
``sample`` (the candidates; the thesis COGNet-DICE's rollouts of its current policy),
``evaluate`` (the candidates' rollouts), ``fresh`` (the fresh rollouts that value the
iteration's winner for the anytime best) and ``other`` (anything else: the default
COGNet-DICE's mode, the thesis algorithm's augmentation). So a search driven by hand draws
exactly what ``step`` draws, and the winner's fresh rollouts never reuse the rollouts it was
selected on.

**Evaluation**, one name per concept:

* ``evaluate(key, policies, params) -> [C]``: the algorithm's fitness of asked candidates;
* ``fresh_value(key, policy, params) -> []``: one policy's mean return over ``best_rollouts``
  fresh rollouts (the anytime best; the thesis COGNet-DICE falls back to ``eval_rollouts`` when
  it is 0); ``tell(..., fresh_value=fn)`` replaces it by your ``fn(key, policy)``;
* ``returns(key, policy, num, params, batch) -> [num]``: the returns of ``num`` rollouts of
  one policy (the honest evaluation, ``api.final_returns``, draws these from the seed's
  evaluation key).

**The threshold engine** (``ThresholdSearch``, G-DICE and COG-DICE): ``tell`` keeps the elites
above the rising threshold V_w (``cross_entropy.elite_selection``), refits the distribution
(the subclass's ``update_distribution``: count MLE + smoothing, Beta refits), injects entropy
when a trigger fires (``Progress.should_inject`` and the subclass's ``inject``), and tracks the
anytime best: the iteration's winner replaces the best policy when its value -- its in-loop
value, or with ``best_rollouts > 0`` a fresh mean, or ``fresh_value(key, policy)`` when given
-- beats the best so far. A subclass provides ``sample_policies(key, dist)``,
``update_distribution(dist, elites, kept, hyper)``, ``inject(dist, injected, hyper)``, and
``policies_of(samples)`` when a sample carries more than its policy (COG-DICE's unit points).
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from typing import Any, ClassVar, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from cognet_jax.algorithms.cross_entropy import (
    EntropyConfig,
    EntropySection,
    elite_selection,
    entropy_config,
    select_tree,
)
from cognet_jax.config import require, require_positive, require_probability
from cognet_jax.controllers.base import guarded_nodes
from cognet_jax.envs.base import GuardedSteps
from cognet_jax.rollout import evaluate_candidates, many_returns, rollouts


@struct.dataclass
class SearchParams:
    """The numbers a search runs with, as one pytree: ``env`` the simulator's params
    (``env_params``), ``hyper`` the algorithm's dynamic hyper-parameters. Every leaf may be
    batched under ``vmap`` (several noise levels, several ``alpha``) with no recompilation."""

    env: Any
    hyper: Any


class Streams(NamedTuple):
    """The independent random streams of one iteration (``streams(key)``)."""

    sample: jax.Array
    evaluate: jax.Array
    fresh: jax.Array
    other: jax.Array


def streams(key: jax.Array) -> Streams:
    """``key`` split once into the iteration's named streams. (The split is prefix-stable
    under JAX's partitionable threefry: ``split(key, 4)[:2] == split(key, 2)``, so the
    ``sample`` and ``evaluate`` streams are those of a two-way split.)"""
    return Streams(*jax.random.split(key, 4))


@dataclasses.dataclass
class ThresholdSection(EntropySection):
    """The ``[algorithm]`` fields G-DICE and COG-DICE share (SPEC sections 2-4): entropy
    injection (``EntropySection``; off as in SPEC), N_n ``nodes``, ``iterations``, N_s
    ``samples``, N_b ``elites``, N_sim ``eval_rollouts``, smoothing ``alpha``, common random
    numbers and ``best_rollouts`` (0: best tracking compares the iteration winner's in-loop
    mean, SPEC; N > 0: a fresh mean over N rollouts, free of the winner's selection bias).
    Each algorithm's section extends it (and may change the defaults)."""

    nodes: int = 3
    iterations: int = 100
    samples: int = 100
    elites: int = 10
    eval_rollouts: int = 100
    alpha: float = 0.1
    common_random_numbers: bool = True
    best_rollouts: int = 0

    def rollouts_per_iteration(self) -> int:
        """Rollouts one iteration simulates at least (``budget.check_budget``'s size checks)."""
        return self.samples * self.eval_rollouts + self.best_rollouts

    def check(self, config) -> None:
        require_positive(self, "algorithm", "nodes", "iterations", "samples", "elites")
        require_positive(self, "algorithm", "eval_rollouts")
        require(
            self.elites <= self.samples,
            "algorithm.elites",
            f"elites ({self.elites}) cannot exceed algorithm.samples ({self.samples})",
        )
        require_probability(self, "algorithm", "alpha")
        require(self.best_rollouts >= 0, "algorithm.best_rollouts", "must be >= 0")
        self.check_entropy()


@struct.dataclass
class ThresholdHyper:
    """Dynamic (sweepable) hyper-parameters of G-DICE and COG-DICE: the smoothing rate and the
    entropy injection (injection off by default, as in SPEC)."""

    alpha: jax.Array | float = 0.1
    entropy: EntropyConfig = EntropyConfig(enabled=False)


def threshold_hyper(config) -> ThresholdHyper:
    """The dynamic hyper-parameters of a G-DICE or COG-DICE ``config.algorithm``: ``alpha``
    and entropy injection (the registry entries' ``hyper``)."""
    a = config.algorithm
    return ThresholdHyper(alpha=a.alpha, entropy=entropy_config(a))


@struct.dataclass
class SearchMetrics:
    """One iteration's figures (scalars; a leading ``[iterations]`` axis after a scan)."""

    value: jax.Array  # [] best sample value of this iteration
    in_loop_best: jax.Array  # [] value of the anytime best so far
    mean_value: jax.Array  # [] mean sample value
    # cross-entropy searches only (None where a search has no such figure):
    threshold: jax.Array | None = None  # [] V_w after this iteration
    kept: jax.Array | None = None  # [] number of elites
    injected: jax.Array | None = None  # [] bool: entropy injected this iteration
    restarted: jax.Array | None = None  # [] bool: the distribution started afresh this iteration


@dataclasses.dataclass(frozen=True, eq=False)
class Search:
    """What every built-in search shares: values by rollouts of its simulator.

    ``env``: the simulator's static description; ``settings``: the algorithm's static settings
    (with ``eval_rollouts``, ``common_random_numbers``, ``best_rollouts`` where it uses them);
    ``memory``: bytes its rollouts in flight may take (``memory.budget_bytes``; ``None``: half
    the machine), candidates are evaluated in chunks when they do not fit. A subclass sets
    ``controller`` (the controller kind) in ``__post_init__``.
    """

    env: Any
    settings: Any
    memory: int | None = None

    def _set(self, **fields) -> None:
        """Set derived fields of this frozen object (``__post_init__`` only)."""
        for name, value in fields.items():
            object.__setattr__(self, name, value)

    #: the ``vmap`` axes of the asked candidates' policy pytree (0: every leaf has the leading
    #: ``[C]`` axis; the thesis COGNet-DICE batches only the action tables)
    candidate_axes: ClassVar[Any] = 0

    def evaluate(self, key, policies, params: SearchParams) -> jax.Array:
        """Mean return ``[C]`` of the asked candidates (leading ``[C]`` axis, ``candidate_axes``),
        each over ``eval_rollouts`` rollouts from the iteration's ``evaluate`` stream, all with
        the same key (common random numbers) unless ``common_random_numbers`` is off."""
        s = self.settings
        return evaluate_candidates(
            self.env,
            self.controller,
            streams(key).evaluate,
            s.eval_rollouts,
            params.env,
            policies,
            policy_axes=self.candidate_axes,
            memory=self.memory,
            common_random_numbers=s.common_random_numbers,
        )

    def returns(self, key, policy, num: int, params: SearchParams, batch: int = 10_000):
        """Returns ``[num]`` of one ``policy`` (``batch`` rollouts at a time): the honest
        evaluation's, where a NaN observation, an action its agent lacks or a node its
        controller lacks makes the episode's return NaN (refused, ``envs.base.GuardedSteps``,
        ``controllers.base.guarded_nodes``)."""
        env, controller = GuardedSteps(self.env), guarded_nodes(self.controller)
        return many_returns(env, controller, key, params.env, policy, num, batch)

    def fresh_value(self, key, policy, params: SearchParams) -> jax.Array:
        """Mean return ``[]`` of one policy over ``best_rollouts`` fresh rollouts."""
        n = self.settings.best_rollouts
        return rollouts(self.env, self.controller, key, n, params.env, policy).mean()

    def step(self, key, state, params: SearchParams):
        """One iteration: ``ask``, the algorithm's ``evaluate``, ``tell``."""
        samples, policies = self.ask(key, state, params)
        return self.tell(key, state, samples, self.evaluate(key, policies, params), params)

    # -- after the last iteration: ``finish``, also as steps ---------------------------------
    #: a sweep runs the ``finish`` of its runs one after another, each with its own program,
    #: instead of side by side (``vmap``): side by side, a ``lax.cond`` in a step computes
    #: every branch for every run (G-DICE's polish: its best responses on every sweep)
    finish_per_run: ClassVar[bool] = False

    def finish_start(self, state, params: SearchParams):
        """The work ``finish`` does after the last iteration, as a pytree advanced by
        ``finish_advance`` until ``finish_done`` (a driver shows progress and obeys signals
        between steps); ``None``: nothing to do (here)."""
        return None

    def finish_advance(self, work, params: SearchParams):
        return work

    def finish_done(self, work) -> jax.Array:
        return jnp.bool_(True)

    def finish_end(self, state, work):
        """``(state, info)`` once the work is done."""
        return state, None

    def finish(self, state, params: SearchParams):
        """After the last iteration (pure, jit-able): ``(state, info)``, the steps of
        ``finish_start`` in one ``while_loop`` (``info`` None when there is nothing to do)."""
        work = self.finish_start(state, params)
        if work is None:
            return state, None
        work = jax.lax.while_loop(
            lambda w: ~self.finish_done(w), lambda w: self.finish_advance(w, params), work
        )
        return self.finish_end(state, work)

    @staticmethod
    def best_policy(state):
        return state.best_policy

    # -- what a finished run reports: the driver asks the search, never its kind -------------
    def settings_record(self) -> dict:
        """The settings as built, JSON-ready (results.json ``resolved``: e.g. sizes "auto"
        chose)."""
        if not dataclasses.is_dataclass(self.settings):
            return {}
        return json.loads(json.dumps(dataclasses.asdict(self.settings), default=str))

    def history_record(self, history) -> dict:
        """Fields of results.json from one run's metrics ``history`` (this search's metrics,
        leaves ``[iterations]``), beside the value curves every run writes
        (``values_per_iteration``, ``in_loop_best_per_iteration``). Default: the
        cross-entropy figures of ``SearchMetrics`` the search reports (not ``None``):
        ``threshold_per_iteration``, ``kept_per_iteration``, ``entropy_injections`` (the
        iterations that injected entropy) and ``restarts`` (that restarted the distribution)."""
        fields = {}
        for name, field in (
            ("threshold", "threshold_per_iteration"),
            ("kept", "kept_per_iteration"),
        ):
            series = getattr(history, name, None)
            if series is not None:
                fields[field] = np.asarray(series).tolist()
        for name, field in (("injected", "entropy_injections"), ("restarted", "restarts")):
            flags = getattr(history, name, None)
            if flags is not None:
                fields[field] = int(np.sum(flags))
        return fields

    def finish_record(self, info, seconds: float) -> dict | None:
        """One run's record of ``finish`` for results.json (``info``: what ``finish_end``
        returned for that run; ``seconds``: its wall time); ``None``: nothing to record."""
        return None

    def finish_status(self, work) -> dict:
        """Fields of the progress line after a step of ``finish`` (``work`` of every run)."""
        return {}

    def finish_line(self, record: dict) -> str | None:
        """A line for the person who ran ``train``, from ``finish_record``'s record."""
        return None

    def exact_record(self, config, policy) -> dict | None:
        """Exact values of a finished run's best policy, added to its ``final_value``
        (``None``: the search computes none)."""
        return None

    def write_plots(self, config, policy, record: dict, out_dir) -> list:
        """Figures of a finished run's best policy in ``out_dir`` (the driver draws the value
        curve, ``values.png``, for every search); returns the paths written."""
        return []

    def run_files(self) -> dict:
        """Files a run folder keeps beside its policy, ``{name: (config_field, bytes)}``
        (e.g. an encoder the policy reads its observations through): ``evaluate`` of the
        folder points ``config_field`` at the kept file and refuses one replaced since."""
        return {}


class ThresholdSearch(Search):
    """The shared ``ask`` / ``evaluate`` / ``tell`` of G-DICE and COG-DICE."""

    @staticmethod
    def policies_of(samples):
        """The policies (leading ``[samples]`` axis) of what ``sample_policies`` drew."""
        return samples

    @property
    def best_rollouts(self) -> int:
        """Fresh rollouts that value the iteration's winner (0: its in-loop value)."""
        return self.settings.best_rollouts

    def mean_value(self, values: jax.Array) -> jax.Array:
        return values.mean()

    def ask(self, key, state, params: SearchParams):
        """``(samples, policies)``: ``settings.samples`` controllers drawn from the state's
        distribution (leading ``[samples]`` axis), from the ``sample`` stream."""
        samples = self.sample_policies(streams(key).sample, state.distribution)
        return samples, self.policies_of(samples)

    def anytime_value(self, key, winner, in_loop, params, fresh_value=None) -> jax.Array:
        """The value the anytime best compares for the iteration's ``winner``: ``fresh_value``
        (yours), else the mean of ``best_rollouts`` fresh rollouts, else its ``in_loop``
        value; ``key`` is the iteration's ``fresh`` stream."""
        if fresh_value is not None:
            return fresh_value(key, winner)
        if self.best_rollouts > 0:
            return self.fresh_value(key, winner, params)
        return in_loop

    def tell(
        self,
        key,
        state,
        samples,
        values: jax.Array,
        params: SearchParams,
        *,
        fresh_value: Callable[[jax.Array, Any], jax.Array] | None = None,
    ):
        """The state after ``values [samples]`` of ``samples`` (as ``ask`` returned them);
        returns ``(state, SearchMetrics)``."""
        hyper = params.hyper
        progress = state.progress
        idx, kept, threshold = elite_selection(values, progress.threshold, self.settings.elites)
        elites = jax.tree.map(lambda x: x[idx], samples)
        dist = self.update_distribution(state.distribution, elites, kept, hyper)
        injected = progress.should_inject(hyper.entropy)
        dist = self.inject(dist, injected, hyper)
        progress = progress.replace(threshold=threshold).after_injection(injected)
        best_idx = jnp.argmax(values)
        winner = jax.tree.map(lambda x: x[best_idx], self.policies_of(samples))
        value = self.anytime_value(
            streams(key).fresh, winner, values[best_idx], params, fresh_value
        )
        progress, improved = progress.record(value)
        best_policy = select_tree(improved, winner, state.best_policy)
        metrics = SearchMetrics(
            value=values[best_idx],
            in_loop_best=progress.in_loop_best,
            mean_value=self.mean_value(values),
            threshold=progress.threshold,
            kept=kept.sum(),
            injected=injected,
        )
        return state.replace(distribution=dist, best_policy=best_policy, progress=progress), metrics
