"""PyTorch references (benchmarks/torch_reference): simulators equal cognet_jax's tagging step,
both COGNet-DICE versions run, and SPEC section 8 values come out of the torch simulator."""

import importlib
import importlib.util
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cognet_jax.envs.tagging import TaggingState
from cognet_jax.envs.tagging import make_tagging as jax_make_tagging


class _ImportedAtFirstUse:
    """Module ``name``, imported when one of its attributes is first read: importing torch takes
    about 2 s, which every xdist worker paid while collecting the suite; now only the worker
    that runs these tests does."""

    def __init__(self, name: str):
        self._name = name

    def __getattr__(self, attr: str):
        if attr.startswith("_"):  # pytest's collection probes names such as ``__test__``
            raise AttributeError(attr)
        return getattr(importlib.import_module(self._name), attr)


pytestmark = pytest.mark.skipif(
    importlib.util.find_spec("torch") is None, reason="torch is not installed"
)
torch = _ImportedAtFirstUse("torch")
# ``benchmarks`` is a top-level folder of the repository, not part of the installed package; the
# pytest configuration (``pythonpath = ["."]``) puts the repository root on the import path.
reference = _ImportedAtFirstUse("benchmarks.torch_reference")
torch_tagging = _ImportedAtFirstUse("benchmarks.torch_reference.tagging")


def _random_cases(rng, num, noise_len):
    """Positions mixing uniform values, integers (exact tag-radius and wall cases) and ties."""
    kind = rng.integers(0, 3, size=(num, 3))
    uniform = rng.uniform(0, 10, size=(num, 3))
    integer = rng.integers(0, 11, size=(num, 3)).astype(float)
    pos = np.where(kind == 0, uniform, integer)
    pos = np.where(kind == 2, pos[:, 2:3], pos)  # some positions equal to the evader
    pos = pos.astype(np.float32)
    actions = rng.integers(0, 3, size=(num, 2))
    u = rng.uniform(size=(num, noise_len)).astype(np.float32)
    return pos, actions, u


@pytest.mark.parametrize("setting", ["thesis", "cogdice-paper"])
@pytest.mark.parametrize("noise", [0.0, 0.3])
def test_torch_simulators_match_jax(setting, noise):
    env, params = jax_make_tagging(setting, motion_noise=noise, obs_noise=noise)
    cfg = reference.make_tagging(setting, motion_noise=noise, obs_noise=noise)
    assert cfg.step_noise == env.step_noise and cfg.reset_noise == env.reset_noise
    pos, actions, u = _random_cases(np.random.default_rng(int(noise * 10) + len(setting)), 400, 7)

    step = jax.jit(jax.vmap(env.step, (0, 0, 0, None)))
    state = TaggingState(taggers=jnp.asarray(pos[:, :2]), evader=jnp.asarray(pos[:, 2]))
    nxt, obs, reward = step(jnp.asarray(u), state, jnp.asarray(actions, jnp.int32), params)
    ref = [np.asarray(x) for x in (nxt.taggers, nxt.evader, obs, reward)]

    # batched torch
    out = torch_tagging.step_batched(
        torch.from_numpy(u),
        torch.from_numpy(pos[:, :2]),
        torch.from_numpy(pos[:, 2]),
        torch.from_numpy(actions),
        cfg,
    )
    for got, want in zip(out, ref):
        assert got.dtype == torch.float32
        np.testing.assert_allclose(got.numpy(), want, atol=1e-5)
    np.testing.assert_array_equal(out[3].numpy(), ref[3])

    # scalar (Python floats), row by row
    for k in range(pos.shape[0]):
        taggers, evader, z, r = torch_tagging.step_scalar(
            u[k].tolist(), pos[k, :2].tolist(), float(pos[k, 2]), actions[k].tolist(), cfg
        )
        np.testing.assert_allclose(taggers, ref[0][k], atol=1e-5)
        np.testing.assert_allclose(evader, ref[1][k], atol=1e-5)
        np.testing.assert_allclose(z, ref[2][k], atol=1e-5)
        assert r == ref[3][k]


def test_torch_reset_matches_jax():
    env, params = jax_make_tagging("thesis")
    u = np.random.default_rng(3).uniform(size=(50, env.reset_noise)).astype(np.float32)
    want = jax.vmap(env.reset, (0, None))(jnp.asarray(u), params)
    taggers, evader = torch_tagging.reset_batched(
        torch.from_numpy(u), reference.make_tagging("thesis")
    )
    np.testing.assert_allclose(taggers.numpy(), np.asarray(want.taggers), atol=1e-6)
    np.testing.assert_allclose(evader.numpy(), np.asarray(want.evader), atol=1e-6)


def _small():
    return reference.CognetSettings(
        nodes=3, rollouts=40, top=6, keep=3, eval_rollouts=6, train_steps=2
    )


@pytest.mark.parametrize("cls", ["TorchCognetLoop", "TorchCognetVectorized"])
def test_one_step_runs(cls):
    algo = getattr(reference, cls)(_small(), seed=0)
    first = algo.step()
    second = algo.step()
    for metrics in (first, second):
        for key in ("value", "best_value", "best_candidate", "rollout_mean"):
            assert math.isfinite(metrics[key]), (key, metrics)
        assert 0 <= metrics["kept"] <= _small().keep
    assert second["best_value"] >= first["value"]
    probs = algo.action_probs
    assert torch.isfinite(probs).all()
    torch.testing.assert_close(probs.sum(-1), torch.ones(probs.shape[:-1]))
    assert algo.rollout_returns(7).shape == (7,)


def test_compiled_reference_draws_the_same_numbers_as_the_eager_one():
    """``torch.compile`` of the time step changes speed, not results: same seed, same returns
    (up to float rounding of the fused kernels), for one policy and for a batch of candidates
    with common random numbers (the two shapes an iteration compiles)."""
    eager, compiled = (
        reference.TorchCognetVectorized(_small(), seed=3),
        reference.TorchCognetCompiled(_small(), seed=3),
    )
    torch.testing.assert_close(compiled.rollout_returns(64), eager.rollout_returns(64))
    cands = torch.stack([eager.action_probs, eager.action_probs.flip(-1)])
    torch.testing.assert_close(
        compiled.rollouts(cands, 16, crn=True), eager.rollouts(cands, 16, crn=True)
    )


def test_noise_free_rollouts_draw_no_simulator_uniforms():
    """The vectorised reference draws only the uniforms the setting uses (as XLA keeps only
    the draws the JAX program reads): 2 per agent and step in the noise-free thesis setting."""
    assert reference.make_tagging("thesis").step_noise_used == 0
    assert reference.make_tagging("thesis", obs_noise=0.1).step_noise_used == 7
    assert reference.make_tagging("cogdice-paper").step_noise_used == 7  # respawn
    algo = reference.TorchCognetVectorized(_small(), seed=0)
    before = algo.gen.get_state()
    algo.rollout_returns(10)
    after = algo.gen.get_state()
    fresh = torch.Generator().set_state(before)
    env = algo.env
    torch.rand(10, env.reset_noise, generator=fresh)
    for _ in range(env.horizon):
        torch.rand(10, 2 * env.num_agents, generator=fresh)
    assert torch.equal(fresh.get_state(), after)


def test_accepts_cognet_jax_settings():
    from cognet_jax.algorithms.cognet_thesis import CognetHyper
    from cognet_jax.algorithms.cognet_thesis import CognetSettings as JaxSettings

    algo = reference.TorchCognetVectorized(
        JaxSettings(nodes=2, rollouts=40, top=8, keep=2, eval_rollouts=5, train_steps=2),
        hyper=CognetHyper(alpha=jnp.float32(0.3)),
    )
    assert algo.settings.nodes == 2 and algo.hyper.alpha == pytest.approx(0.3)
    assert math.isfinite(algo.step()["value"])


def test_separate_training_step_runs():
    settings = reference.CognetSettings(
        nodes=3, rollouts=30, keep=4, eval_rollouts=6, separate=True
    )
    for cls in (reference.TorchCognetLoop, reference.TorchCognetVectorized):
        algo = cls(settings, seed=1)
        before = algo.action_probs.clone()
        assert math.isfinite(algo.step()["value"])
        torch.testing.assert_close(algo.action_probs, before)


def _region_policy_value(cfg, num, seed=0):
    """The reactive 3-node controller of SPEC section 8 on the batched torch simulator: node 0
    moves left, node 1 tags, node 2 moves right; next node by the region of z: (-inf, -1] -> 0,
    (-1, 1] -> 1, (1, inf) -> 2."""
    gen = torch.Generator().manual_seed(seed)
    node_action = torch.tensor([1, 0, 2])
    points = torch.tensor([-1.0, 1.0])
    taggers, evader = torch_tagging.reset_batched(
        torch.rand(num, cfg.reset_noise, generator=gen), cfg
    )
    nodes = torch.zeros(num, cfg.num_agents, dtype=torch.long)
    ret, discount = torch.zeros(num, dtype=torch.float64), 1.0
    for _ in range(cfg.horizon):
        u = torch.rand(num, cfg.step_noise, generator=gen)
        taggers, evader, obs, reward = torch_tagging.step_batched(
            u, taggers, evader, node_action[nodes], cfg
        )
        nodes = (points < obs[..., None]).sum(-1)  # number of points strictly below z
        ret += discount * reward
        discount *= cfg.discount
    return ret.mean().item(), ret.std().item() / math.sqrt(num)


def test_reactive_controller_value_thesis():
    mean, se = _region_policy_value(reference.make_tagging("thesis"), 20_000)
    assert abs(mean - 20.76) < 3 * math.hypot(se, 0.09), (mean, se)


def test_random_policy_value_vectorized():
    algo = reference.TorchCognetVectorized(reference.CognetSettings(nodes=3), seed=2)
    ret = algo.rollout_returns(20_000).double()
    mean, se = ret.mean().item(), ret.std().item() / math.sqrt(ret.numel())
    assert abs(mean - (-23.68)) < 3 * se + 0.05, (mean, se)


def test_random_policy_value_loop():
    algo = reference.TorchCognetLoop(reference.CognetSettings(nodes=3), seed=2)
    ret = algo.rollout_returns(600).double()
    mean, se = ret.mean().item(), ret.std().item() / math.sqrt(ret.numel())
    assert abs(mean - (-23.68)) < 3.5 * se, (mean, se)


def _pairs_round(rng, kept, horizon, agents, nodes, max_node):
    """Trajectory pieces whose visited nodes are ``< max_node`` (others get no training data)."""
    src = rng.integers(0, max_node, size=(kept, horizon, agents))
    return dict(
        nodes=torch.from_numpy(src),
        next_nodes=torch.from_numpy(rng.integers(0, nodes, size=(kept, horizon, agents))),
        obs=torch.from_numpy(rng.uniform(-10, 10, size=(kept, horizon, agents)).astype(np.float32)),
        actions=torch.zeros(kept, horizon, agents, dtype=torch.long),
    )


def test_network_training_matches_jax_and_loop():
    """Same weights, same pairs: cognet_jax's masked optax Adam, the vectorised reference's
    stacked per-member Adam and the loop reference's torch.optim.Adam per module agree, also when
    some members get no data in the first round (their weights and step counts stay put)."""
    from cognet_jax.algorithms.cognet_thesis import CognetHyper as JaxHyper
    from cognet_jax.algorithms.cognet_thesis import CognetSettings as JaxSettings
    from cognet_jax.algorithms.cognet_thesis import CognetThesis, training_pairs
    from cognet_jax.rollout import Trajectory

    nodes, hidden, steps, lr, kept = 4, 5, 3, 0.05, 3
    env, _ = jax_make_tagging("thesis")
    jalgo = CognetThesis(env, JaxSettings(nodes=nodes, hidden=hidden, train_steps=steps))
    settings = reference.CognetSettings(nodes=nodes, hidden=hidden, train_steps=steps)
    vec, loop = (
        reference.TorchCognetVectorized(settings, seed=3),
        reference.TorchCognetLoop(settings),
    )
    with torch.no_grad():  # the loop modules get the vectorised reference's weights
        for i in range(2):
            for q in range(nodes):
                net = loop.nets[i][q]
                net.fc1.weight.copy_(vec.nets.w1[i, q].T)
                net.fc1.bias.copy_(vec.nets.b1[i, q])
                net.fc2.weight.copy_(vec.nets.w2[i, q].T)
                net.fc2.bias.copy_(vec.nets.b2[i, q])
    names = dict(w1=("Dense_0", "kernel"), b1=("Dense_0", "bias"))
    names.update(w2=("Dense_1", "kernel"), b2=("Dense_1", "bias"))
    jnet = {"params": {"Dense_0": {}, "Dense_1": {}}}
    for name, (layer, leaf) in names.items():
        jnet["params"][layer][leaf] = jnp.asarray(getattr(vec.nets, name).detach().numpy())
    initial = vec.nets.w2.detach().clone()

    rng = np.random.default_rng(0)
    rounds = [_pairs_round(rng, kept, env.horizon, 2, nodes, m) for m in (2, nodes)]

    @jax.jit
    def jax_two_rounds(net, trajs):
        opt = jax.vmap(jax.vmap(jalgo.optimizer.init))(net)
        out = []
        for traj in trajs:
            pairs = training_pairs(traj, jnp.arange(kept), jnp.ones(kept, bool))
            net, opt = jalgo.train_networks(net, opt, pairs, JaxHyper(learning_rate=lr))
            out.append(net)
        return out

    jtrajs = [
        Trajectory(
            *(r[k].numpy() for k in ("nodes", "actions", "obs", "next_nodes")),
            rewards=np.zeros((kept, env.horizon), np.float32),
            ret=np.zeros(kept, np.float32),
        )
        for r in rounds
    ]
    jax_nets = jax_two_rounds(jnet, jtrajs)

    # round 1: members of nodes 2, 3 get no pairs; round 2: every member does
    for max_node, traj, jax_net in zip((2, nodes), rounds, jax_nets):
        vec._train_networks(traj, torch.arange(kept), lr)
        loop._train_networks([loop_episode(traj, k) for k in range(kept)], lr)
        ref = {n: np.asarray(jax_net["params"][a][b]) for n, (a, b) in names.items()}
        for name in names:
            got = getattr(vec.nets, name).detach().numpy()
            np.testing.assert_allclose(got, ref[name], atol=1e-4, err_msg=name)
        for i in range(2):
            for q in range(nodes):
                net = loop.nets[i][q]
                np.testing.assert_allclose(net.fc1.weight.detach().T, ref["w1"][i, q], atol=1e-4)
                np.testing.assert_allclose(net.fc1.bias.detach(), ref["b1"][i, q], atol=1e-4)
                np.testing.assert_allclose(net.fc2.weight.detach().T, ref["w2"][i, q], atol=1e-4)
                np.testing.assert_allclose(net.fc2.bias.detach(), ref["b2"][i, q], atol=1e-4)
        moved = (vec.nets.w2.detach() - initial).abs().amax((-1, -2)) > 1e-3  # [agents, nodes]
        assert moved[:, :max_node].all() and not moved[:, max_node:].any()


def loop_episode(traj, k):
    from benchmarks.torch_reference.loop import Episode

    return Episode(
        nodes=traj["nodes"][k].tolist(),
        actions=traj["actions"][k].tolist(),
        obs=traj["obs"][k].tolist(),
        next_nodes=traj["next_nodes"][k].tolist(),
        ret=0.0,
    )
