"""A large synthetic MADP file: 300 states, 2 agents with 4 actions and 8 observations each,
several hundred KB of T / O row lines. Parsing must stay fast, the JAX model must build, and a
short G-DICE run must give finite values."""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cognet_jax.algorithms.engine import SearchParams, ThresholdHyper
from cognet_jax.algorithms.gdice_search import GDice, GDiceSettings
from cognet_jax.envs.tabular import make_tabular
from cognet_jax.exact import exact_value
from cognet_jax.io.dpomdp import parse_dpomdp

S, A, Z = 300, 4, 8
JA, JO = A * A, Z * Z


def sparse_row(rng: np.random.Generator, n: int, support: int) -> np.ndarray:
    """A probability row over ``n`` entries with ``support`` non-zeros, each a multiple of
    1/100 (exact two-decimal text, sums to 1 up to float rounding)."""
    row = np.zeros(n)
    cols = rng.choice(n, size=support, replace=False)
    row[cols] = (1 + rng.multinomial(100 - support, np.ones(support) / support)) / 100
    return row


def row_text(row: np.ndarray) -> str:
    return " ".join("0" if p == 0 else f"{p:.2f}" for p in row)


def write_model(path, seed: int = 0):
    """Write the model with ``T: * : s :`` rows, per-joint-action overrides and
    ``O: * : s' :`` rows; return the dense arrays it describes."""
    rng = np.random.default_rng(seed)
    T = np.zeros((S, JA, S))
    Obs = np.zeros((JA, S, JO))
    R = np.round(rng.normal(size=(S, JA)), 2)
    lines = [
        "# synthetic large Dec-POMDP for the parser / G-DICE scale test",
        "agents: 2",
        "discount: 0.95",
        "values: reward",
        f"states: {S}",
        "start:",
        "uniform",
        "actions:",
        f"{A}",
        f"{A}",
        "observations:",
        f"{Z}",
        f"{Z}",
    ]
    for s in range(S):  # default transition rows, for every joint action
        row = sparse_row(rng, S, 6)
        T[s, :, :] = row
        lines += [f"T: * : {s} :", row_text(row)]
    for ja in range(JA):  # later lines overwrite: action-specific rows for some states
        for s in rng.choice(S, size=25, replace=False):
            row = sparse_row(rng, S, 6)
            T[s, ja, :] = row
            a0, a1 = divmod(ja, A)
            lines += [f"T: {a0} {a1} : {s} :", row_text(row)]
    for sp in range(S):
        row = sparse_row(rng, JO, 10)
        Obs[:, sp, :] = row
        lines += [f"O: * : {sp} :", row_text(row)]
    for ja in range(JA):
        for sp in rng.choice(S, size=10, replace=False):
            row = sparse_row(rng, JO, 10)
            Obs[ja, sp, :] = row
            lines += [f"O: {ja} : {sp} :", row_text(row)]
    for ja in range(JA):
        for s in range(S):
            lines.append(f"R: {ja} : {s} : * : * : {R[s, ja]:.2f}")
    path.write_text("\n".join(lines) + "\n")
    return T, Obs, R


@pytest.fixture(scope="module")
def large(tmp_path_factory):
    path = tmp_path_factory.mktemp("large") / "large.dpomdp"
    arrays = write_model(path)
    t0 = time.perf_counter()
    model = parse_dpomdp(path)
    parse_s = time.perf_counter() - t0
    return path, model, parse_s, arrays


def test_large_file_parses_quickly_and_exactly(large):
    path, model, parse_s, (T, Obs, R) = large
    size = path.stat().st_size
    assert 300_000 < size < 2_000_000, size
    assert parse_s < 5.0, f"parsing {size / 1e3:.0f} KB took {parse_s:.2f} s"
    assert model.num_states == S and model.num_agents == 2
    assert model.action_counts == (A, A) and model.obs_counts == (Z, Z)
    assert model.discount == 0.95
    np.testing.assert_allclose(model.transition, T, atol=1e-12)
    np.testing.assert_allclose(model.observation, Obs, atol=1e-12)
    np.testing.assert_allclose(model.reward, R, atol=1e-12)
    np.testing.assert_allclose(model.initial_belief, np.full(S, 1 / S))


def test_large_model_builds_and_short_gdice_run_is_finite(large):
    _, model, _, _ = large
    horizon = 6
    env, env_params = make_tabular(model, horizon)
    # sparse rows (6 non-zeros of 300): only the rows are kept, and they are the model's rows
    assert env_params.transition is None
    succ, probs = np.asarray(env_params.successors), np.asarray(env_params.successor_probs)
    assert succ.shape[:2] == (S, JA) and succ.shape[2] < S // 2
    dense = np.zeros((S, JA, S))
    np.add.at(dense, (np.arange(S)[:, None, None], np.arange(JA)[None, :, None], succ), probs)
    np.testing.assert_allclose(dense, model.transition, atol=1e-6)
    assert env_params.observation.shape == (JA, S, JO)
    settings = GDiceSettings(nodes=3, iterations=3, samples=16, elites=4, eval_rollouts=16)
    algo = GDice(env, settings)
    params = SearchParams(env_params, ThresholdHyper())
    step = jax.jit(algo.step)
    state = algo.init(jax.random.key(0), params)
    for i in range(settings.iterations):
        state, m = step(jax.random.key(10 + i), state, params)
        assert np.isfinite(float(m.value)) and np.isfinite(float(m.mean_value))
        # the first iteration keeps N_b elites (V_w = -inf); later ones may keep none
        assert int(m.kept) == settings.elites if i == 0 else 0 <= int(m.kept) <= settings.elites
    assert np.isfinite(float(state.progress.in_loop_best))
    best = jax.device_get(state.best_policy)
    returns = jax.jit(lambda k, p: algo.returns(k, p, 4000, params, 4000))(
        jax.random.key(99), state.best_policy
    )
    mean = float(jnp.mean(returns))
    stderr = float(jnp.std(returns) / np.sqrt(returns.size))
    exact = exact_value(model, best.actions, best.transitions, horizon, model.discount)
    assert np.isfinite(mean) and np.isfinite(exact)
    assert abs(mean - exact) < 5 * stderr + 1e-3, (mean, stderr, exact)


def test_steps_from_sparse_rows_draw_what_the_dense_rows_draw(large):
    """The rows-only model steps like the dense table would: with the same uniforms every draw
    of the next state and observation is the same (inverse CDF over the non-zeros in column
    order), and the reward too."""
    _, model, _, _ = large
    env, sparse = make_tabular(model, 3)
    dense = sparse.replace(
        transition=jnp.asarray(model.transition, jnp.float32),
        successors=None,
        successor_probs=None,
    )
    n = 20_000
    k_s, k_a, k_u = jax.random.split(jax.random.key(5), 3)
    states = jax.random.randint(k_s, (n,), 0, S)
    actions = jax.random.randint(k_a, (n, 2), 0, A)
    u = jax.random.uniform(k_u, (n, env.step_noise))

    @jax.jit
    def both(u, s, a):
        step = jax.vmap(env.step, (0, 0, 0, None))
        return step(u, s, a, sparse), step(u, s, a, dense)

    got, want = both(u, states, actions)
    for g, w in zip(got, want):
        np.testing.assert_array_equal(np.asarray(g), np.asarray(w))


def test_one_layer_move_values_on_sparse_rows(large):
    """The polish's one-layer move values on a rows-only model (occupancy pushed along the
    sparse rows) equal full exact evaluations of the changed controllers."""
    from test_exact_jax import _check_move_values

    _, model, _, _ = large
    env, params = make_tabular(model, 3)
    assert params.successors is not None
    _check_move_values(env, params, width=2, seed=4, joint=False, count=40)
