"""Single-thread numpy reference of the rollout benchmark: batched rollouts of a random neural
controller on tagging, written the way a numpy user would vectorise them.

Same work as ``jax_cases.rollout_throughput`` and the torch references' ``rollout_returns``
(SPEC sections 1 and 7.1): all rollouts advance together, one Python iteration per time step;
per step one block of float32 uniforms ``[B, 2 agents + noise columns used]`` (action draws,
transition draws, simulator noise; none in the noise-free thesis setting); actions and next
nodes by the inverse CDF; every (agent, node) network ``1 -> hidden (ReLU) -> nodes`` applied to
its agent's observation with ``np.einsum`` and each row's current-node logits taken; the
tagging step of ``cognet_jax.envs.tagging`` on arrays. numpy's elementwise kernels and
``np.einsum`` (without ``optimize``) run on one thread, so this is a one-core figure, to set
against the other engines' per-core figures. ``tests/test_numpy_reference.py`` checks it
against the JAX engine.
"""

from __future__ import annotations

import math

import numpy as np

TAG, LEFT, RIGHT = 0, 1, 2


def random_policy(nodes: int, hidden: int = 10, agents: int = 2, actions: int = 3, seed: int = 0):
    """Stacked member weights (``nn.Linear``'s uniform init) and uniform action tables:
    ``w1 [agents, nodes, hidden]`` (one input), ``b1 [agents, nodes, hidden]``, ``w2 [agents,
    nodes, hidden, nodes]``, ``b2 [agents, nodes, nodes]``, ``action_probs [agents, nodes,
    actions]``."""
    rng = np.random.default_rng(seed)

    def uniform(*shape, fan_in):
        bound = 1.0 / math.sqrt(fan_in)
        return rng.uniform(-bound, bound, shape).astype(np.float32)

    return dict(
        w1=uniform(agents, nodes, hidden, fan_in=1),
        b1=uniform(agents, nodes, hidden, fan_in=1),
        w2=uniform(agents, nodes, hidden, nodes, fan_in=hidden),
        b2=uniform(agents, nodes, nodes, fan_in=hidden),
        action_probs=np.full((agents, nodes, actions), 1.0 / actions, np.float32),
    )


def sample_categorical(u: np.ndarray, probs: np.ndarray) -> np.ndarray:
    """Inverse-CDF draw: ``u [...]``, ``probs [..., K]`` (not necessarily normalised)."""
    cdf = np.cumsum(probs, axis=-1)
    idx = (cdf <= (u * cdf[..., -1])[..., None]).sum(-1)
    return np.minimum(idx, probs.shape[-1] - 1)


def tagging_step(u_env, taggers, evader, actions, length=10.0, respawn=False, tag_radius=1.0):
    """Noise-free tagging step of B rollouts (``u_env [B, agents + 1]``: respawn positions,
    read only with ``respawn``); returns ``(taggers', evader', obs [B, agents], reward [B])``."""
    tagging = actions == TAG
    hit = tagging & (np.abs(taggers - evader[:, None]) <= tag_radius)
    reward = np.where(tagging, np.where(hit, 50.0, -20.0), -1.0).sum(-1, dtype=np.float32)
    move = np.where(actions == LEFT, -1.0, np.where(actions == RIGHT, 1.0, 0.0))
    taggers = np.clip(taggers + move.astype(np.float32), 0.0, length)
    d = (taggers - evader[:, None]).sum(-1)
    evader = np.clip(evader - np.sign(d), 0.0, length)
    if respawn:
        again = hit.any(-1)
        pos = u_env * length
        taggers = np.where(again[:, None], pos[:, :-1], taggers)
        evader = np.where(again, pos[:, -1], evader)
    return taggers, evader, evader[:, None] - taggers, reward


def rollout_returns(policy: dict, num: int, horizon: int = 3, seed: int = 0) -> np.ndarray:
    """Returns ``[num]`` of ``num`` rollouts (tagging thesis setting: gamma 1, no noise, no
    respawn) of the stochastic neural controller ``policy``."""
    rng = np.random.default_rng(seed)
    agents = policy["w1"].shape[0]
    rows = np.arange(agents)[None, :]
    pos = rng.random((num, agents + 1), dtype=np.float32) * 10.0
    taggers, evader = pos[:, :-1], pos[:, -1]
    nodes = np.zeros((num, agents), np.int64)
    ret = np.zeros(num, np.float32)
    for _ in range(horizon):
        u = rng.random((num, 2 * agents), dtype=np.float32)
        actions = sample_categorical(u[:, :agents], policy["action_probs"][rows, nodes])
        taggers, evader, obs, reward = tagging_step(None, taggers, evader, actions)
        # every member of agent a on a's observation, then each row's current node
        h = obs[:, :, None, None] * policy["w1"][None] + policy["b1"][None]  # [B, a, q, H]
        logits = np.einsum("baqh,aqhk->baqk", np.maximum(h, 0.0), policy["w2"])
        logits = np.take_along_axis(logits, nodes[:, :, None, None], axis=2)[:, :, 0]
        logits = logits + policy["b2"][rows, nodes]
        weights = np.exp(logits - logits.max(-1, keepdims=True))
        nodes = sample_categorical(u[:, agents:], weights)
        ret += reward
    return ret


def throughput(nodes: int, num: int, runs: int):
    """``(Timing, agent-steps/s)`` of ``num`` rollouts (thesis setting, h 3, 2 agents): median
    of ``runs`` calls after one warm-up call."""
    from benchmarks.timing import time_calls

    policy = random_policy(nodes)
    timing = time_calls(lambda: rollout_returns(policy, num), runs=runs)
    return timing, num * 3 * 2 / timing.median_s
