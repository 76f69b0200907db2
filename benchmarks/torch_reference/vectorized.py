"""COGNet-DICE in PyTorch, vectorised the way a PyTorch user would: tensors over rollouts.

* All rollouts of one call advance together, one Python iteration per time step, state tensors
  ``[B, agents]`` (``tagging.step_batched``).
* The (agent, node) networks are *stacked* parameters ``w1 [agents, nodes, obs, hidden]``, ``b1``,
  ``w2 [agents, nodes, hidden, nodes]``, ``b2`` (``StackedNodeNets``, an ``nn.Module``). In a
  rollout every member of agent i is applied to agent i's observation with ``einsum`` (batched
  matmuls over the stack) and each row's current-node logits are gathered -- the fastest of the
  variants measured on the 2-core CPU (gathering each row's weights + ``torch.bmm``: ~1.5x slower
  at 1e3 rows; a loop over (agent, node) with boolean masks: ~2x slower at 1e3 rows, similar at
  1e4). In training every member is applied to its agent's pairs the same way and the per-member
  losses are summed, so one backward pass gives every member its own gradient.
* Actions and next nodes are drawn by the inverse CDF from one block of uniforms per time step
  (``torch.rand(B, 2 agents + step_noise_used)``, laid out as in cognet_jax: action draws,
  transition draws, simulator noise; in the noise-free thesis setting no simulator columns are
  drawn, as XLA drops them on the JAX side), which also makes common random numbers simple: the
  block is drawn for ``eval_rollouts`` rows and repeated for every candidate.
* All ``top`` candidates are evaluated in one batched call (``top * eval_rollouts`` rows).
* Optimiser: Adam (or SGD with momentum) written out over the stacked tensors with one step count
  per member, so that members without training pairs keep their weights *and* optimiser state,
  exactly as cognet_jax's masked optax update (``torch.optim.Adam`` on a stacked tensor would
  still move them through their momentum and share one step count).
"""

from __future__ import annotations

import copy
import math

import torch
import torch.nn.functional as F
from torch import nn

from benchmarks.torch_reference.common import Progress, as_hyper, as_settings
from benchmarks.torch_reference.kernels import compile_step, sample_categorical
from benchmarks.torch_reference.tagging import (
    TaggingConfig,
    make_tagging,
    reset_batched,
    step_batched,
)


def elite_selection(values: torch.Tensor, threshold: float, num_elites: int):
    """G-DICE elite threshold: indices (decreasing value) of at most ``num_elites`` candidates
    strictly above ``threshold``, and the new threshold (smallest kept value, or unchanged)."""
    eligible = torch.where(values > threshold, values, -math.inf)
    top, idx = torch.topk(eligible, min(num_elites, values.numel()))
    kept = top > -math.inf
    if not bool(kept.any()):
        return idx[:0], threshold
    return idx[kept], float(top[kept].min())


class StackedNodeNets(nn.Module):
    """Every (agent, node) network as one stack; member (i, q) never shares weights."""

    def __init__(self, agents: int, nodes: int, in_features: int, hidden: int):
        super().__init__()

        def uniform(*shape, fan_in):  # nn.Linear's default init: U(+-1/sqrt(fan_in))
            bound = 1.0 / math.sqrt(fan_in)
            return nn.Parameter(torch.empty(*shape).uniform_(-bound, bound))

        self.w1 = uniform(agents, nodes, in_features, hidden, fan_in=in_features)
        self.b1 = uniform(agents, nodes, hidden, fan_in=in_features)
        self.w2 = uniform(agents, nodes, hidden, nodes, fan_in=hidden)
        self.b2 = uniform(agents, nodes, nodes, fan_in=hidden)

    def forward(self, obs: torch.Tensor, nodes: torch.Tensor) -> torch.Tensor:
        """Logits ``[B, agents, nodes]`` of each agent's current member: ``obs [B, agents, in]``,
        ``nodes [B, agents]``.

        Every member of agent i is applied to agent i's observation (two ``einsum`` calls, i.e.
        batched matmuls over the stack) and the current node's logits are gathered; measured
        faster here than gathering each row's weights and ``torch.bmm`` or a loop over
        (agent, node) with boolean masks, because the members are tiny."""
        h = torch.relu(torch.einsum("bai,aqih->baqh", obs, self.w1) + self.b1)
        logits = torch.einsum("baqh,aqhk->baqk", h, self.w2) + self.b2  # [B, agents, nodes, K]
        index = nodes[:, :, None, None].expand(-1, -1, 1, logits.shape[-1])
        return logits.gather(2, index).squeeze(2)

    def members(self, obs: torch.Tensor) -> torch.Tensor:
        """Logits ``[agents, nodes, P, nodes]`` of every member on its agent's ``obs [agents, P,
        in]``."""
        h = torch.relu(torch.einsum("api,aqih->aqph", obs, self.w1) + self.b1[:, :, None])
        return torch.einsum("aqph,aqhk->aqpk", h, self.w2) + self.b2[:, :, None]


class MemberOptimizer:
    """Adam / SGD-momentum over stacked parameters ``[agents, nodes, ...]``, one step count per
    member; ``step(lr, mask)`` only updates members where ``mask [agents, nodes]``."""

    def __init__(self, params, kind: str = "adam", momentum: float = 0.5):
        if kind not in ("adam", "sgd"):
            raise ValueError(f"unknown optimizer {kind!r}")
        self.params = list(params)
        self.kind, self.momentum = kind, momentum
        self.b1, self.b2, self.eps = 0.9, 0.999, 1e-8
        self.m = [torch.zeros_like(p) for p in self.params]
        self.v = [torch.zeros_like(p) for p in self.params]
        self.count = torch.zeros(self.params[0].shape[:2])

    @torch.no_grad()
    def step(self, lr: float, mask: torch.Tensor) -> None:
        count = self.count + 1.0
        for p, m, v in zip(self.params, self.m, self.v):
            shape = mask.shape + (1,) * (p.dim() - 2)
            keep = mask.reshape(shape)
            g = p.grad
            if self.kind == "adam":
                m_new = self.b1 * m + (1.0 - self.b1) * g
                v_new = self.b2 * v + (1.0 - self.b2) * g * g
                c = count.reshape(shape)
                m_hat = m_new / (1.0 - self.b1**c)
                v_hat = v_new / (1.0 - self.b2**c)
                update = m_hat / (v_hat.sqrt() + self.eps)
                v.copy_(torch.where(keep, v_new, v))
            else:
                m_new = g + self.momentum * m
                update = m_new
            m.copy_(torch.where(keep, m_new, m))
            p.copy_(torch.where(keep, p - lr * update, p))
        self.count = torch.where(mask, count, self.count)

    def zero_grad(self) -> None:
        for p in self.params:
            p.grad = None


class TorchCognetVectorized:
    """COGNet-DICE with batched rollouts, stacked networks and batched candidate evaluation."""

    def __init__(self, settings=None, hyper=None, env: TaggingConfig | None = None, seed: int = 0):
        self.settings = as_settings(settings)
        self.hyper = as_hyper(hyper)
        self.env = env if env is not None else make_tagging("thesis")
        torch.manual_seed(seed)
        self.gen = torch.Generator().manual_seed(seed)
        s, n, a = self.settings, self.env.num_agents, self.env.num_actions
        self.nets = StackedNodeNets(n, s.nodes, 1, s.hidden)
        self.optimizer = MemberOptimizer(self.nets.parameters(), s.optimizer, s.momentum)
        if s.separate:
            probs = F.one_hot(torch.arange(s.nodes) % a, a).float().expand(n, -1, -1).clone()
        else:
            probs = torch.full((n, s.nodes, a), 1.0 / a)
        self.action_probs = probs
        self.progress = Progress(s.entropy_window)
        self.best_policy = self._snapshot()

    def _snapshot(self):
        return self.action_probs.clone(), copy.deepcopy(self.nets.state_dict())

    # -- rollouts --------------------------------------------------------------------------------
    @torch.no_grad()
    def rollouts(self, action_probs: torch.Tensor, num: int, record: bool = False, crn=False):
        """``num`` rollouts of each of P policies that share the networks and differ in their
        action tables ``action_probs [P, agents, nodes, actions]``.

        ``crn``: the same uniforms for every policy (common random numbers). Returns the returns
        ``[P, num]``, or with ``record`` a dict of ``nodes / actions / obs / next_nodes [P * num,
        H, agents]``, ``rewards [P * num, H]`` and ``ret [P * num]``.
        """
        env = self.env
        n = env.num_agents
        p = action_probs.shape[0]
        rows = p * num

        def draw(k):
            if crn and p > 1:
                return torch.rand(num, k, generator=self.gen).repeat(p, 1)
            return torch.rand(rows, k, generator=self.gen)

        taggers, evader = reset_batched(draw(env.reset_noise), env)
        policy = torch.arange(p).repeat_interleave(num)[:, None]
        nodes = torch.zeros(rows, n, dtype=torch.long)
        ret = torch.zeros(rows)
        discount = 1.0
        out = []
        for _t in range(env.horizon):
            u = draw(2 * n + env.step_noise_used)
            taggers, evader, obs, reward, actions, next_nodes = self._advance(
                u, taggers, evader, nodes, action_probs, policy
            )
            ret += discount * reward
            discount *= env.discount
            if record:
                out.append((nodes, actions, obs, next_nodes, reward))
            nodes = next_nodes
        if not record:
            return ret.reshape(p, num)
        names = ("nodes", "actions", "obs", "next_nodes", "rewards")
        traj = {k: torch.stack(v, 1) for k, v in zip(names, zip(*out))}
        traj["ret"] = ret
        return traj

    def _advance(self, u, taggers, evader, nodes, action_probs, policy):
        """One time step of every row: draw actions, step the simulator, draw next nodes.
        Returns ``(taggers, evader, obs, reward, actions, next_nodes)``."""
        env, n = self.env, self.env.num_agents
        agent = torch.arange(n)[None, :]
        if action_probs.shape[0] == 1:
            probs = action_probs[0][agent, nodes]
        else:
            probs = action_probs[policy, agent, nodes]
        actions = sample_categorical(u[:, :n], probs)
        taggers, evader, obs, reward = step_batched(u[:, 2 * n :], taggers, evader, actions, env)
        logits = self.nets(obs[..., None], nodes)
        # unnormalised softmax (the inverse CDF normalises): torch.softmax over a last axis
        # of 3-6 entries is several times slower on CPU
        weights = (logits - logits.amax(-1, keepdim=True)).exp()
        next_nodes = sample_categorical(u[:, n : 2 * n], weights)
        return taggers, evader, obs, reward, actions, next_nodes

    def rollout_returns(self, num: int) -> torch.Tensor:
        """Returns ``[num]`` of ``num`` rollouts of the current policy."""
        return self.rollouts(self.action_probs[None], num)[0]

    # -- pieces of one iteration -----------------------------------------------------------------
    def _train_networks(self, traj: dict, kept_idx: torch.Tensor, learning_rate: float) -> None:
        s = self.settings
        h = self.env.horizon if s.train_last_transition else self.env.horizon - 1
        n = self.env.num_agents
        # pairs per agent: [agents, P] with P = kept * h
        src = traj["nodes"][kept_idx, :h].reshape(-1, n).T
        tgt = traj["next_nodes"][kept_idx, :h].reshape(-1, n).T
        obs = traj["obs"][kept_idx, :h].reshape(-1, n).T[..., None]
        weights = F.one_hot(src, s.nodes).permute(0, 2, 1).float()  # [agents, nodes, P]
        count = weights.sum(-1)
        has_data = count > 0
        if not bool(has_data.any()):
            return
        targets = tgt[:, None, :].expand(-1, s.nodes, -1).reshape(-1)
        for _ in range(s.train_steps):
            self.optimizer.zero_grad()
            logits = self.nets.members(obs)  # [agents, nodes, P, nodes]
            ce = F.cross_entropy(logits.reshape(-1, s.nodes), targets, reduction="none")
            member_loss = (weights * ce.reshape(weights.shape)).sum(-1) / count.clamp_min(1.0)
            member_loss.sum().backward()
            self.optimizer.step(learning_rate, has_data)

    # -- one iteration ---------------------------------------------------------------------------
    def step(self, hyper=None) -> dict:
        """One COGNet-DICE iteration; returns the metrics of cognet_jax's ``CognetMetrics``."""
        hyper = self.hyper if hyper is None else as_hyper(hyper)
        s, progress = self.settings, self.progress
        a = self.env.num_actions
        probs = self.action_probs

        # 1-2: rollouts of the current policy, pre-selection by return
        traj = self.rollouts(probs[None], s.rollouts, record=True)
        injected = False
        if s.separate:
            best_ret, kept_idx = torch.topk(traj["ret"], s.keep)
            best_candidate = float(best_ret[0])
        else:
            top_idx = torch.topk(traj["ret"], s.top).indices
            node_oh = F.one_hot(traj["nodes"][top_idx], s.nodes).float()
            act_oh = F.one_hot(traj["actions"][top_idx], a).float()
            counts = torch.einsum("ktiq,ktia->kiqa", node_oh, act_oh)  # [top, agents, nodes, A]
            # 3-4: clone candidates, evaluate all of them in one batch
            total = counts.sum(-1, keepdim=True)
            cand = torch.where(total > 0, counts / total.clamp_min(1.0), probs[None])
            values = self.rollouts(cand, s.eval_rollouts, crn=s.common_random_numbers).mean(-1)
            best_candidate = float(values.max())
            # 5: threshold, keep the best `keep`
            bar = progress.best_value if s.threshold_rule == "best" else progress.threshold
            sel, new_bar = elite_selection(values, bar, s.keep)
            if s.threshold_rule != "best":
                progress.threshold = new_bar
            kept_idx = top_idx[sel]
            # 6: count MLE over the kept rollouts, smoothing, entropy injection
            kept_counts = counts[sel].sum(0)
            total = kept_counts.sum(-1, keepdim=True)
            mle = kept_counts / total.clamp_min(1e-30)
            probs = torch.where(total > 0, hyper.alpha * mle + (1.0 - hyper.alpha) * probs, probs)
            injected = progress.should_inject(hyper.entropy)
            if injected:
                rate = hyper.entropy.rate
                probs = (1.0 - rate) * probs + rate / a
        progress.after_injection(injected)

        # 7: train the node networks on the kept rollouts' transitions
        self._train_networks(traj, kept_idx, hyper.learning_rate)
        self.action_probs = probs

        # 8: evaluate the updated policy, record, keep the best
        value = float(self.rollouts(probs[None], s.eval_rollouts).mean())
        if progress.record(value):
            self.best_policy = self._snapshot()
        return dict(
            value=value,
            best_value=progress.best_value,
            threshold=progress.threshold,
            kept=int(kept_idx.numel()),
            best_candidate=best_candidate,
            rollout_mean=float(traj["ret"].mean()),
            injected=injected,
        )


class TorchCognetCompiled(TorchCognetVectorized):
    """The vectorised reference with each rollout time step compiled by ``torch.compile``
    (inductor, CPU, static shapes: one compilation per batch size, done in the warm-up call).
    The step is the same function as the eager version's, so the two draw the same numbers;
    random draws stay outside the compiled step (``torch.rand`` with an explicit generator)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._advance = compile_step(self._advance)
