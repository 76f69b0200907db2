"""Exact polish of G-DICE's best controller (``cognet_jax.algorithms.polish``)."""

from __future__ import annotations

import dataclasses
import json

import jax
import numpy as np
import pytest
from shared_files import dpomdp_file as _file

from cognet_jax.algorithms.engine import SearchParams, ThresholdHyper
from cognet_jax.algorithms.gdice_portfolio import GDicePortfolio
from cognet_jax.algorithms.gdice_search import GDice, GDiceSettings
from cognet_jax.algorithms.polish import apply_move, neighbour_moves
from cognet_jax.controllers.tabular import TabularController
from cognet_jax.envs.tabular import make_tabular
from cognet_jax.exact import exact_value as exact_numpy
from cognet_jax.io.dpomdp import parse_dpomdp


def test_moves_cover_every_single_entry_change_of_a_layered_controller():
    ctrl = TabularController(2, 6, 3, 2, layers=3, action_counts=(3, 2))
    moves = neighbour_moves(ctrl, (3, 2), (2, 1), joint_moves=False)
    actions = moves[moves[:, 0] == 0]
    assert len(actions) == 6 * 3 + 6 * 2  # every node, each agent's own actions
    trans = moves[moves[:, 0] == 1]
    # layers 0 and 1 (2 nodes each) move to the 2 nodes of the next layer; none from layer 2
    assert len(trans) == 4 * 2 * 2 + 4 * 1 * 2
    assert np.all(trans[:, 4] // 2 == trans[:, 2] // 2 + 1)
    joint = neighbour_moves(ctrl, (3, 3), (2, 2), joint_moves=True)
    assert (joint[:, 1] == -1).sum() == len(joint) // 3


def test_apply_move_changes_exactly_one_entry_or_every_agents():
    ctrl = TabularController(2, 4, 3, 2)
    policy = ctrl.sample(jax.random.key(0), ctrl.init_distribution())
    new = apply_move(policy, np.array([0, 1, 2, 0, 2], np.int32))
    diff = np.asarray(new.actions) != np.asarray(policy.actions)
    assert diff.sum() <= 1 and int(new.actions[1, 2]) == 2
    np.testing.assert_array_equal(new.transitions, policy.transitions)
    both = apply_move(policy, np.array([1, -1, 3, 1, 0], np.int32))
    assert np.all(np.asarray(both.transitions)[:, 3, 1] == 0)
    np.testing.assert_array_equal(both.actions, policy.actions)


def _search(name: str, horizon: int, **kw):
    model = parse_dpomdp(_file(name), discount=1.0)
    env, env_params = make_tabular(model, horizon)
    kw = {"polish_budget": 1e9, **kw}  # these tests are about the polish, not its budget
    settings = GDiceSettings(
        nodes=2, iterations=3, samples=32, elites=4, evaluator="exact", layered=True, **kw
    )
    return model, env, SearchParams(env_params, ThresholdHyper()), settings


def test_polish_reaches_a_local_optimum_and_reports_its_exact_value():
    """From a poor controller, polish climbs to one that no single move improves; the value
    it reports is the float64 exact value of the policy it returns."""
    model, env, params, settings = _search("dectiger", 3, polish_sweeps=50)
    algo = GDice(env, settings)
    state = algo.init(jax.random.key(1), params)  # a random controller, never searched
    state, info = jax.jit(algo.finish)(state, params)
    best = jax.device_get(state.best_policy)
    value = exact_numpy(model, best.actions, best.transitions, 3, 1.0)
    assert float(info.after) == pytest.approx(value, abs=1e-4)
    assert float(info.after) > float(info.before) + 1.0 and int(info.moves_applied) > 0
    assert int(info.moves_applied) < 50  # stopped because nothing improves, not by the limit
    moves = neighbour_moves(algo.controller, env.action_counts, env.obs_counts, True)
    neighbours = jax.vmap(lambda m: apply_move(state.best_policy, m))(moves)
    assert float(np.max(algo.exact_values(neighbours, params))) <= value + 1e-4


def test_polish_off_by_default_and_with_rollout_values():
    _, env, params, settings = _search("dectiger", 3)
    assert not GDice(env, settings).polishes
    rollouts = dataclasses.replace(settings, polish_sweeps=5, evaluator="rollouts")
    algo = GDice(env, rollouts)
    state = algo.init(jax.random.key(0), params)
    assert algo.finish(state, params) == (state, None)


def test_portfolio_polish_never_lowers_the_best_value():
    _, env, params, settings = _search("dectiger", 3, polish_sweeps=3)
    algo = GDicePortfolio(env, settings, shared_restarts=1)
    state = algo.init(jax.random.key(2), params)
    state, _ = jax.jit(algo.step)(jax.random.key(3), state, params)
    before = float(state.progress.in_loop_best)
    # what each member search's best polishes to on its own
    search, polish = algo._polish()
    alone = [
        float(
            search.polish_policy(
                jax.tree.map(lambda x, i=i: x[i], m.best_policy), params, polish
            ).value
        )
        for m in state.members
        for i in range(m.progress.in_loop_best.shape[0])
    ]
    finished, info = jax.jit(algo.finish)(state, params)
    value = float(finished.progress.in_loop_best)
    assert value >= before - 1e-6
    assert int(info.moves_applied) <= 3 and info.moves_per_sweep == len(search.polish_moves())
    # the kept policy is the best polished one, and its exact value is the reported one
    assert value == pytest.approx(max(max(alone), before), abs=1e-5)
    exact = float(search.exact_value_of(finished.best_policy, params))
    assert exact == pytest.approx(value, abs=1e-5)


def _polished() -> list[str]:
    """A small G-DICE run on Dec-Tiger whose polish has room for several sweeps."""
    return [
        f"problem.path={str(_file('dectiger'))!r}",
        "problem.horizon=2",
        "algorithm.iterations=3",
        "algorithm.samples=50",
        "algorithm.polish_sweeps=5",
        "algorithm.polish_budget=1000",
        "algorithm.repeats=1",  # the record, not the search, is under test
    ]


def test_train_and_sweep_record_the_polish(tmp_path):
    from cognet_jax.driver import train
    from cognet_jax.registry import load_config
    from cognet_jax.sweep import run_sweep

    sets = [*_polished(), "run.progress=false", "run.plots=false", "evaluation.rollouts=1000"]
    train(load_config("gdice-dpomdp", sets), 0, tmp_path / "train", log=lambda *_: None)
    # (the next test's Program.init and finish are these programs, compiled once)
    results = json.loads((tmp_path / "train" / "results.json").read_text())
    polish = results["finish"]
    assert polish["value_after"] >= polish["value_before"] - 1e-6
    assert results["final_value"]["exact"] == pytest.approx(polish["value_after"], abs=1e-4)
    out = run_sweep("gdice-dpomdp", [0, 1], overrides=sets, log=lambda *_: None)
    for row in out["rows"]:
        assert row["final_value"]["exact"] == pytest.approx(row["finish"]["value_after"], abs=1e-4)


def test_polish_budget_bounds_the_exact_evaluations():
    """The polish spends at most ``polish_budget`` times the search's evaluations: below one
    sweep it does nothing; with room for k sweeps it does at most k, and says what it spent."""
    _, env, params, settings = _search("dectiger", 3, polish_sweeps=50)
    algo = GDice(env, settings)
    state = algo.init(jax.random.key(1), params)  # a random controller: every sweep improves
    moves = len(algo.polish_moves())
    evaluations = settings.iterations * settings.samples  # what the search valued: 96
    assert moves > evaluations  # so the default budget (1.0) allows no sweep at all
    for factor, sweeps in ((1.0, 0), (2 * moves / evaluations, 1), (3.5 * moves / evaluations, 3)):
        tight = GDice(env, dataclasses.replace(settings, polish_budget=factor))
        assert tight.polish_budget() == int(factor * evaluations)
        finished, info = jax.jit(tight.finish)(state, params)
        assert int(info.evaluations) == 1 + sweeps * moves <= info.budget
        assert int(info.moves_applied) == sweeps  # each sweep from a random controller improves
    # the budget of a portfolio is shared by its candidates
    portfolio = GDicePortfolio(
        env, dataclasses.replace(settings, polish_budget=10.0), shared_restarts=1
    )
    _, polish = portfolio._polish()
    assert polish.budget == 10 * evaluations * 2 // 3  # 2 searches' worth for 3 candidates


def test_finish_as_steps_equals_finish_in_one_loop():
    """The driver's ``finish`` (steps from the host, a progress report after each) gives what
    the algorithm's ``finish`` (one ``while_loop``, ``make_train``) gives."""
    from cognet_jax.program import Program, Run
    from cognet_jax.registry import load_config

    config = load_config("gdice-dpomdp", _polished())  # the test above's search
    program = Program([Run(config=config, seed=0, setting=0)])
    state = program.init()
    reports = []
    stepped, info = program.finish(state, reports.append)
    looped, info2 = jax.jit(lambda s: program.algorithm.finish(s, program.params))(state)
    assert len(reports) >= 2 and int(info.moves_applied) > 0 and int(info.responses_applied) >= 0
    for a, b in zip(
        jax.tree.leaves((stepped, info)), jax.tree.leaves((looped, info2)), strict=True
    ):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
