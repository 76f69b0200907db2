"""Settings of the default ``cognet-dice`` (``algorithms.cognet_weights``): its ``[algorithm]``
section with the checks of each field, the dynamic hyper-parameters, the static settings a
compiled search reads, and the counts that follow from them (the pool's size, the first
iteration of the refine phase, rollouts per iteration), and the rules that decide its
``standardize_inputs``, ``default_vote_scale``, ``restart_tol`` and ``refine_tol`` "auto" and
its ``budget_minutes`` from the problem."""

from __future__ import annotations

import dataclasses
import math
from typing import Literal

import jax
import jax.numpy as jnp
from flax import struct

from cognet_jax.algorithms.sizing import AUTO_BUDGET_ROLLOUTS, SIZE_FIELDS, sized
from cognet_jax.config import (
    NetworkSection,
    require,
    require_positive,
    require_probability,
    settings_class,
)
from cognet_jax.observations import (
    build_pipeline,
    check_network,
    input_statistics,
    neural_controller,
)


@dataclasses.dataclass
class CognetWeightsSection:
    """``[algorithm]`` of the default ``cognet-dice`` (this module). Per iteration
    ``candidates`` joint controllers, each evaluated with ``eval_rollouts`` rollouts (common
    random numbers), the best ``elites`` refit the distribution with smoothing ``alpha``;
    ``action_floor`` / ``category_floor`` mix the categoricals with the uniform distribution
    every iteration; the winner and the distribution's mode are re-evaluated on
    ``best_rollouts`` fresh rollouts for the anytime best. ``init_scale``: initial std of the
    hidden layer (``init_scale / sqrt(inputs)`` for the weights); ``vote_mean`` /
    ``vote_std``: initial Gaussian of the output votes (the default vote's scaled by
    ``default_vote_scale``; with ``vote_alternate`` in every other exploring search only, the
    first at 1, or at ``default_vote_scale`` with ``vote_first``; those searches converge at
    ``vote_restart_tol``, 0: ``restart_tol``); ``tied_vote_scale`` multiplies the default vote
    of candidates whose nodes are tied (reactive controllers); ``standardize_inputs``: search
    over a network that reads each input feature standardised by its mean and standard deviation
    under the random controller, with ``whiten_inputs`` its principal components each
    standardised instead (PCA whitening, off by default); ``paired_best``: the
    best policy so far is re-evaluated on the challengers' fresh rollouts and replaced only
    when a challenger beats it there;
    ``best_pool``: size of the pool of best policies raced on fresh rollouts (0: no pool);
    ``tie_structure``, ``restart_tol``, ``refine``, ``refine_scale``, ``refine_tol``,
    ``refine_levels``, ``refine_redraw`` and ``starts``: tied candidates, restarts, the refine
    phase and independent starts (``cognet_weights``); ``distinct_actions``: candidates may
    draw their nodes' actions without repeats until every action has a node
    (``weight_space.distinct_draw``; "auto": ``covers_rarely``); ``vote_sharpness``
    multiplies every vote of the policies the search runs (the softmax over next nodes is
    that much sharper, the argmax the same), ``kept_sharpness`` those of the policies the
    anytime best keeps only; ``polish_share``: the paired-rollout polish of the kept policy
    after the search may simulate at most that share of the search's rollouts
    (``algorithms.weight_polish``; 0: none); ``polish_axes``: its moves include rewriting a
    node's weakest unit as a threshold on one feature (AXIS, on inputs of at most
    ``AXIS_MAX_FEATURES`` features) and starting a controller at another node's role
    (START); ``polish_counter``: and rewriting every controller as a counter of the evidence
    on one feature (COUNTER, inputs of at most ``AXIS_MAX_FEATURES`` features, with
    ``polish_axes``); ``polish_extend``: while each sweep applies a move, the polish goes on
    past its share up to that many times it (1: never); ``start_draw``: every candidate also draws,
    per agent, the node whose role it starts in (a categorical refit to the elites; tied
    agents share a controller and may start apart), from a first categorical that puts
    ``start_spread`` of its mass evenly on every node and the rest on node 0 (1: uniform).
    **[choice]** On, with ``start_spread`` 0: the exploring searches start every controller
    at node 0 and the refine phase's centred categoricals move the start roles, which found
    the paper setting's asymmetric start (two tied agents starting in different roles) in
    the search instead of only in the polish's START move (experiments/NOTES.md, "Twice the
    exploring searches, start roles in the refine phase"). The
    hidden width is ``network.hidden``."""

    nodes: int = 3
    iterations: int | Literal["auto"] = "auto"
    candidates: int | Literal["auto"] = "auto"
    eval_rollouts: int | Literal["auto"] = "auto"
    elites: int | Literal["auto"] = "auto"
    budget: float | Literal["auto"] = "auto"
    budget_minutes: float = 0.0
    alpha: float = 0.3
    action_floor: float = 0.02
    category_floor: float = 0.02
    best_rollouts: int = 1000
    common_random_numbers: bool = True
    init_scale: float = 10.0
    vote_mean: float = 5.0
    vote_std: float = 5.0
    default_vote_scale: float | Literal["auto"] = "auto"
    vote_alternate: bool = False
    vote_first: bool = False
    vote_restart_tol: float = 0.0
    tied_vote_scale: float = 1.0
    vote_sharpness: float = 1.0
    kept_sharpness: float = 10.0
    standardize_inputs: bool | Literal["auto"] = "auto"
    whiten_inputs: bool = False
    paired_best: bool = False
    best_pool: int = 4
    tie_structure: bool = True
    restart_tol: float | Literal["auto"] = "auto"
    distinct_actions: bool | Literal["auto"] = "auto"
    refine: float = 0.25
    refine_scale: float = 0.1
    refine_tol: float | Literal["auto"] = "auto"
    refine_redraw: float | Literal["auto"] = "auto"
    refine_levels: int = 1
    starts: int = 1
    polish_share: float = 0.25
    polish_axes: bool = True
    polish_counter: bool = True
    polish_extend: float = 2.0
    start_draw: bool = True
    start_spread: float = 0.0

    def rollouts_per_iteration(self) -> int:
        """Rollouts one iteration simulates (the size checks of ``budget.check_budget``)."""
        return rollouts_per_iteration(self)

    def size_references(self, env) -> dict[str, float]:
        """The sizes this section's "auto" rules give by default on ``env`` (the default budget,
        no noise measured), and that budget: what a too-long run's sizes are compared with to
        name the one to lower (``budget.check_budget``)."""
        auto = dict.fromkeys((*SIZE_FIELDS, "budget"), "auto")
        default = sized(dataclasses.replace(self, **auto), env)
        references = {f: getattr(default, f) for f in SIZE_FIELDS}
        return {**references, "budget": AUTO_BUDGET_ROLLOUTS * env.horizon * env.num_agents}

    @staticmethod
    def given_warnings(given: dict) -> list[str]:
        """What the user's ``[algorithm]`` settings ``given`` (before any "auto" is resolved)
        set to no effect: a ``budget`` beside every size."""
        sizes = [given.get(f, "auto") for f in SIZE_FIELDS]
        if given.get("budget", "auto") != "auto" and "auto" not in sizes:
            return [
                "algorithm.budget sizes nothing: every size is given (iterations, candidates, "
                "eval_rollouts, elites); leave one of them 'auto'"
            ]
        return []

    def check(self, config) -> None:
        require_positive(self, "algorithm", "nodes", "best_rollouts")
        require(
            self.budget == "auto" or 1 <= self.budget <= 1e16,
            "algorithm.budget",
            f"agent-steps, in 1 .. 1e16, or 'auto'; got {self.budget}",
        )
        require(
            0 <= self.start_spread <= 1,
            "algorithm.start_spread",
            f"a share of the first start roles' mass, in 0 .. 1, got {self.start_spread}",
        )
        require(
            0 <= self.budget_minutes <= 1e5,
            "algorithm.budget_minutes",
            f"wall minutes of search, in 0 (off) .. 1e5, got {self.budget_minutes}",
        )
        require(
            self.budget_minutes == 0 or self.budget == "auto",
            "algorithm.budget_minutes",
            "give the budget in agent-steps (algorithm.budget) or in minutes, not both",
        )
        for name in ("vote_first", "vote_restart_tol"):
            require(
                not getattr(self, name) or self.vote_alternate,
                f"algorithm.{name}",
                "acts on alternating searches only: set algorithm.vote_alternate = true",
            )
        require(
            self.budget_minutes == 0 or any(getattr(self, f) == "auto" for f in SIZE_FIELDS),
            "algorithm.budget_minutes",
            "every size is given (iterations, candidates, eval_rollouts, elites): a budget "
            "sizes nothing; leave one of them 'auto'",
        )
        require_probability(self, "algorithm", "alpha", "action_floor", "category_floor")
        for name in (
            "init_scale",
            "vote_mean",
            "vote_std",
            "default_vote_scale",
            "tied_vote_scale",
        ):
            v = getattr(self, name)
            require(v == "auto" or v >= 0, f"algorithm.{name}", f"must be >= 0, got {v}")
        require(self.init_scale > 0, "algorithm.init_scale", "must be > 0")
        for name in ("vote_sharpness", "kept_sharpness"):
            v = getattr(self, name)
            require(0 < v <= 1e4, f"algorithm.{name}", f"in (0, 1e4], got {v}")
        require(
            self.best_pool == 0 or 2 <= self.best_pool <= 64,
            "algorithm.best_pool",
            f"0 (no pool) or 2 .. 64, got {self.best_pool}",
        )
        for name in ("restart_tol", "refine_tol"):
            v = getattr(self, name)
            require(v == "auto" or 0 <= v < 1, f"algorithm.{name}", f"in [0, 1) or 'auto', got {v}")
        require(0 <= self.refine < 1, "algorithm.refine", f"in [0, 1), got {self.refine}")
        require(self.refine_scale > 0, "algorithm.refine_scale", "must be > 0")
        require(
            0 <= self.polish_share <= 1,
            "algorithm.polish_share",
            f"in [0, 1] (0: no polish), got {self.polish_share}",
        )
        require(
            1 <= self.polish_extend <= 10,
            "algorithm.polish_extend",
            f"in [1, 10] (1: the polish stops at its share), got {self.polish_extend}",
        )
        require(
            self.refine_redraw == "auto" or 0 <= self.refine_redraw <= 1,
            "algorithm.refine_redraw",
            f"in [0, 1] or 'auto', got {self.refine_redraw}",
        )
        require(
            1 <= self.refine_levels <= 8,
            "algorithm.refine_levels",
            f"in 1 .. 8, got {self.refine_levels}",
        )
        require(
            0 <= self.vote_restart_tol < 1,
            "algorithm.vote_restart_tol",
            f"in [0, 1) (0: restart_tol), got {self.vote_restart_tol}",
        )
        require_positive(self, "algorithm", "starts")
        require(
            not (self.whiten_inputs is True and self.standardize_inputs is False),
            "algorithm.whiten_inputs",
            "whitening standardises the inputs: it needs standardize_inputs true or 'auto'",
        )
        require(
            self.distinct_actions in (True, False, "auto"),
            "algorithm.distinct_actions",
            f"true, false or 'auto', got {self.distinct_actions!r}",
        )
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
        if any(getattr(self, f) == "auto" for f in SIZE_FIELDS):
            return  # checked again once the registry resolved them (``sized``)
        require_positive(self, "algorithm", *SIZE_FIELDS)
        require(
            self.elites <= self.candidates,
            "algorithm.elites",
            f"elites ({self.elites}) cannot exceed algorithm.candidates ({self.candidates})",
        )
        require(self.elites >= 2, "algorithm.elites", "needs >= 2 to fit a standard deviation")


def pool_size(s) -> int:
    """Members of the race of best policies: ``best_pool``, none with ``paired_best``."""
    return 0 if s.paired_best else s.best_pool


def fresh_start(s, done):
    """Whether the search starts afresh after ``done`` iterations (``[]`` int32): the
    iterations before the refine phase are ``starts`` independent searches of equal length;
    the anytime best is kept across them."""
    period = max(1, refine_start(s) // s.starts)
    return (s.starts > 1) & (done > 0) & (done % period == 0) & (done < period * s.starts)


def refine_start(s) -> int:
    """The iteration after which the search refines the kept policy (``refine``): the last
    ``refine`` share of the iterations; ``iterations`` when there is none."""
    return s.iterations - round(s.refine * s.iterations)


def rollouts_per_iteration(s) -> int:
    """Rollouts one iteration of the settings (or section) ``s`` simulates: the candidates'
    evaluations plus the fresh evaluations of the winner and of the mode (and of the best so
    far, ``paired_best``, or of the pool's members, ``best_pool``)."""
    fresh = 2 + (1 if s.paired_best else 0) + pool_size(s)
    return s.candidates * s.eval_rollouts + fresh * s.best_rollouts


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


#: the exploring searches' fields that "auto" decides by the horizon (``resolve_search``):
#: values when the horizon is longer than the controller has nodes, and when it is not
SEARCH_LONG_HORIZON = {"default_vote_scale": 10.0, "restart_tol": 0.1, "refine_tol": 0.1}
SEARCH_SHORT_HORIZON = {"default_vote_scale": 1.0, "restart_tol": 0.02, "refine_tol": 0.2}


def loops_back(horizon: int, nodes: int) -> bool:
    """Whether a controller of ``nodes`` nodes must come back to a node within ``horizon``
    steps (``horizon > nodes``): then a node that repeats its action until an observation is
    far enough out -- its default vote winning over its units -- is the loop the episode needs
    (walk until near the beacon, listen until the count is clear), and the search starts with
    the default vote at the units' scale, in short exploring searches."""
    return horizon > nodes


def resolve_search(section, env):
    """``section`` (config section or ``WeightsSettings``) with ``default_vote_scale``,
    ``restart_tol`` and ``refine_tol`` "auto" decided by ``loops_back`` on ``env.horizon``:
    ``SEARCH_LONG_HORIZON`` or ``SEARCH_SHORT_HORIZON``; numbers given are kept.
    **[choice]** Where the controller must loop back, the long-horizon values let a node
    repeat its action until an observation is far enough out and spend the budget on short
    exploring searches; where every step can run a node of its own (tagging's thesis setting,
    the heatmap) the next node is the observation's to decide and the short-horizon values
    stay (8-seed sweeps of the suite: experiments/NOTES.md)."""
    if section.distinct_actions == "auto":
        distinct = covers_rarely(env.action_counts, section.nodes)
        section = dataclasses.replace(section, distinct_actions=distinct)
    if section.refine_redraw == "auto":
        section = dataclasses.replace(section, refine_redraw=redraw_share(env.obs_shape))
    auto = [f for f in SEARCH_LONG_HORIZON if getattr(section, f) == "auto"]
    if not auto:
        return section
    values = SEARCH_LONG_HORIZON if loops_back(env.horizon, section.nodes) else SEARCH_SHORT_HORIZON
    return dataclasses.replace(section, **{f: values[f] for f in auto})


#: ``refine_redraw = "auto"``: the share of the refine phase's candidates that redraw a unit
#: on a scalar observation (``redraw_share``)
REDRAW_SCALAR = 0.5


def redraw_share(obs_shape) -> float:
    """``refine_redraw`` "auto": ``REDRAW_SCALAR`` where the observation is one number, else 0.
    **[choice]** A unit redrawn from the initial distribution is a random threshold on a
    scalar, which can add the region a converged controller lacks (the chase: 8-seed mean
    14.58 against 14.07, seeds at the hand-written 14.9 six of eight against four); on a 3 x 3
    patch it is a random direction in 9 dimensions, and the candidates it takes from tuning
    the kept policy cost more than it finds (plume 16.65 against 16.90; experiments/NOTES.md).
    """
    return REDRAW_SCALAR if math.prod(obs_shape) == 1 else 0.0


#: ``distinct_actions = "auto"`` is on where independent draws give a candidate every action
#: of some agent with less than this probability (``covers_rarely``)
DISTINCT_COVER = 0.1


def cover_probability(actions: int, nodes: int) -> float:
    """Probability that ``nodes`` independent uniform draws among ``actions`` actions run
    every action (inclusion-exclusion): 0 with fewer nodes than actions."""
    if nodes < actions:
        return 0.0
    return sum(
        (-1) ** k * math.comb(actions, k) * ((actions - k) / actions) ** nodes
        for k in range(actions + 1)
    )


def covers_rarely(action_counts, nodes: int) -> bool:
    """Whether ``distinct_actions`` "auto" is on: the controller has at least as many nodes
    as some agent has actions (then it can run them all), and independent draws of the
    initial distribution run them all with probability below ``DISTINCT_COVER``.
    **[choice]** A controller that must move four ways and stay (beacon, chase, plume: 5
    nodes, 5 actions, 0.038) then has the chance to be drawn whole, where independent draws
    give a few candidates of 200 every action; the problems that cover often enough keep the
    draws of before bit for bit (probabilities and sweeps: experiments/NOTES.md)."""
    return any(
        nodes >= a and cover_probability(a, nodes) < DISTINCT_COVER for a in set(action_counts)
    )


#: ``standardize_inputs = "auto"`` standardises inputs whose features hold fewer of the initial
#: units' thresholds within one standard deviation of their mean than centred features of this
#: spread (x ``sqrt(F)``, the thresholds' own scale) would (``missed_inputs``)
NARROW_INPUTS = 0.3


def threshold_cover(stats) -> jax.Array:
    """``[agents, F]``: per input feature, the share of the initial units' thresholds that fall
    within one standard deviation of the feature's mean, for inputs of statistics ``stats``
    (``(mean, scale) [agents, F]``, ``input_statistics``). A unit's threshold along a feature,
    ``-b / w`` with ``b ~ N(0, s)`` and ``w ~ N(0, s / sqrt(F))``, is a Cauchy variable of
    scale ``sqrt(F)`` centred at 0, so the share is
    ``(atan((m + d) / sqrt(F)) - atan((m - d) / sqrt(F))) / pi`` for a feature of mean ``m``
    and standard deviation ``d``."""
    mean, scale = stats
    root = math.sqrt(scale.shape[-1])
    return (jnp.arctan((mean + scale) / root) - jnp.arctan((mean - scale) / root)) / jnp.pi


def missed_inputs(stats) -> bool:
    """Whether the initial units' thresholds miss some input feature of statistics ``stats``:
    its ``threshold_cover`` below that of a centred feature spread ``NARROW_INPUTS x
    sqrt(F)`` (``2 atan(NARROW_INPUTS) / pi``, 0.19). A feature is missed when it is narrow
    (for a centred one exactly: its standard deviation below ``NARROW_INPUTS x sqrt(F)``) or
    far off centre (a reading in other units, an offset sensor): the units then split nothing
    along it until the search has moved their thresholds to the data.
    **[choice]** One missed feature is enough: a user's features come on different scales (a
    distance in metres beside a bearing in radians), and a missed one is unusable whatever the
    others are. The suite's scalar and planar observations are centred and spread 1 - 7 under
    the random controller (cover 0.52 - 0.91), its image patches a tenth of the limit's spread
    (cover 0.04 - 0.05): the limit splits the patches from the rest with a margin of about 3
    on both sides, and decides every problem of the suite as the earlier rule (the median
    spread against the same limit, image patches only) did. The README's simulator with its
    reading offset by 10 or 50, or in units a hundred times larger (cover 0.001 - 0.03), ends
    0.09 - 1.5 lower unstandardised (8 seeds each) than standardised, where it reaches the
    unchanged reading's value (experiments/NOTES.md, "Inputs off centre")."""
    limit = 2.0 * math.atan(NARROW_INPUTS) / math.pi
    return bool(float(jnp.min(threshold_cover(stats))) < limit)


#: ``input_whitening`` scales no direction by more than ``1 / sqrt`` of this share of the
#: largest variance (the plume's pixel noise: about 0.01 of it)
WHITEN_FLOOR = 1e-3


def input_whitening(stats, covariance) -> tuple[jax.Array, jax.Array]:
    """``(mean [agents, F], transform [agents, F, F])``: the PCA whitening of inputs of
    statistics ``stats`` and ``covariance`` (``input_covariance``), ``(x - mean) @ transform``
    of covariance the identity along every direction whose variance is at least
    ``WHITEN_FLOOR`` of the largest; the others are scaled as if at that floor (a direction
    that hardly varies -- a noise-free patch's covariance is often singular -- is not amplified
    without bound)."""
    mean, _ = stats
    values, vectors = jnp.linalg.eigh(covariance)  # [agents, F], [agents, F, F]
    floor = WHITEN_FLOOR * jnp.max(values, axis=-1, keepdims=True)
    return mean, vectors / jnp.sqrt(jnp.maximum(values, floor))[:, None, :]


def resolve_standardize(config, env, env_params) -> CognetWeightsSection:
    """``config.algorithm`` with ``standardize_inputs = "auto"`` decided: ``missed_inputs`` on
    the input statistics of ``env_params`` (measured once per simulator in a process, and
    needed by the polish anyway), on with ``whiten_inputs`` (whitening standardises);
    unchanged otherwise."""
    section = config.algorithm
    if section.standardize_inputs != "auto":
        return section
    if section.whiten_inputs:
        return dataclasses.replace(section, standardize_inputs=True)
    pipeline, controller = neural_controller(
        env, section.nodes, config.network.hidden, build_pipeline(config, env, env_params)
    )
    stats = input_statistics(env, controller, pipeline, env_params)
    return dataclasses.replace(section, standardize_inputs=missed_inputs(stats))


def minutes_to_budget(section, noise) -> CognetWeightsSection:
    """``section`` with ``budget_minutes`` turned into ``budget`` agent-steps at the noise
    pilot's measured rate (``Noise.rate``, a lower bound on a search's: the search's larger
    batches run faster, while its compile, the fresh evaluations of the anytime best and the
    final evaluation are not counted), and ``budget_minutes`` 0. **[choice]** The resolved
    config then holds agent-steps, so results.json, ``evaluate`` and ``--resume`` repeat the
    same sizes; the same minutes on another machine, or under load, give other sizes."""
    if not math.isfinite(noise.rate) or noise.rate <= 0:
        raise ValueError(f"the noise pilot measured no rate ({noise.rate})")
    budget = float(f"{noise.rate * 60.0 * section.budget_minutes:.3g}")
    return dataclasses.replace(section, budget=max(1.0, budget), budget_minutes=0.0)
