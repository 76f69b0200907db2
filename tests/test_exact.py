"""Exact evaluation of deterministic joint FSCs and brute-force optima (SPEC sections 3 and 8)."""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
import pytest

from cognet_jax.exact import (
    brute_force_optimum,
    exact_value,
    exact_values,
    policy_tree_transitions,
    tree_num_nodes,
)
from cognet_jax.io.dpomdp import TabularModel, parse_dpomdp

DPOMDP_DIR = Path(__file__).resolve().parents[2] / "shared" / "dpomdp"


@pytest.fixture(scope="module")
def models() -> dict[str, TabularModel]:
    if not DPOMDP_DIR.is_dir():
        pytest.skip(f"benchmark files not found at {DPOMDP_DIR}")
    names = ["dectiger", "broadcastChannel", "recycling", "GridSmall"]
    return {n: parse_dpomdp(DPOMDP_DIR / f"{n}.dpomdp") for n in names}


def random_model_text(
    rng: np.random.Generator, S: int, actions: tuple[int, ...], obs: tuple[int, ...]
) -> str:
    """A random dense model written in the .dpomdp format (rows as joint indices)."""
    JA, JO = int(np.prod(actions)), int(np.prod(obs))
    lines = [
        f"agents: {len(actions)}",
        "discount: 1",
        "values: reward",
        f"states: {S}",
        "start:",
        " ".join(repr(float(p)) for p in rng.dirichlet(np.ones(S))),
        "actions:",
        *[str(a) for a in actions],
        "observations:",
        *[str(z) for z in obs],
    ]
    for ja in range(JA):
        lines.append(f"T: {ja} :")
        lines += [" ".join(repr(float(p)) for p in rng.dirichlet(np.ones(S))) for _ in range(S)]
        lines.append(f"O: {ja} :")
        lines += [" ".join(repr(float(p)) for p in rng.dirichlet(np.ones(JO))) for _ in range(S)]
        for s in range(S):
            lines.append(f"R: {ja} : {s} : * : * : {rng.normal():.6f}")
    return "\n".join(lines) + "\n"


def random_controller(rng, m: TabularModel, nodes: int):
    actions = np.stack([rng.integers(0, m.action_counts[i], nodes) for i in range(m.num_agents)])
    transitions = rng.integers(0, nodes, (m.num_agents, nodes, max(m.obs_counts)))
    return actions, transitions


def slow_value(m: TabularModel, actions, transitions, horizon: int, gamma: float) -> float:
    """Plain-Python restatement of SPEC section 1, memoised on (state, nodes, time)."""
    n = m.num_agents
    tm, om, rm = m.transition, m.observation, m.reward

    @functools.cache
    def value(s: int, nodes: tuple[int, ...], t: int) -> float:
        if t == horizon:
            return 0.0
        ja = 0
        for i in range(n):
            ja = ja * m.action_counts[i] + int(actions[i][nodes[i]])
        v = float(rm[s, ja])
        for s2 in range(m.num_states):
            if tm[s, ja, s2] == 0.0:
                continue
            for jo in range(m.num_joint_obs):
                p = tm[s, ja, s2] * om[ja, s2, jo]
                if p == 0.0:
                    continue
                rest, zs = jo, [0] * n
                for i in reversed(range(n)):
                    zs[i] = rest % m.obs_counts[i]
                    rest //= m.obs_counts[i]
                nxt = tuple(int(transitions[i][nodes[i]][zs[i]]) for i in range(n))
                v += gamma * p * value(s2, nxt, t + 1)
        return v

    return sum(float(m.initial_belief[s]) * value(s, (0,) * n, 0) for s in range(m.num_states))


# --------------------------------------------------------------------------------------------
# Brute-force optima of SPEC section 8

SPEC_OPTIMA = [
    ("dectiger", 2, -4.0, 1e-9),
    ("broadcastChannel", 2, 2.0, 1e-9),
    ("recycling", 2, 7.0, 1e-9),
    ("GridSmall", 2, 0.91, 1e-9),
    ("dectiger", 3, 5.190812, 1e-6),
    ("broadcastChannel", 3, 2.99, 5e-3),
    ("recycling", 3, 10.660125, 1e-6),
]


@pytest.mark.parametrize("name, horizon, value, tol", SPEC_OPTIMA)
def test_brute_force_matches_published_optima(models, name, horizon, value, tol):
    m = models[name]
    opt = brute_force_optimum(m, horizon)  # undiscounted by default
    assert opt.value == pytest.approx(value, abs=tol)
    # the returned joint policy tree really has that value
    assert exact_value(m, opt.actions, opt.transitions, horizon, 1.0) == pytest.approx(
        opt.value, abs=1e-9
    )
    assert slow_value(m, opt.actions, opt.transitions, horizon, 1.0) == pytest.approx(
        opt.value, abs=1e-9
    )


@pytest.mark.parametrize(
    "name, horizon",
    [
        ("dectiger", 2),
        ("broadcastChannel", 2),
        ("recycling", 2),
        ("GridSmall", 2),
        ("broadcastChannel", 3),
    ],
)
def test_best_response_search_equals_exhaustive_enumeration(models, name, horizon):
    m = models[name]
    fast = brute_force_optimum(m, horizon, method="best_response")
    full = brute_force_optimum(m, horizon, method="exhaustive")
    assert fast.value == pytest.approx(full.value, abs=1e-9)


def test_brute_force_on_asymmetric_three_agent_model():
    rng = np.random.default_rng(3)
    m = parse_dpomdp(random_model_text(rng, 3, (2, 3, 2), (2, 1, 3)))
    for h in (1, 2):
        fast = brute_force_optimum(m, h)
        full = brute_force_optimum(m, h, method="exhaustive")
        assert fast.value == pytest.approx(full.value, abs=1e-9)
        assert slow_value(m, fast.actions, fast.transitions, h, 1.0) == pytest.approx(fast.value)
    # discounted brute force too
    fast = brute_force_optimum(m, 2, discount=0.5)
    full = brute_force_optimum(m, 2, discount=0.5, method="exhaustive")
    assert fast.value == pytest.approx(full.value, abs=1e-9)


def test_brute_force_limits(models):
    with pytest.raises(ValueError, match="max_policies"):
        brute_force_optimum(models["dectiger"], 3, method="exhaustive", max_policies=1000)
    with pytest.raises(ValueError):
        brute_force_optimum(models["dectiger"], 2, method="magic")


# --------------------------------------------------------------------------------------------
# Exact evaluation against an independent slow reference


@pytest.mark.parametrize("name, horizon, nodes", [("dectiger", 4, 3), ("recycling", 4, 2)])
def test_exact_matches_slow_reference(models, name, horizon, nodes):
    m = models[name]
    rng = np.random.default_rng(11)
    for _ in range(4):
        acts, trans = random_controller(rng, m, nodes)
        for gamma in (1.0, 0.9):
            got = exact_value(m, acts, trans, horizon, gamma)
            assert got == pytest.approx(slow_value(m, acts, trans, horizon, gamma), abs=1e-9)


def test_exact_on_asymmetric_models():
    rng = np.random.default_rng(5)
    for actions, obs in [((2, 3), (3, 2)), ((3, 2, 2), (2, 2, 1))]:
        m = parse_dpomdp(random_model_text(rng, 4, actions, obs))
        for _ in range(3):
            acts, trans = random_controller(rng, m, 3)
            want = slow_value(m, acts, trans, 3, 0.95)
            assert exact_value(m, acts, trans, 3, 0.95) == pytest.approx(want, abs=1e-9)


def test_batch_equals_single(models):
    m = models["GridSmall"]
    rng = np.random.default_rng(2)
    ctrls = [random_controller(rng, m, 4) for _ in range(7)]
    acts = np.stack([c[0] for c in ctrls])
    trans = np.stack([c[1] for c in ctrls])
    batch = exact_values(m, acts, trans, 6, 0.9)
    single = [exact_value(m, a, t, 6, 0.9) for a, t in ctrls]
    np.testing.assert_allclose(batch, single, atol=1e-12)
    # the arrays form of the model gives the same numbers
    arrays = (
        m.transition,
        m.observation,
        m.reward,
        m.initial_belief,
        m.action_counts,
        m.obs_counts,
    )
    np.testing.assert_allclose(exact_values(arrays, acts, trans, 6, 0.9), batch, atol=1e-12)


def test_horizon_zero_and_one(models):
    m = models["dectiger"]
    acts = np.array([[0], [0]])
    trans = np.zeros((2, 1, 2), dtype=int)
    assert exact_value(m, acts, trans, 0, 1.0) == 0.0
    assert exact_value(m, acts, trans, 1, 1.0) == -2.0  # listen-listen
    # always listening for h steps costs 2 per step
    assert exact_value(m, acts, trans, 5, 1.0) == pytest.approx(-10.0)
    assert exact_value(m, acts, trans, 3, 0.5) == pytest.approx(-2 * (1 + 0.5 + 0.25))


def test_infinite_horizon_converges(models):
    m = models["recycling"]  # discount 0.9 in the file
    rng = np.random.default_rng(4)
    for _ in range(3):
        acts, trans = random_controller(rng, m, 3)
        inf = exact_value(m, acts, trans, None, 0.9)
        long = exact_value(m, acts, trans, 600, 0.9)  # tail below 0.9^600 * 5 / 0.1
        assert inf == pytest.approx(long, abs=1e-9)
        # independent reference: solve (I - gamma P) V = r over (joint node, state)
        S, N = m.num_states, 3
        size = N * N * S
        P = np.zeros((size, size))
        r = np.zeros(size)
        for q0 in range(N):
            for q1 in range(N):
                ja = m.joint_action_index([acts[0, q0], acts[1, q1]])
                for s in range(S):
                    row = (q0 * N + q1) * S + s
                    r[row] = m.reward[s, ja]
                    for s2 in range(S):
                        for jo in range(m.num_joint_obs):
                            z0, z1 = m.split_joint_obs(jo)
                            col = (trans[0, q0, z0] * N + trans[1, q1, z1]) * S + s2
                            P[row, col] += m.transition[s, ja, s2] * m.observation[ja, s2, jo]
        V = np.linalg.solve(np.eye(size) - 0.9 * P, r)
        want = m.initial_belief @ V[:S]
        assert inf == pytest.approx(want, abs=1e-9)
        loose = exact_value(m, acts, trans, None, 0.9, tol=1e-3)
        assert abs(loose - want) <= 1e-3


def test_infinite_horizon_needs_discount_below_one(models):
    m = models["dectiger"]
    acts, trans = np.zeros((2, 1), int), np.zeros((2, 1, 2), int)
    with pytest.raises(ValueError, match="discount < 1"):
        exact_value(m, acts, trans, None, 1.0)
    with pytest.raises(RuntimeError, match="did not reach"):
        exact_value(m, acts, trans, None, 0.999, max_iter=3)


def test_controller_validation(models):
    m = models["dectiger"]
    ok_a, ok_t = np.zeros((2, 2), int), np.zeros((2, 2, 2), int)
    with pytest.raises(ValueError, match="actions must lie"):
        exact_value(m, ok_a + 3, ok_t, 2, 1.0)
    with pytest.raises(ValueError, match="next nodes"):
        exact_value(m, ok_a, ok_t + 2, 2, 1.0)
    with pytest.raises(ValueError, match="agents"):
        exact_value(m, np.zeros((3, 2), int), ok_t, 2, 1.0)
    with pytest.raises(ValueError, match="integer"):
        exact_value(m, ok_a.astype(float), ok_t, 2, 1.0)
    with pytest.raises(ValueError, match="horizon"):
        exact_value(m, ok_a, ok_t, -1, 1.0)


def test_policy_tree_transitions():
    t = policy_tree_transitions(2, 3)
    assert tree_num_nodes(2, 3) == 7 and t.shape == (7, 2)
    np.testing.assert_array_equal(t[:3], [[1, 2], [3, 4], [5, 6]])
    np.testing.assert_array_equal(t[3:, 0], [3, 4, 5, 6])  # leaves loop
    t3 = policy_tree_transitions(3, 2)
    np.testing.assert_array_equal(t3[0], [1, 2, 3])
    assert policy_tree_transitions(1, 3).tolist() == [[1], [2], [2]]
