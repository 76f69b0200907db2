"""COGNet-DICE (SPEC section 5): cross-entropy search over FSCs whose node transitions are small
neural networks on continuous observations.

One iteration (``CognetThesis.step``, compiled once) -- values are returns to **maximise**:

1. roll out the current stochastic joint policy ``rollouts`` times, recording trajectories;
2. pre-select the ``top`` rollouts with the highest return;
3. candidates: for each pre-selected rollout, the current policy with the action distribution of
   every visited node replaced by the empirical action frequencies of that rollout;
4. evaluate every candidate with ``eval_rollouts`` rollouts (common random numbers by default);
5. elite threshold on the candidate values (``threshold_rule="elite"``), or, as in the thesis
   code, keep only candidates beating the best in-loop value so far (``"best"``); keep ``keep``;
6. action distributions: count MLE over the kept *original* rollouts (every visit counts),
   smoothing with ``alpha``, optional entropy injection (SPEC section 2);
7. node networks: pairs ``(z_{t+1}, q_{t+1})`` for every t with ``q_t = q`` in the kept rollouts
   (mapped by the observation pipeline, ``cognet_jax.observations``: identity, or the VAE
   encoder's mean, plus optional augmentation pairs) train node q's network by softmax
   cross-entropy (``train_steps`` full-batch optax steps per iteration; members
   without pairs are masked so their optimiser state does not move them);
8. evaluate the updated joint policy with ``eval_rollouts`` fresh rollouts, record the value and
   keep the best policy (anytime).

**Separate training** (``separate=True``, thesis 5.2): node q's action distribution is fixed to
a one-hot on action ``q mod |A|`` and steps 3-6 are skipped. **[choice]** The kept rollouts are
then the ``keep`` best of the ``rollouts`` rollouts by return, without a threshold (single-rollout
returns are too noisy for a rising threshold: it would lock onto the luckiest one).

Optimiser **[choice]**: Adam (``optimizer="adam"``) with the learning rate in the dynamic
hyper-parameters; ``"sgd"`` gives SGD with momentum as in the thesis code.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Literal

import jax
import jax.numpy as jnp
import optax
from flax import struct

from cognet_jax.algorithms.cross_entropy import (
    ENTROPY_FIELDS,
    ENTROPY_SECTION_FIELDS,
    EntropyConfig,
    EntropySection,
    Progress,
    elite_selection,
    entropy_config,
    inject_entropy,
    select_tree,
    smooth,
)
from cognet_jax.algorithms.engine import SearchParams, streams
from cognet_jax.algorithms.neural_search import NeuralSearch
from cognet_jax.config import (
    NetworkSection,
    require,
    require_positive,
    require_probability,
    settings_class,
)
from cognet_jax.controllers.base import action_support
from cognet_jax.controllers.neural import NeuralController, NeuralPolicy
from cognet_jax.observations import (
    ObservationPipeline,
    build_pipeline,
    check_network,
    neural_controller,
)
from cognet_jax.registry import fields_from, register_algorithm
from cognet_jax.rollout import rollouts


@dataclasses.dataclass
class CognetThesisSection(EntropySection):
    """``[algorithm]`` of COGNet-DICE as the thesis specifies it (SPEC 5), algorithm
    ``cognet-dice-thesis``; names follow the thesis: K_roll ``rollouts``, K_top ``top``,
    K_keep ``keep``, K_eval ``eval_rollouts``; entropy injection on (``EntropySection``)."""

    entropy_injection: bool = True
    nodes: int = 3
    iterations: int = 500
    rollouts: int = 1000
    top: int = 100
    keep: int = 10
    eval_rollouts: int = 100
    alpha: float = 0.2
    threshold_rule: Literal["elite", "best"] = "elite"
    separate: bool = False
    common_random_numbers: bool = True
    train_last_transition: bool = True
    #: "kept" (SPEC) or "top": train the node networks on the pairs of all K_top pre-selected
    #: rollouts instead of the K_keep kept ones
    train_on: Literal["kept", "top"] = "kept"
    #: 0 (SPEC): step 8 evaluates the updated policy with eval_rollouts; N > 0: with N
    best_rollouts: int = 0

    def rollouts_per_iteration(self) -> int:
        """Rollouts one iteration simulates (the size checks of ``budget.check_budget``)."""
        return rollouts_per_iteration(self)

    def check(self, config) -> None:
        names = ("nodes", "iterations", "rollouts", "top", "keep", "eval_rollouts")
        require_positive(self, "algorithm", *names)
        require(
            self.top <= self.rollouts,
            "algorithm.top",
            f"pre-selected rollouts ({self.top}) cannot exceed algorithm.rollouts "
            f"({self.rollouts})",
        )
        limit = self.rollouts if self.separate else self.top
        require(
            self.keep <= limit,
            "algorithm.keep",
            f"kept elites ({self.keep}) cannot exceed the candidates ({limit})",
        )
        require_probability(self, "algorithm", "alpha")
        self.check_entropy()
        require(self.best_rollouts >= 0, "algorithm.best_rollouts", "must be >= 0")
        check_network(config, training=True)


def rollouts_per_iteration(s) -> int:
    """Rollouts one iteration of the settings (or section) ``s`` simulates: the policy's
    rollouts, the candidates' evaluations (not in separate training) and the evaluation of the
    updated policy."""
    candidates = 0 if s.separate else s.top * s.eval_rollouts
    return s.rollouts + candidates + (s.best_rollouts or s.eval_rollouts)


@struct.dataclass
class CognetHyper:
    """Dynamic (sweepable) hyper-parameters of COGNet-DICE; defaults those of the config."""

    alpha: jax.Array | float = CognetThesisSection.alpha
    learning_rate: jax.Array | float = NetworkSection.learning_rate
    entropy: EntropyConfig = EntropyConfig()


#: static settings: the fields of ``CognetThesisSection`` without the hyper-parameters
#: (``CognetHyper``), and the networks' fields of ``[network]``
CognetSettings = settings_class(
    "CognetSettings",
    CognetThesisSection,
    exclude=("alpha", *ENTROPY_SECTION_FIELDS),
    extra=tuple(
        (NetworkSection, name) for name in ("hidden", "train_steps", "optimizer", "momentum")
    ),
)


@struct.dataclass
class CognetState:
    """Full search state (a pytree): current and best policy, optimiser state, bookkeeping."""

    policy: NeuralPolicy
    opt_state: Any
    best_policy: NeuralPolicy
    progress: Progress


@struct.dataclass
class CognetMetrics:
    value: jax.Array  # [] step-8 value of the updated policy
    in_loop_best: jax.Array  # [] best in-loop value so far
    threshold: jax.Array  # [] V_w after this iteration
    kept: jax.Array  # [] number of kept candidates
    best_candidate: jax.Array  # [] largest candidate value
    rollout_mean: jax.Array  # [] mean return of step-1 rollouts
    injected: jax.Array  # [] bool


@struct.dataclass
class CognetAsked:
    """What ``CognetThesis.ask`` drew for ``tell``: the current policy's recorded rollouts
    (``Trajectory``, leading ``[rollouts]`` axis), the indices ``[top]`` of the pre-selected
    ones and their action counts ``[top, agents, nodes, actions]`` (``None`` in separate
    training)."""

    traj: Any
    top_idx: jax.Array | None = None
    counts: jax.Array | None = None


def make_optimizer(settings: CognetSettings) -> optax.GradientTransformation:
    """The optimiser *without* its learning rate (applied from ``CognetHyper``)."""
    if settings.optimizer == "adam":
        return optax.scale_by_adam()
    if settings.optimizer == "sgd":
        return optax.trace(decay=settings.momentum)
    raise ValueError(f"unknown optimizer {settings.optimizer!r}")


def fixed_one_hot_actions(controller: NeuralController) -> jax.Array:
    """Separate training: node q plays action ``q mod |A|``; ``[agents, nodes, actions]``."""
    n, a = controller.num_nodes, controller.num_actions
    table = jax.nn.one_hot(jnp.arange(n) % a, a, dtype=jnp.float32)
    return jnp.broadcast_to(table, (controller.num_agents, n, a))


def rollout_action_counts(traj_nodes, traj_actions, num_nodes, num_actions):
    """Per-rollout action counts ``[..., agents, nodes, actions]`` from trajectories
    ``nodes / actions [..., H, agents]`` (every visit counts once)."""
    node_oh = jax.nn.one_hot(traj_nodes, num_nodes, dtype=jnp.float32)
    act_oh = jax.nn.one_hot(traj_actions, num_actions, dtype=jnp.float32)
    return jnp.einsum("...tiq,...tia->...iqa", node_oh, act_oh)


def candidate_action_probs(current: jax.Array, counts: jax.Array) -> jax.Array:
    """Clone rule: ``current [agents, nodes, actions]`` with visited rows replaced by the
    empirical frequencies in ``counts [C, agents, nodes, actions]``; returns ``[C, ...]``."""
    total = counts.sum(-1, keepdims=True)
    return jnp.where(total > 0, counts / jnp.maximum(total, 1.0), current[None])


def training_pairs(traj, kept_idx, kept_mask, last_transition: bool = True):
    """Training pairs of the kept rollouts, per agent.

    Args:
      traj: batched ``Trajectory`` with leading axis R (``nodes [R, H, agents]`` ...).
      kept_idx: ``[K]`` indices of the kept rollouts; ``kept_mask [K]`` which of them are real.
      last_transition: include ``t = H - 1`` (whose next node is never used by the episode).

    Returns:
      ``(obs [agents, K*H, *obs_shape], src [agents, K*H], tgt [agents, K*H], valid [agents, K*H])``
      where pair p says: in node ``src`` the agent saw ``obs`` and moved to ``tgt``.
    """
    k = kept_idx.shape[0]
    h = traj.nodes.shape[1]
    nodes = traj.nodes[kept_idx]  # [K, H, agents]
    nxt = traj.next_nodes[kept_idx]
    obs = traj.obs[kept_idx]  # [K, H, agents, *obs]
    valid = jnp.broadcast_to(kept_mask[:, None, None], nodes.shape)
    if not last_transition:
        valid = valid & (jnp.arange(h) < h - 1)[None, :, None]
    agents = nodes.shape[-1]

    def flat(x):  # [K, H, agents, ...] -> [agents, K*H, ...]
        x = jnp.moveaxis(x, 2, 0)
        return x.reshape((agents, k * h) + x.shape[3:])

    return flat(obs), flat(nodes), flat(nxt), flat(valid)


@dataclasses.dataclass(frozen=True, eq=False)
class CognetThesis(NeuralSearch):
    """COGNet-DICE on one environment; ``init`` / ``ask`` / ``evaluate`` / ``tell`` / ``step``
    are pure and jit-able (the protocol of ``algorithms.engine``).

    ``pipeline`` maps the environment's observations to the node networks' input (default: the
    identity); see ``cognet_jax.observations``.
    """

    pipeline: ObservationPipeline | None = None
    #: the candidates share the current networks: only their action tables are batched
    candidate_axes = NeuralPolicy(action_probs=0, net_params=None)

    def __post_init__(self):
        s = self.settings
        pipeline, controller = neural_controller(self.env, s.nodes, s.hidden, self.pipeline)
        self._set(pipeline=pipeline, controller=controller, optimizer=make_optimizer(s))

    # -- state ---------------------------------------------------------------------------
    def init(self, key: jax.Array, params: SearchParams) -> CognetState:
        policy = self.controller.init(key)
        if self.settings.separate:
            policy = policy.replace(action_probs=fixed_one_hot_actions(self.controller))
        opt_state = jax.vmap(jax.vmap(self.optimizer.init))(policy.net_params)
        return CognetState(
            policy=policy,
            opt_state=opt_state,
            best_policy=policy,
            progress=Progress.create(self.settings.entropy_window),
        )

    # -- pieces ------------------------------------------------------------------------------
    def train_networks(self, net_params, opt_state, pairs, hyper: CognetHyper):
        """``train_steps`` full-batch steps of softmax cross-entropy on every member at once."""
        obs, src, tgt, valid = pairs
        n = self.settings.nodes
        # weights[a, q, p]: pair p of agent a belongs to member (a, q)
        weights = (valid[:, None, :] & (src[:, None, :] == jnp.arange(n)[None, :, None])).astype(
            jnp.float32
        )
        counts = weights.sum(-1)  # [agents, nodes]
        has_data = counts > 0

        def member_loss(params, obs_a, tgt_a, w):
            logits = jax.vmap(self.controller.one_net_logits, (None, 0))(params, obs_a)
            ce = optax.softmax_cross_entropy_with_integer_labels(logits, tgt_a)
            return jnp.sum(w * ce) / jnp.maximum(w.sum(), 1.0)

        # grads over members: vmap agents (obs per agent) then nodes (weights per node)
        grad_fn = jax.vmap(
            jax.vmap(jax.grad(member_loss), in_axes=(0, None, None, 0)), in_axes=(0, 0, 0, 0)
        )
        update_fn = jax.vmap(jax.vmap(self.optimizer.update))

        def one_step(carry, _):
            params, opt = carry
            grads = grad_fn(params, obs, tgt, weights)
            updates, new_opt = update_fn(grads, opt, params)
            new_params = jax.tree.map(lambda p, u: p - hyper.learning_rate * u, params, updates)

            def masked(new, old):
                m = has_data.reshape(has_data.shape + (1,) * (new.ndim - 2))
                return jnp.where(m, new, old)

            return (
                jax.tree.map(masked, new_params, params),
                jax.tree.map(masked, new_opt, opt),
            ), None

        (net_params, opt_state), _ = jax.lax.scan(
            one_step, (net_params, opt_state), None, length=self.settings.train_steps
        )
        return net_params, opt_state

    def fresh_value(self, key: jax.Array, policy: NeuralPolicy, params: SearchParams):
        """Step 8: the mean return ``[]`` of ``policy`` over ``best_rollouts`` (or, when 0,
        ``eval_rollouts``) fresh rollouts."""
        s = self.settings
        n = s.best_rollouts or s.eval_rollouts
        return rollouts(self.env, self.controller, key, n, params.env, policy).mean()

    # -- one iteration -------------------------------------------------------------------------
    @property
    def rollouts_per_iteration(self) -> int:
        """Simulated rollouts in one ``step`` (``rollouts_per_iteration``)."""
        return rollouts_per_iteration(self.settings)

    # -- one iteration: ask / evaluate / tell (algorithms.engine's protocol) ------------------
    def ask(self, key: jax.Array, state: CognetState, params: SearchParams):
        """Steps 1-3: the current policy's recorded rollouts (the algorithm's simulator), the
        ``top`` of them and their candidates. Returns ``(asked, candidates)``: ``candidates``
        is the current policy with ``action_probs [top, agents, nodes, actions]`` (one per
        pre-selected rollout; the networks are shared), ``None`` in separate training."""
        s = self.settings
        traj = rollouts(
            self.env,
            self.controller,
            streams(key).sample,
            s.rollouts,
            params.env,
            state.policy,
            record=True,
        )
        if s.separate:
            return CognetAsked(traj=traj), None
        _, top_idx = jax.lax.top_k(traj.ret, s.top)
        counts = rollout_action_counts(
            traj.nodes[top_idx], traj.actions[top_idx], s.nodes, self.env.num_actions
        )  # [top, agents, nodes, actions]
        candidates = state.policy.replace(
            action_probs=candidate_action_probs(state.policy.action_probs, counts)
        )
        return CognetAsked(traj=traj, top_idx=top_idx, counts=counts), candidates

    def evaluate(self, key: jax.Array, candidates: NeuralPolicy | None, params: SearchParams):
        """Step 4: mean returns ``[top]`` of the candidates over ``eval_rollouts`` rollouts
        (common random numbers by default; the ``evaluate`` stream); ``None`` in separate
        training."""
        if candidates is None:
            return None
        return super().evaluate(key, candidates, params)

    def tell(
        self,
        key: jax.Array,
        state: CognetState,
        asked: CognetAsked,
        values: jax.Array | None,
        params: SearchParams,
        *,
        fresh_value=None,
    ):
        """Steps 5-8 with the candidates' ``values [top]``; returns ``(state, CognetMetrics)``.
        Step 8 values the updated policy on the ``fresh`` stream (``fresh_value``; yours with
        ``fresh_value(key, policy)``); augmentation draws from the ``other`` stream."""
        hyper = params.hyper
        s = self.settings
        k = streams(key)
        policy, progress, traj = state.policy, state.progress, asked.traj
        if s.separate:
            _, kept_idx = jax.lax.top_k(traj.ret, s.keep)
            kept_mask = jnp.ones(s.keep, bool)
            threshold = progress.threshold
            best_candidate = traj.ret[kept_idx[0]]
            action_probs = policy.action_probs
            injected = jnp.bool_(False)
        else:
            best_candidate = values.max()
            # 5: threshold
            bar = progress.in_loop_best if s.threshold_rule == "best" else progress.threshold
            sel, kept_mask, new_bar = elite_selection(values, bar, s.keep)
            threshold = progress.threshold if s.threshold_rule == "best" else new_bar
            kept_idx = asked.top_idx[sel]
            # 6: count MLE over the kept original rollouts, smoothing, entropy injection
            kept_counts = (asked.counts[sel] * kept_mask[:, None, None, None]).sum(0)
            action_probs = smooth(policy.action_probs, kept_counts, hyper.alpha)
            injected = progress.should_inject(hyper.entropy)
            action_probs = jnp.where(
                injected,
                inject_entropy(action_probs, hyper.entropy.rate, action_support(self.env)),
                action_probs,
            )

        progress = progress.replace(threshold=threshold).after_injection(injected)

        # 7: train the node networks on the kept rollouts' transitions
        if s.train_on == "top" and not s.separate:
            pairs = training_pairs(
                traj, asked.top_idx, jnp.ones(s.top, bool), s.train_last_transition
            )
        else:
            pairs = training_pairs(traj, kept_idx, kept_mask, s.train_last_transition)
        pairs = self.pipeline.training_pairs(k.other, *pairs)
        net_params, opt_state = self.train_networks(
            policy.net_params, state.opt_state, pairs, hyper
        )
        policy = NeuralPolicy(action_probs=action_probs, net_params=net_params)

        # 8: evaluate, record, keep the best
        if fresh_value is None:
            value = self.fresh_value(k.fresh, policy, params)
        else:
            value = fresh_value(k.fresh, policy)
        progress, improved = progress.record(value)
        best_policy = select_tree(improved, policy, state.best_policy)
        metrics = CognetMetrics(
            value=value,
            in_loop_best=progress.in_loop_best,
            threshold=progress.threshold,
            kept=kept_mask.sum(),
            best_candidate=best_candidate,
            rollout_mean=traj.ret.mean(),
            injected=injected,
        )
        new_state = CognetState(
            policy=policy, opt_state=opt_state, best_policy=best_policy, progress=progress
        )
        return new_state, metrics


# ---------------------------------------------------------------------------------------------
# the registry entry: config -> algorithm, hyper-parameters
# ---------------------------------------------------------------------------------------------
def build(config, env, env_params, memory: int | None = None) -> CognetThesis:
    """The search of ``config`` (``experiment.algorithm = "cognet-dice-thesis"``)."""
    settings = fields_from(CognetSettings, config.algorithm, config.network)
    return CognetThesis(env, settings, memory, build_pipeline(config, env, env_params))


def hyper(config) -> CognetHyper:
    """The dynamic hyper-parameters: ``alpha``, ``network.learning_rate``, entropy."""
    a = config.algorithm
    return fields_from(CognetHyper, a, config.network, entropy=entropy_config(a))


register_algorithm(
    "cognet-dice-thesis",
    CognetThesisSection,
    build,
    hyper,
    dynamic=(*ENTROPY_FIELDS, "algorithm.alpha", "network.learning_rate"),
    reads=("network",),
    overwrite=False,
)
