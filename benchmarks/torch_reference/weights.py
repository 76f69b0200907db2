"""The default ``cognet-dice`` (cross-entropy over the node networks' weights,
``cognet_jax.algorithms.cognet_weights``) in PyTorch, vectorised and optionally compiled, on the
tagging simulator of ``tagging.py``.

The same search, step by step (``TorchWeightsSearch.step``):

1. draw ``candidates`` joint controllers from the distribution: one action per (agent, node),
   hidden-layer Gaussians ``w1 [agents, Q, F, H]`` and ``b1 [agents, Q, H]``, per hidden unit
   a voted next node (categorical) with a Gaussian strength, a default node with a Gaussian
   bias; with ``tie_structure`` per agent whether every node runs node 0's network and
   whether every agent runs agent 0's controller (``weight_space.tie``);
2. evaluate every candidate with ``eval_rollouts`` rollouts, all candidates in one batch on the
   same uniforms (common random numbers);
3. the best ``elites`` refit the distribution with smoothing ``alpha`` (Gaussians by the elites'
   mean and standard deviation, categoricals by count MLE), then the uniform floors;
4. the winner, the distribution's mode and (``best_pool``) the pool's members on ``best_rollouts``
   fresh rollouts, the same for all of them with a pool; the race of ``best_pool.race`` keeps
   the member with the largest lower confidence bound;
5. with ``restart_tol``, a distribution whose hidden-layer spread shrank below that fraction of
   its initial one starts afresh.

Not implemented: the refine phase (``algorithm.refine``) and ``algorithm.starts``. They only
replace the distribution at a few iterations (centred on the kept policy, or the initial one),
so a run does the same work with or without them; its values differ.

Written the way a PyTorch engineer vectorises it: rows ``[P policies, K rollouts]``, one Python
iteration per time step, every member network of a policy applied with two ``einsum`` calls
(batched matmuls over the policy axis) and the current node's logits gathered (the variant
``vectorized.StackedNodeNets`` measured fastest), deterministic actions looked up (no draw),
next nodes by the inverse CDF of one uniform per agent. ``TorchWeightsCompiled`` compiles the
time step with ``torch.compile`` (inductor).

Settings come from a cognet_jax config (``settings_from_config``), so both sides run the same
sizes; the random numbers are torch's (``torch.Generator``), not JAX's.
"""

from __future__ import annotations

import dataclasses
import math

import torch
import torch.nn.functional as F

from benchmarks.torch_reference.kernels import compile_step, sample_categorical
from benchmarks.torch_reference.tagging import (
    TaggingConfig,
    make_tagging,
    reset_batched,
    step_batched,
)

#: the race's lower confidence bound, in standard errors (``best_pool.CONFIDENCE``)
CONFIDENCE = 2.0
#: fields of a node's network, copied by node tying (``weight_space.NETWORK_FIELDS``)
NETWORK_FIELDS = ("w1", "b1", "targets", "m", "default", "bias")


@dataclasses.dataclass(frozen=True)
class WeightsSettings:
    """The sizes and settings of one ``cognet-dice`` search (``CognetWeightsSection`` with its
    sizes resolved, and ``network.hidden``)."""

    nodes: int = 3
    candidates: int = 200
    eval_rollouts: int = 500
    elites: int = 10
    best_rollouts: int = 1000
    alpha: float = 0.3
    action_floor: float = 0.02
    category_floor: float = 0.02
    init_scale: float = 10.0
    vote_mean: float = 5.0
    vote_std: float = 5.0
    default_vote_scale: float = 1.0
    hidden: int = 10
    best_pool: int = 4
    tie_structure: bool = True
    restart_tol: float = 0.02
    common_random_numbers: bool = True


def settings_from_config(config) -> WeightsSettings:
    """``WeightsSettings`` of a loaded cognet_jax config (``registry.load_config``: sizes
    resolved) of ``experiment.algorithm = "cognet-dice"``."""
    values = {
        f.name: getattr(config.algorithm, f.name, None) for f in dataclasses.fields(WeightsSettings)
    }
    values["hidden"] = config.network.hidden
    values = {k: v for k, v in values.items() if v is not None}
    if getattr(config.algorithm, "paired_best", False):
        raise ValueError("the torch reference implements the pool, not paired_best")
    return WeightsSettings(**values)


def env_from_config(config) -> TaggingConfig:
    """The torch tagging simulator of a cognet_jax config's ``[env]`` (tagging only)."""
    e = config.env
    if e.name != "tagging":
        raise ValueError(f"the torch reference simulates tagging only, not {e.name!r}")
    extra = {k: getattr(e, k) for k in ("motion_noise", "obs_noise") if getattr(e, k)}
    if e.discount is not None:
        extra["discount"] = e.discount
    if e.respawn is not None:
        extra["respawn"] = e.respawn
    return make_tagging(e.setting, horizon=e.horizon, obs_division=e.obs_division, **extra)


def one_hot_float(x: torch.Tensor, k: int) -> torch.Tensor:
    return F.one_hot(x, k).to(torch.float32)


class TorchWeightsSearch:
    """``cognet-dice`` on tagging with batched rollouts (eager torch)."""

    def __init__(self, settings: WeightsSettings, env: TaggingConfig | None = None, seed: int = 0):
        self.s = settings
        self.env = env if env is not None else make_tagging("thesis")
        self.gen = torch.Generator().manual_seed(seed)
        self.features = 1  # the tagging observation: one signed distance per agent
        self.agents_can_tie = self.s.tie_structure and self.env.num_agents > 1
        self.dist = self.initial_distribution()
        first = self.draw(self.dist, 1)
        self.pool = None
        if self.s.best_pool:
            size = self.s.best_pool
            self.pool = dict(
                policy={k: v.expand(size, *v.shape[1:]).clone() for k, v in first.items()},
                mean=torch.full((size,), -math.inf),
                m2=torch.zeros(size),
                count=torch.zeros(size, dtype=torch.long),
            )
        self.best = first
        self.best_value = -math.inf
        self.iteration = 0

    # ---------------------------------------------------------------- distribution
    def initial_distribution(self) -> dict:
        s, n, na, f = self.s, self.env.num_agents, self.env.num_actions, self.features
        q, h = s.nodes, s.hidden
        tie_p = 0.5 if s.tie_structure else 0.0
        return dict(
            actions=torch.full((n, q, na), 1.0 / na),
            w1_mean=torch.zeros(n, q, f, h),
            w1_std=torch.full((n, q, f, h), s.init_scale / math.sqrt(f)),
            b1_mean=torch.zeros(n, q, h),
            b1_std=torch.full((n, q, h), s.init_scale),
            targets=torch.full((n, q, h, q), 1.0 / q),
            m_mean=torch.full((n, q, h), s.vote_mean),
            m_std=torch.full((n, q, h), s.vote_std),
            default=torch.full((n, q, q), 1.0 / q),
            bias_mean=torch.full((n, q), s.vote_mean * s.default_vote_scale),
            bias_std=torch.full((n, q), s.vote_std * s.default_vote_scale),
            node_tie=torch.tensor([[1.0 - tie_p, tie_p]]).expand(n, 2).clone(),
            agent_tie=torch.tensor([0.5, 0.5] if self.agents_can_tie else [1.0, 0.0]),
        )

    def _categorical(self, probs: torch.Tensor, num: int) -> torch.Tensor:
        u = torch.rand((num,) + probs.shape[:-1], generator=self.gen)
        return sample_categorical(u, probs.expand((num,) + probs.shape))

    def _normal(self, mean: torch.Tensor, std: torch.Tensor, num: int) -> torch.Tensor:
        return mean + std * torch.randn((num,) + mean.shape, generator=self.gen)

    def draw(self, dist: dict, num: int) -> dict:
        """``num`` candidates: tensors with a leading ``[num]`` axis."""
        sample = dict(
            actions=self._categorical(dist["actions"], num),
            w1=self._normal(dist["w1_mean"], dist["w1_std"], num),
            b1=self._normal(dist["b1_mean"], dist["b1_std"], num),
            targets=self._categorical(dist["targets"], num),
            m=self._normal(dist["m_mean"], dist["m_std"], num),
            default=self._categorical(dist["default"], num),
            bias=self._normal(dist["bias_mean"], dist["bias_std"], num),
        )
        if not self.s.tie_structure:
            return sample
        sample["node_tie"] = self._categorical(dist["node_tie"], num)
        sample["agent_tie"] = self._categorical(dist["agent_tie"], num)
        return tie(sample)

    def mode(self, dist: dict) -> dict:
        """The most likely controller, with a leading axis of 1."""
        sample = dict(
            actions=dist["actions"].argmax(-1),
            w1=dist["w1_mean"],
            b1=dist["b1_mean"],
            targets=dist["targets"].argmax(-1),
            m=dist["m_mean"],
            default=dist["default"].argmax(-1),
            bias=dist["bias_mean"],
        )
        if self.s.tie_structure:
            sample["node_tie"] = dist["node_tie"].argmax(-1)
            sample["agent_tie"] = dist["agent_tie"].argmax(-1)
        sample = {k: v[None] for k, v in sample.items()}
        return tie(sample) if self.s.tie_structure else sample

    def refit(self, dist: dict, elites: dict) -> dict:
        """Smoothed refit to ``elites`` (leading ``[E]`` axis), then the uniform floors."""
        s, q, na = self.s, self.s.nodes, self.env.num_actions
        alpha = s.alpha

        def gaussian(name, draws):
            mean = alpha * draws.mean(0) + (1 - alpha) * dist[name + "_mean"]
            # the population standard deviation, as jnp.std
            std = alpha * draws.std(0, unbiased=False) + (1 - alpha) * dist[name + "_std"]
            return {name + "_mean": mean, name + "_std": std}

        def categorical(name, draws, k, floor):
            counts = one_hot_float(draws, k).sum(0)
            total = counts.sum(-1, keepdim=True)
            mle = counts / total.clamp_min(1e-30)
            old = dist[name]
            new = torch.where(total > 0, alpha * mle + (1 - alpha) * old, old)
            return {name: (1 - floor) * new + floor / k}

        out = {}
        for name in ("w1", "b1", "m", "bias"):
            out |= gaussian(name, elites[name])
        out |= categorical("actions", elites["actions"], na, s.action_floor)
        out |= categorical("targets", elites["targets"], q, s.category_floor)
        out |= categorical("default", elites["default"], q, s.category_floor)
        if s.tie_structure:
            out |= categorical("node_tie", elites["node_tie"], 2, s.category_floor)
            floor = s.category_floor if self.agents_can_tie else 0.0
            out |= categorical("agent_tie", elites["agent_tie"], 2, floor)
        else:
            out |= {k: dist[k] for k in ("node_tie", "agent_tie")}
        return out

    def converged(self, dist: dict) -> bool:
        initial = self.s.init_scale / math.sqrt(self.features)
        return (
            self.s.restart_tol > 0 and float(dist["w1_std"].mean()) < self.s.restart_tol * initial
        )

    # ---------------------------------------------------------------- rollouts
    def policy_tensors(self, sample: dict) -> tuple:
        """``(actions [P, agents, Q], w1 [P, agents, Q, F, H], b1 [P, agents, Q, H],
        w2 [P, agents, Q, H, Q], b2 [P, agents, Q, Q])``: the networks of ``sample``."""
        q = self.s.nodes
        w2 = sample["m"][..., None] * one_hot_float(sample["targets"], q)
        b2 = sample["bias"][..., None] * one_hot_float(sample["default"], q)
        return sample["actions"], sample["w1"], sample["b1"], w2, b2

    @torch.no_grad()
    def returns(self, sample: dict, num: int, crn: bool) -> torch.Tensor:
        """Returns ``[P, num]`` of each of the ``P`` policies of ``sample``; ``crn``: every
        policy on the same uniforms."""
        env, n = self.env, self.env.num_agents
        policy = self.policy_tensors(sample)
        p = policy[0].shape[0]

        def draw(cols):
            if crn and p > 1:
                return torch.rand(1, num, cols, generator=self.gen).expand(p, num, cols)
            return torch.rand(p, num, cols, generator=self.gen)

        taggers, evader = reset_batched(draw(env.reset_noise).reshape(p * num, -1), env)
        nodes = torch.zeros(p, num, n, dtype=torch.long)
        ret = torch.zeros(p * num)
        discount = 1.0
        for _ in range(env.horizon):
            u = draw(n + env.step_noise_used)
            taggers, evader, nodes, reward = self._advance(u, taggers, evader, nodes, *policy)
            ret += discount * reward
            discount *= env.discount
        return ret.reshape(p, num)

    def _advance(self, u, taggers, evader, nodes, actions, w1, b1, w2, b2):
        """One time step of rows ``[P, K]``: the nodes' actions, the simulator, the next nodes.
        ``u [P, K, agents + simulator columns]``; returns ``(taggers, evader, nodes, reward)``."""
        env, n = self.env, self.env.num_agents
        p, k = nodes.shape[:2]
        agent = torch.arange(n)
        act = actions[torch.arange(p)[:, None, None], agent, nodes]  # [P, K, agents]
        taggers, evader, obs, reward = step_batched(
            u[..., n:].reshape(p * k, -1), taggers, evader, act.reshape(p * k, n), env
        )
        x = obs.reshape(p, k, n, 1)
        hidden = torch.relu(torch.einsum("pkaf,paqfh->pkaqh", x, w1) + b1[:, None])
        logits = torch.einsum("pkaqh,paqhj->pkaqj", hidden, w2) + b2[:, None]
        index = nodes[..., None, None].expand(-1, -1, -1, 1, logits.shape[-1])
        current = logits.gather(3, index).squeeze(3)  # [P, K, agents, Q]
        weights = (current - current.amax(-1, keepdim=True)).exp()
        nodes = sample_categorical(u[..., :n], weights)
        return taggers, evader, nodes, reward

    # ---------------------------------------------------------------- one iteration
    def step(self) -> dict:
        """One iteration; returns ``value`` (the challenger's fresh value), ``best_value``,
        ``mean_value``, ``top_value`` and ``restarted``."""
        s = self.s
        samples = self.draw(self.dist, s.candidates)
        values = self.returns(samples, s.eval_rollouts, s.common_random_numbers).mean(-1)
        top, idx = torch.topk(values, s.elites)
        elites = {k: v[idx] for k, v in samples.items()}
        dist = self.refit(self.dist, elites)
        winner = {k: v[idx[:1]] for k, v in samples.items()}
        mode = self.mode(dist)
        if self.pool is not None:  # winner, mode and the members on the same fresh rollouts
            both = {
                k: torch.cat([winner[k], mode[k], self.pool["policy"][k]])
                for k in self.pool["policy"]
            }
            fresh = self.returns(both, s.best_rollouts, crn=True).mean(-1)
        else:
            both = {k: torch.cat([winner[k], mode[k]]) for k in winner}
            fresh = self.returns(both, s.best_rollouts, crn=False).mean(-1)
        mode_better = bool(fresh[1] > fresh[0])
        challenger = mode if mode_better else winner
        value = float(fresh[:2].max())
        if self.pool is not None:
            race(self.pool, fresh[2:], challenger, value)
            kept = pool_best(self.pool)
            self.best = {k: v[kept : kept + 1] for k, v in self.pool["policy"].items()}
            self.best_value = float(self.pool["mean"][kept])
        elif value > self.best_value:
            self.best, self.best_value = challenger, value
        restarted = self.converged(dist)
        self.dist = self.initial_distribution() if restarted else dist
        self.iteration += 1
        return dict(
            value=value,
            best_value=self.best_value,
            mean_value=float(values.mean()),
            top_value=float(top[0]),
            restarted=restarted,
        )

    def run(self, iterations: int) -> float:
        """``iterations`` iterations; returns the kept policy's estimate."""
        for _ in range(iterations):
            self.step()
        return self.best_value


def tie(sample: dict) -> dict:
    """``weight_space.tie`` on a dict sample with a leading candidate axis: node 0's network in
    every node where ``node_tie``, agent 0's controller for every agent where ``agent_tie``."""
    out = dict(sample)
    flag = sample["node_tie"] == 1  # [C, agents]
    for name in NETWORK_FIELDS:
        x = out[name]
        f = flag.reshape(flag.shape + (1,) * (x.dim() - 2))
        out[name] = torch.where(f, x[:, :, :1].expand_as(x), x)
    flag = sample["agent_tie"] == 1  # [C]
    for name in (*NETWORK_FIELDS, "actions", "node_tie"):
        x = out[name]
        f = flag.reshape(flag.shape + (1,) * (x.dim() - 1))
        out[name] = torch.where(f, x[:, :1].expand_as(x), x)
    return out


def pool_spread(pool: dict) -> float:
    usable = (pool["count"] >= 2) & torch.isfinite(pool["mean"])
    dof = float((pool["count"] - 1)[usable].sum())
    return math.sqrt(max(float(pool["m2"][usable].sum()), 0.0) / max(dof, 1.0))


def pool_means(pool: dict) -> torch.Tensor:
    return torch.where(pool["count"] > 0, pool["mean"], torch.tensor(-math.inf))


def pool_best(pool: dict) -> int:
    """The member with the largest lower confidence bound (``BestPool.best``)."""
    bound = pool_means(pool) - CONFIDENCE * pool_spread(pool) / pool["count"].clamp_min(1).sqrt()
    return int(torch.nan_to_num(bound, nan=-math.inf).argmax())


def race(pool: dict, member_values: torch.Tensor, challenger: dict, value: float) -> None:
    """``best_pool.race`` in place: the members' running means (Welford), then the challenger
    replaces the weakest member but the kept one when it beats it and is new."""
    seen = pool["count"] > 0
    count = pool["count"] + seen.long()
    old = torch.where(seen, pool["mean"], torch.zeros(()))
    delta = member_values - old
    mean = old + delta / count.clamp_min(1)
    m2 = pool["m2"] + delta * (member_values - mean)
    bad = seen & ~torch.isfinite(member_values)
    pool["mean"] = torch.where(bad, -math.inf, torch.where(seen, mean, pool["mean"]))
    pool["m2"] = torch.where(bad, 0.0, torch.where(seen, m2, pool["m2"]))
    pool["count"] = count
    evictable = pool_means(pool).clone()
    evictable[pool_best(pool)] = math.inf
    worst = int(evictable.argmin())
    duplicate = bool((seen & (member_values == value)).any())
    if math.isfinite(value) and value > float(evictable[worst]) and not duplicate:
        for k, v in pool["policy"].items():
            v[worst] = challenger[k][0]
        pool["mean"][worst], pool["m2"][worst], pool["count"][worst] = value, 0.0, 1


class TorchWeightsCompiled(TorchWeightsSearch):
    """``TorchWeightsSearch`` with the time step compiled by ``torch.compile`` (inductor,
    static shapes: one graph per row layout, made in the first iteration)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._advance = compile_step(self._advance)
