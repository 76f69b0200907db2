"""The compiled exact evaluator (cognet_jax.exact_jax) against the numpy one, and G-DICE with
``algorithm.evaluator = "exact"``: wiring, validation and a known optimum."""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cognet_jax.controllers.tabular import DeterministicTabularPolicy
from cognet_jax.envs.tabular import make_tabular
from cognet_jax.exact import exact_values
from cognet_jax.exact_jax import exact_value as exact_value_jax

DPOMDP_DIR = Path(__file__).resolve().parents[2] / "shared" / "dpomdp"
CASES = [  # file, horizon, discount override, nodes
    ("dectiger", 4, None, 5),
    ("recycling", 30, 0.9, 3),
    ("broadcastChannel", 3, None, 2),
    ("GridSmall", 3, None, 3),
]


def _model(name, discount):
    from cognet_jax.io.dpomdp import parse_dpomdp

    path = DPOMDP_DIR / f"{name}.dpomdp"
    if not path.is_file():
        pytest.skip(f"benchmark file not found at {path}")
    return parse_dpomdp(str(path), discount=discount)


@pytest.mark.parametrize("name,horizon,discount,nodes", CASES)
def test_matches_numpy_exact_values_on_random_controllers(name, horizon, discount, nodes):
    model = _model(name, discount)
    env, params = make_tabular(model, horizon, discount)
    rng = np.random.default_rng(1)
    batch = 32
    counts = np.asarray(env.action_counts)[None, :, None]
    actions = rng.integers(0, 1 << 20, (batch, env.num_agents, nodes)) % counts
    transitions = rng.integers(0, nodes, (batch, env.num_agents, nodes, env.num_obs))
    expected = exact_values(model, actions, transitions, horizon, model.discount)
    pol = DeterministicTabularPolicy(
        actions=jnp.asarray(actions, jnp.int32), transitions=jnp.asarray(transitions, jnp.int32)
    )
    got = np.asarray(jax.vmap(lambda p: exact_value_jax(env, params, p, nodes))(pol))
    scale = max(1.0, float(np.abs(expected).max()))
    np.testing.assert_allclose(got, expected, rtol=0, atol=2e-6 * scale * horizon)


def test_gdice_exact_evaluator_finds_dectiger_h2_optimum_and_in_loop_value_is_exact():
    from cognet_jax.api import make_train
    from cognet_jax.envs.tabular import load_problem
    from cognet_jax.exact import exact_value
    from cognet_jax.registry import load_config

    path = DPOMDP_DIR / "dectiger.dpomdp"
    if not path.is_file():
        pytest.skip(f"benchmark file not found at {path}")
    config = load_config(
        "gdice-dpomdp-spec",
        [
            f"problem.path={str(path)!r}",
            "problem.horizon=2",
            "algorithm.nodes=3",
            "algorithm.iterations=10",
            "algorithm.samples=50",
            "algorithm.elites=5",
            "algorithm.alpha=0.3",
            'algorithm.evaluator="exact"',
        ],
    )
    state, metrics = jax.jit(make_train(config))(jax.random.key(0))
    best = jax.device_get(state.best_policy)
    value = exact_value(load_problem(config.problem), best.actions, best.transitions, 2, 1.0)
    assert value == pytest.approx(-4.0, abs=1e-9)
    # with exact values there is no winner's curse: the in-loop best is the true value
    assert float(metrics.in_loop_best[-1]) == pytest.approx(value, abs=1e-4)


def test_exact_evaluator_config_errors(tmp_path):
    from cognet_jax.api import build_algorithm
    from cognet_jax.config import ConfigError
    from cognet_jax.registry import load_config

    with pytest.raises(ConfigError, match="algorithm.evaluator"):
        load_config("gdice-dpomdp", ["problem.path='x.dpomdp'", 'algorithm.evaluator="magic"'])
    toml = tmp_path / "tagging-gdice.toml"
    toml.write_text(
        '[experiment]\nalgorithm = "gdice"\n[env]\nname = "tagging"\nobs_division = 1.0\n'
        '[algorithm]\nevaluator = "exact"\n'
    )
    with pytest.raises(ConfigError, match="algorithm.evaluator"):  # no exact tagging model
        build_algorithm(load_config(str(toml)))


def _check_move_values(env, params, width: int, seed: int, joint: bool, count: int = 60):
    """``layered_move_values`` against valuing every changed controller in full."""
    from cognet_jax.algorithms.polish import apply_move, neighbour_moves
    from cognet_jax.controllers.tabular import TabularController
    from cognet_jax.exact_jax import exact_value_layered, layered_move_values

    controller = TabularController(
        num_agents=env.num_agents,
        num_nodes=width * env.horizon,
        num_actions=max(env.action_counts),
        num_obs=max(env.obs_counts),
        action_counts=tuple(env.action_counts),
        obs_counts=tuple(env.obs_counts),
        layers=env.horizon,
    )
    moves = neighbour_moves(controller, env.action_counts, env.obs_counts, joint)
    rng = np.random.default_rng(seed)
    moves = jnp.asarray(moves[rng.choice(len(moves), min(count, len(moves)), replace=False)])
    policy = controller.sample(jax.random.key(seed), controller.init_distribution())

    @jax.jit
    def both(policy, moves):
        fast = layered_move_values(env, params, policy, width, moves)
        full = jax.vmap(lambda m: exact_value_layered(env, params, apply_move(policy, m), width))(
            moves
        )
        return fast, full

    fast, full = both(policy, moves)
    np.testing.assert_allclose(np.asarray(fast), np.asarray(full), rtol=1e-5, atol=1e-4)
    assert int(jnp.argmax(fast)) == int(jnp.argmax(full)) or np.isclose(
        float(fast.max()), float(full.max()), rtol=1e-6
    )


@pytest.mark.parametrize("name,horizon,discount", [("dectiger", 4, 0.9), ("GridSmall", 3, None)])
def test_one_layer_move_values_equal_full_evaluations(name, horizon, discount):
    """The polish's sweep values (a move in layer t: occupancy up to t, one backup, V_{t+1})
    equal the exact values of the changed controllers, joint moves of identical agents too."""
    model = _model(name, discount)
    env, params = make_tabular(model, horizon, discount)
    _check_move_values(env, params, width=3, seed=2, joint=name == "dectiger")
