"""The pure-JAX tabular simulator against its model, and Monte Carlo against exact values."""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cognet_jax.controllers.tabular import DeterministicTabularPolicy, TabularController
from cognet_jax.envs.tabular import TabularEnv, TabularParams, make_tabular
from cognet_jax.exact import exact_values
from cognet_jax.io.dpomdp import parse_dpomdp
from cognet_jax.rollout import rollouts

DPOMDP_DIR = Path(__file__).resolve().parents[2] / "shared" / "dpomdp"


def _require_files():
    if not DPOMDP_DIR.is_dir():
        pytest.skip(f"benchmark files not found at {DPOMDP_DIR}")


def asymmetric_model(seed: int = 0):
    """2 agents with 2 and 3 actions, 3 and 2 observations; 4 states; random dense model."""
    rng = np.random.default_rng(seed)
    S, JA, JO = 4, 6, 6
    lines = [
        "agents: 2",
        "discount: 1",
        "values: reward",
        "states: 4",
        "start: 0.1 0.2 0.3 0.4",
        "actions:",
        "stay go",
        "left mid right",
        "observations:",
        "lo mid hi",
        "no yes",
    ]
    for ja in range(JA):
        lines.append(f"T: {ja} :")
        lines += [" ".join(repr(float(p)) for p in rng.dirichlet(np.ones(S))) for _ in range(S)]
        lines.append(f"O: {ja} :")
        lines += [" ".join(repr(float(p)) for p in rng.dirichlet(np.ones(JO))) for _ in range(S)]
        lines += [f"R: {ja} : {s} : * : * : {rng.normal():.4f}" for s in range(S)]
    return parse_dpomdp("\n".join(lines) + "\n")


def test_static_description_and_params():
    m = asymmetric_model()
    env, params = make_tabular(m, horizon=5)
    assert isinstance(env, TabularEnv) and isinstance(params, TabularParams)
    assert env.num_agents == 2 and env.num_states == 4 and env.horizon == 5
    assert env.action_counts == (2, 3) and env.num_actions == 3
    assert env.obs_counts == (3, 2) and env.num_obs == 3
    assert env.obs_shape == () and env.obs_range is None
    assert env.num_joint_actions == 6 and env.num_joint_obs == 6
    # hashable and equal by value: usable as a static argument, no arrays inside
    assert hash(env) == hash(make_tabular(m, horizon=5)[0]) and env == make_tabular(m, 5)[0]
    leaves = jax.tree_util.tree_leaves(params)
    assert len(leaves) == 5 and all(leaf.dtype == jnp.float32 for leaf in leaves)
    assert params.transition.shape == (4, 6, 4) and params.observation.shape == (6, 4, 6)
    assert float(params.discount) == 1.0
    assert float(make_tabular(m, 5, discount=0.9)[1].discount) == pytest.approx(0.9)
    with pytest.raises(NotImplementedError):
        env.default_params()
    with pytest.raises(ValueError):
        make_tabular(m, 0)


def test_joint_index_conventions_match_the_model():
    m = asymmetric_model()
    env, _ = make_tabular(m, horizon=3)
    for a0 in range(2):
        for a1 in range(3):
            got = int(env.joint_action(jnp.array([a0, a1])))
            assert got == m.joint_action_index([a0, a1]) == a0 * 3 + a1
    for jo in range(6):
        got = tuple(int(z) for z in env.split_joint_obs(jnp.int32(jo)))
        assert got == m.split_joint_obs(jo)


def test_step_takes_uniforms_or_a_key():
    m = asymmetric_model()
    env, params = make_tabular(m, horizon=3)
    assert env.reset_noise == 1 and env.step_noise == 2
    key = jax.random.key(5)
    a = jnp.array([1, 2], jnp.int32)
    by_key = env.step(key, jnp.int32(1), a, params)
    by_u = env.step(jax.random.uniform(key, (2,)), jnp.int32(1), a, params)
    for x, y in zip(by_key, by_u, strict=True):
        np.testing.assert_array_equal(x, y)
    # inverse CDF: u = 0 picks the first possible outcome, u -> 1 the last one
    ja = m.joint_action_index([1, 2])
    s_lo, obs_lo, _ = env.step(jnp.array([0.0, 0.0]), jnp.int32(1), a, params)
    s_hi, obs_hi, _ = env.step(jnp.array([0.999999, 0.999999]), jnp.int32(1), a, params)
    assert int(s_lo) == np.flatnonzero(m.transition[1, ja])[0]
    assert int(s_hi) == np.flatnonzero(m.transition[1, ja])[-1]
    assert m.joint_obs_index(list(np.asarray(obs_lo))) == 0
    assert m.joint_obs_index(list(np.asarray(obs_hi))) == 5


def test_reset_draws_from_the_initial_belief():
    m = asymmetric_model()
    env, params = make_tabular(m, horizon=3)
    keys = jax.random.split(jax.random.key(0), 40_000)
    states = np.asarray(jax.jit(jax.vmap(lambda k: env.reset(k, params)))(keys))
    assert states.dtype == np.int32
    freq = np.bincount(states, minlength=4) / len(states)
    sd = np.sqrt(m.initial_belief * (1 - m.initial_belief) / len(states))
    assert np.all(np.abs(freq - m.initial_belief) < 5 * sd + 1e-9), freq


def test_step_matches_the_model():
    """For several (state, actions): reward = R[s, ja] exactly, (s', jo) ~ T[s, ja] O[ja, s']."""
    m = asymmetric_model()
    env, params = make_tabular(m, horizon=3)
    cases = [(0, (0, 0)), (1, (1, 2)), (3, (0, 1)), (2, (1, 0))]
    states = jnp.array([c[0] for c in cases], jnp.int32)
    acts = jnp.array([c[1] for c in cases], jnp.int32)
    n = 30_000
    keys = jax.random.split(jax.random.key(1), (len(cases), n))

    def one_case(ks, s, a):
        return jax.vmap(lambda k: env.step(k, s, a, params))(ks)

    nxt, obs, rew = jax.jit(jax.vmap(one_case))(keys, states, acts)
    nxt, obs, rew = np.asarray(nxt), np.asarray(obs), np.asarray(rew)
    assert nxt.dtype == np.int32 and obs.dtype == np.int32 and rew.dtype == np.float32
    assert obs.shape == (len(cases), n, 2)
    assert np.all(obs[..., 0] < 3) and np.all(obs[..., 1] < 2) and np.all(obs >= 0)
    for c, (s, a) in enumerate(cases):
        ja = m.joint_action_index(list(a))
        np.testing.assert_allclose(rew[c], np.float32(m.reward[s, ja]))
        jo = m.joint_obs_index([obs[c, :, 0], obs[c, :, 1]])
        counts = np.zeros((4, 6))
        np.add.at(counts, (nxt[c], jo), 1)
        want = m.transition[s, ja][:, None] * m.observation[ja]
        sd = np.sqrt(want * (1 - want) / n)
        assert np.all(np.abs(counts / n - want) < 5 * sd + 1e-3), (s, a)


def test_zero_probability_events_never_happen():
    _require_files()
    m = parse_dpomdp(DPOMDP_DIR / "broadcastChannel.dpomdp")
    env, params = make_tabular(m, horizon=2)
    keys = jax.random.split(jax.random.key(2), 5000)
    s0 = jax.jit(jax.vmap(lambda k: env.reset(k, params)))(keys)
    assert np.all(np.asarray(s0) == 3)  # start: S11
    wait_wait = jnp.array([1, 1], jnp.int32)
    nxt, _, rew = jax.jit(jax.vmap(lambda k: env.step(k, jnp.int32(3), wait_wait, params)))(keys)
    assert np.all(np.asarray(nxt) == 3) and np.all(np.asarray(rew) == 0)


def _mc_vs_exact(m, horizon, gamma, nodes, num_ctrl, seed, num_rollouts=20_000):
    env, params = make_tabular(m, horizon, discount=gamma)
    rng = np.random.default_rng(seed)
    acts = np.stack(
        [
            np.stack([rng.integers(0, m.action_counts[i], nodes) for i in range(m.num_agents)])
            for _ in range(num_ctrl)
        ]
    )
    trans = rng.integers(0, nodes, (num_ctrl, m.num_agents, nodes, env.num_obs))
    ctrl = TabularController(
        m.num_agents, nodes, env.num_actions, env.num_obs, action_counts=env.action_counts
    )
    policies = DeterministicTabularPolicy(
        actions=jnp.asarray(acts, jnp.int32), transitions=jnp.asarray(trans, jnp.int32)
    )
    key = jax.random.key(seed)
    run = jax.jit(jax.vmap(lambda pol: rollouts(env, ctrl, key, num_rollouts, params, pol)))
    returns = np.asarray(run(policies), dtype=np.float64)  # [C, R]
    mean = returns.mean(1)
    se = returns.std(1, ddof=1) / np.sqrt(num_rollouts)
    exact = exact_values(m, acts, trans, horizon, gamma)
    return mean, se, exact


def test_monte_carlo_agrees_with_exact_recycling():
    _require_files()
    m = parse_dpomdp(DPOMDP_DIR / "recycling.dpomdp")
    mean, se, exact = _mc_vs_exact(m, horizon=8, gamma=0.9, nodes=3, num_ctrl=5, seed=1)
    assert np.all(se > 0)  # (with this seed no controller has a deterministic return)
    assert np.all(np.abs(mean - exact) <= 3 * se + 1e-5 * (1 + np.abs(exact))), (mean, exact, se)


def test_monte_carlo_agrees_with_exact_asymmetric():
    m = asymmetric_model(seed=3)
    mean, se, exact = _mc_vs_exact(m, horizon=5, gamma=1.0, nodes=3, num_ctrl=4, seed=8)
    assert np.all(se > 0)
    assert np.all(np.abs(mean - exact) < 3 * se), (mean, exact, se)
    # the controllers differ enough for the comparison to mean something
    assert np.ptp(exact) > 10 * se.max()


def test_sparse_observation_rows_draw_and_value_as_the_full_rows():
    """A model that observes deterministically keeps its observation rows as lists
    (``obs_outcomes``): rollouts draw exactly what the full rows draw, and exact values are the
    same, on the GridSmall benchmark (16 states, one observation of 4 per row)."""
    from cognet_jax.exact_jax import exact_value

    _require_files()
    env, params = make_tabular(parse_dpomdp((DPOMDP_DIR / "GridSmall.dpomdp").read_text()), 4)
    assert params.obs_outcomes is not None and params.obs_outcomes.shape[-1] == 1
    dense = params.replace(obs_outcomes=None, obs_outcome_probs=None)
    rng = np.random.default_rng(0)
    n = 20_000
    u = jnp.asarray(rng.uniform(size=(n, 2)), jnp.float32)
    s = jnp.asarray(rng.integers(0, env.num_states, n), jnp.int32)
    a = jnp.asarray(np.stack([rng.integers(0, c, n) for c in env.action_counts], 1), jnp.int32)
    sparse_out = jax.vmap(lambda u, s, a: env.step(u, s, a, params))(u, s, a)
    dense_out = jax.vmap(lambda u, s, a: env.step(u, s, a, dense))(u, s, a)
    for x, y in zip(sparse_out, dense_out):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    for seed in range(5):
        r = np.random.default_rng(seed)
        policy = DeterministicTabularPolicy(
            jnp.asarray(r.integers(0, min(env.action_counts), (2, 3)), jnp.int32),
            jnp.asarray(r.integers(0, 3, (2, 3, max(env.obs_counts))), jnp.int32),
        )
        assert float(exact_value(env, params, policy, 3)) == pytest.approx(
            float(exact_value(env, dense, policy, 3)), abs=1e-5
        )


def test_rows_of_17_to_32_listed_entries_draw_by_their_inverse_cdf():
    """Rows listing 17 to 32 successors (the meeting grid's 25) are drawn with written-out
    running sums (``LISTED_UNROLLED``): every draw is the inverse CDF of its row, as float64
    running sums place it, except within float32 rounding of a boundary."""
    from cognet_jax.envs.base import UNROLLED_CATEGORIES
    from cognet_jax.envs.tabular import LISTED_UNROLLED

    rng = np.random.default_rng(0)
    S, K = 60, 25
    assert UNROLLED_CATEGORIES < K <= LISTED_UNROLLED
    transition = np.zeros((S, 1, S))
    for s in range(S):
        transition[s, 0, rng.choice(S, K, replace=False)] = rng.dirichlet(np.ones(K))
    lines = ["agents: 1", "discount: 1", "values: reward", f"states: {S}", "start: uniform"]
    lines += ["actions:", "a", "observations:", "o", "R: * : * : * : * : 0"]
    rows, cols = transition[:, 0].nonzero()
    lines += [f"T: 0 : {s} : {n} : {float(transition[s, 0, n])!r}" for s, n in zip(rows, cols)]
    lines += ["O: * : * : 0 : 1"]
    env, params = make_tabular(parse_dpomdp("\n".join(lines) + "\n"), 2)
    assert params.successors is not None and params.successors.shape[-1] == K
    n = 50_000
    u = rng.uniform(size=n)
    s = rng.integers(0, S, n)
    uu = jnp.asarray(np.stack([u, u], 1), jnp.float32)
    step = jax.vmap(lambda u, s: env.step(u, s, jnp.zeros(1, jnp.int32), params)[0])
    drawn = np.asarray(step(uu, jnp.asarray(s, jnp.int32)))
    listed = np.asarray(params.successors)[s, 0]  # [n, K]
    probs = np.asarray(params.successor_probs, np.float64)[s, 0]
    cdf = np.cumsum(probs, -1)
    threshold = np.asarray(uu[:, 0], np.float64)[:, None] * cdf[:, -1:]
    expected = listed[np.arange(n), np.minimum((cdf <= threshold).sum(-1), K - 1)]
    near = np.min(np.abs(cdf - threshold), -1) < 1e-5
    assert np.mean(near) < 0.01
    np.testing.assert_array_equal(drawn[~near], expected[~near])
