"""COGNet-DICE in PyTorch, written like the thesis code: Python loops everywhere.

* one ``nn.Module`` (Linear(obs, hidden) - ReLU - Linear(hidden, nodes)) per (agent, node), each
  with its own ``torch.optim`` optimiser (Adam by default, SGD with momentum as an option);
* a Python loop per rollout and per time step; batch-1 forward calls; actions and next nodes
  drawn with ``torch.multinomial`` one call at a time; the simulator works on Python floats
  (``tagging.step_scalar``) with noise uniforms from ``random.Random``;
* candidates evaluated in a loop over candidates and, inside, over rollouts.

The algorithm is that of ``cognet_jax.algorithms.cognet_thesis.CognetThesis.step`` (see the package
docstring of ``benchmarks.torch_reference``).
"""

from __future__ import annotations

import copy
import dataclasses
import random

import torch
import torch.nn.functional as F
from torch import nn

from benchmarks.torch_reference.common import Progress, as_hyper, as_settings
from benchmarks.torch_reference.tagging import (
    TaggingConfig,
    make_tagging,
    reset_scalar,
    step_scalar,
)


class NodeNet(nn.Module):
    """The transition network of one (agent, node): observation -> logits over next nodes."""

    def __init__(self, in_features: int, hidden: int, nodes: int):
        super().__init__()
        self.fc1 = nn.Linear(in_features, hidden)
        self.fc2 = nn.Linear(hidden, nodes)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.fc2(torch.relu(self.fc1(x)))


@dataclasses.dataclass
class Episode:
    """One recorded rollout: per time step and agent, q_t, a_t, z_{t+1}, q_{t+1}."""

    nodes: list[list[int]]
    actions: list[list[int]]
    obs: list[list[float]]
    next_nodes: list[list[int]]
    ret: float


class TorchCognetLoop:
    """COGNet-DICE with per-(agent, node) modules and per-rollout Python loops."""

    def __init__(self, settings=None, hyper=None, env: TaggingConfig | None = None, seed: int = 0):
        self.settings = as_settings(settings)
        self.hyper = as_hyper(hyper)
        self.env = env if env is not None else make_tagging("thesis")
        self.rng = random.Random(seed)
        torch.manual_seed(seed)
        s, n, a = self.settings, self.env.num_agents, self.env.num_actions
        self.nets = [[NodeNet(1, s.hidden, s.nodes) for _ in range(s.nodes)] for _ in range(n)]
        self.optimizers = [[self._make_optimizer(net) for net in row] for row in self.nets]
        if s.separate:
            probs = torch.zeros(n, s.nodes, a)
            for q in range(s.nodes):
                probs[:, q, q % a] = 1.0
        else:
            probs = torch.full((n, s.nodes, a), 1.0 / a)
        self.action_probs = probs
        self.progress = Progress(s.entropy_window)
        self.best_policy = self._snapshot()

    def _make_optimizer(self, net: nn.Module) -> torch.optim.Optimizer:
        lr = self.hyper.learning_rate
        if self.settings.optimizer == "adam":
            return torch.optim.Adam(net.parameters(), lr=lr)
        if self.settings.optimizer == "sgd":
            return torch.optim.SGD(net.parameters(), lr=lr, momentum=self.settings.momentum)
        raise ValueError(f"unknown optimizer {self.settings.optimizer!r}")

    def _snapshot(self):
        return self.action_probs.clone(), copy.deepcopy(self.nets)

    # -- rollouts --------------------------------------------------------------------------------
    def _new_streams(self, seed: int | None = None):
        """A torch generator (policy draws) and a Python generator (simulator noise)."""
        seed = self.rng.getrandbits(62) if seed is None else seed
        return torch.Generator().manual_seed(seed), random.Random(seed)

    def _next_node(self, agent: int, node: int, z: float, gen: torch.Generator) -> int:
        logits = self.nets[agent][node](torch.tensor([[z]]))
        probs = torch.softmax(logits, dim=-1)
        return int(torch.multinomial(probs[0], 1, generator=gen))

    def _rollout(self, action_probs: torch.Tensor, gen, rng: random.Random) -> Episode:
        env = self.env
        n = env.num_agents
        taggers, evader = reset_scalar([rng.random() for _ in range(env.reset_noise)], env)
        nodes = [0] * n
        no_noise = [0.5] * env.step_noise
        ep = Episode([], [], [], [], 0.0)
        discount = 1.0
        for _t in range(env.horizon):
            actions = [
                int(torch.multinomial(action_probs[i, nodes[i]], 1, generator=gen))
                for i in range(n)
            ]
            # noise-free: nothing to draw (step_scalar reads no noise column then)
            u = [rng.random() for _ in range(env.step_noise_used)] or no_noise
            taggers, evader, obs, reward = step_scalar(u, taggers, evader, actions, env)
            next_nodes = [self._next_node(i, nodes[i], obs[i], gen) for i in range(n)]
            ep.nodes.append(nodes)
            ep.actions.append(actions)
            ep.obs.append(obs)
            ep.next_nodes.append(next_nodes)
            ep.ret += discount * reward
            discount *= env.discount
            nodes = next_nodes
        return ep

    @torch.no_grad()
    def _episodes(self, action_probs: torch.Tensor, num: int, seed: int | None = None):
        gen, rng = self._new_streams(seed)
        return [self._rollout(action_probs, gen, rng) for _ in range(num)]

    def _mean_return(self, action_probs: torch.Tensor, num: int, seed: int | None = None):
        episodes = self._episodes(action_probs, num, seed)
        return sum(ep.ret for ep in episodes) / num

    def rollout_returns(self, num: int) -> torch.Tensor:
        """Returns ``[num]`` of ``num`` rollouts of the current policy."""
        return torch.tensor([ep.ret for ep in self._episodes(self.action_probs, num)])

    # -- pieces of one iteration -----------------------------------------------------------------
    def _action_counts(self, ep: Episode) -> torch.Tensor:
        s, n = self.settings, self.env.num_agents
        counts = torch.zeros(n, s.nodes, self.env.num_actions)
        for nodes, actions in zip(ep.nodes, ep.actions):
            for i in range(n):
                counts[i, nodes[i], actions[i]] += 1.0
        return counts

    def _train_networks(self, kept: list[Episode], learning_rate: float) -> None:
        s, n = self.settings, self.env.num_agents
        steps = self.env.horizon if s.train_last_transition else self.env.horizon - 1
        data = [[([], []) for _ in range(s.nodes)] for _ in range(n)]
        for ep in kept:
            for t in range(steps):
                for i in range(n):
                    obs, targets = data[i][ep.nodes[t][i]]
                    obs.append([ep.obs[t][i]])
                    targets.append(ep.next_nodes[t][i])
        for i in range(n):
            for q in range(s.nodes):
                obs, targets = data[i][q]
                if not obs:
                    continue
                x, y = torch.tensor(obs), torch.tensor(targets)
                net, opt = self.nets[i][q], self.optimizers[i][q]
                for group in opt.param_groups:
                    group["lr"] = learning_rate
                for _ in range(s.train_steps):
                    opt.zero_grad()
                    loss = F.cross_entropy(net(x), y)
                    loss.backward()
                    opt.step()

    # -- one iteration ---------------------------------------------------------------------------
    def step(self, hyper=None) -> dict:
        """One COGNet-DICE iteration; returns the metrics of cognet_jax's ``CognetMetrics``."""
        hyper = self.hyper if hyper is None else as_hyper(hyper)
        s, progress = self.settings, self.progress
        a = self.env.num_actions
        probs = self.action_probs

        # 1-2: rollouts of the current policy, pre-selection by return
        episodes = self._episodes(probs, s.rollouts)
        ranked = sorted(episodes, key=lambda ep: ep.ret, reverse=True)
        injected = False
        if s.separate:
            kept = ranked[: s.keep]
            best_candidate = kept[0].ret
        else:
            top = ranked[: s.top]
            counts = [self._action_counts(ep) for ep in top]
            # 3-4: clone candidates, evaluate each with eval_rollouts rollouts
            seed = self.rng.getrandbits(62) if s.common_random_numbers else None
            values = []
            for c in counts:
                cand = probs.clone()
                total = c.sum(-1)
                for i in range(cand.shape[0]):
                    for q in range(s.nodes):
                        if total[i, q] > 0:
                            cand[i, q] = c[i, q] / total[i, q]
                values.append(self._mean_return(cand, s.eval_rollouts, seed))
            best_candidate = max(values)
            # 5: threshold, keep the best `keep`
            bar = progress.best_value if s.threshold_rule == "best" else progress.threshold
            order = sorted(range(len(values)), key=lambda k: values[k], reverse=True)
            chosen = [k for k in order if values[k] > bar][: s.keep]
            if chosen and s.threshold_rule != "best":
                progress.threshold = values[chosen[-1]]
            kept = [top[k] for k in chosen]
            # 6: count MLE over the kept rollouts, smoothing, entropy injection
            probs = probs.clone()
            if chosen:
                kept_counts = sum(counts[k] for k in chosen)
                total = kept_counts.sum(-1)
                for i in range(probs.shape[0]):
                    for q in range(s.nodes):
                        if total[i, q] > 0:
                            mle = kept_counts[i, q] / total[i, q]
                            probs[i, q] = hyper.alpha * mle + (1.0 - hyper.alpha) * probs[i, q]
            injected = progress.should_inject(hyper.entropy)
            if injected:
                rate = hyper.entropy.rate
                probs = (1.0 - rate) * probs + rate / a
        progress.after_injection(injected)

        # 7: train the node networks on the kept rollouts' transitions
        self._train_networks(kept, hyper.learning_rate)
        self.action_probs = probs

        # 8: evaluate the updated policy, record, keep the best
        value = self._mean_return(probs, s.eval_rollouts)
        if progress.record(value):
            self.best_policy = self._snapshot()
        return dict(
            value=value,
            best_value=progress.best_value,
            threshold=progress.threshold,
            kept=len(kept),
            best_candidate=best_candidate,
            rollout_mean=sum(ep.ret for ep in episodes) / len(episodes),
            injected=injected,
        )
