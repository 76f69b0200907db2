"""The paired-rollout polish of a kept neural controller (algorithms/weight_polish.py)."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cognet_jax.algorithms.weight_polish import (
    ACTION,
    AXIS,
    AXIS_LEVELS,
    AXIS_MAX_FEATURES,
    AXIS_SHARPNESS,
    COUNTER,
    COUNTER_LEVELS,
    DEFAULT,
    SHIFT,
    SHIFTS,
    START,
    TARGET,
    PolishWork,
    apply_move,
    axis_moves,
    counter_moves,
    counter_table,
    move_table,
    sweep,
)
from cognet_jax.cli import main as cli_main
from cognet_jax.controllers.neural import NeuralPolicy

A, Q, F, H, NA = 2, 3, 1, 2, 4


def tied_policy() -> NeuralPolicy:
    """Every (agent, node) runs the same network: unit 0 votes for node 1 past x = 0.5, unit 1
    for node 2 below x = -1; default vote for node 0; actions 0, 1, 2 per node."""
    w1 = jnp.broadcast_to(jnp.array([[2.0, -1.0]]), (A, Q, F, H))
    b1 = jnp.broadcast_to(jnp.array([-1.0, -1.0]), (A, Q, H))
    w2 = jnp.broadcast_to(jnp.array([[0.0, 5.0, 0.0], [0.0, 0.0, 5.0]]), (A, Q, H, Q))
    b2 = jnp.broadcast_to(jnp.array([3.0, 0.0, 0.0]), (A, Q, Q))
    actions = jnp.broadcast_to(jax.nn.one_hot(jnp.arange(Q), NA), (A, Q, NA))
    params = {"Dense_0": {"kernel": w1, "bias": b1}, "Dense_1": {"kernel": w2, "bias": b2}}
    return NeuralPolicy(action_probs=actions, net_params={"params": params})


def leaves(policy):
    p = policy.net_params["params"]
    return (
        np.asarray(p["Dense_0"]["bias"]),
        np.asarray(p["Dense_1"]["kernel"]),
        np.asarray(p["Dense_1"]["bias"]),
        np.asarray(policy.action_probs),
    )


SCALE = jnp.full((A, F), 0.5)
SUPPORT = jnp.ones((A, NA), bool).at[1, 3].set(False)  # agent 1 lacks action 3


def test_the_table_lists_every_move_of_every_unit_and_node():
    moves = move_table(A, Q, H, NA)
    per_node = H * (len(SHIFTS) + Q - 1) + (NA - 1) + (Q - 1)
    assert moves.shape == (A * Q * per_node, 5)
    assert set(moves[:, 0]) == {SHIFT, TARGET, ACTION, DEFAULT}


def test_axis_moves_are_listed_for_inputs_of_few_features_only_start_moves_for_all():
    plain = move_table(A, Q, H, NA)
    with_axes = move_table(A, Q, H, NA, features=2)
    per_node = 2 * 2 * len(AXIS_LEVELS) * Q  # features x sides x levels x targets
    assert axis_moves(2, Q) == per_node
    starts = (A + 1) * (Q - 1)  # per agent, and every agent at once
    assert len(with_axes) == len(plain) + A * Q * per_node + starts
    assert set(with_axes[:, 0]) == {SHIFT, TARGET, ACTION, DEFAULT, AXIS, START}
    wide = move_table(A, Q, H, NA, features=AXIS_MAX_FEATURES + 1)
    assert len(wide) == len(plain) + starts and AXIS not in wide[:, 0]
    # the COUNTER moves: a table of their own (a sweep of them before the others)
    counters = counter_table(2, Q, H, NA)
    assert len(counters) == counter_moves(2, Q, H, NA) == 2 * len(COUNTER_LEVELS) * 1 * NA * NA
    assert set(counters[:, 0]) == {COUNTER}
    assert counter_moves(1, Q, 1, NA) == 0  # a counter node needs two units
    assert counter_moves(AXIS_MAX_FEATURES + 1, Q, H, NA) == 0


def test_a_counter_move_makes_every_controller_a_tally_of_one_feature():
    """Depth 2 on five nodes: node 0 holds tally 0, node 1 tally +1, node 2 tally -1, nodes 3
    and 4 the ends; steps past +-margin spreads of the feature move the tally, the ends act
    and start again at node 0."""
    q = 5
    policy = tied_policy()
    p = policy.net_params["params"]
    grow = lambda x, axis: jnp.concatenate([x] + [jnp.take(x, jnp.array([0, 1]), axis)], axis)  # noqa: E731
    w1, b1 = grow(p["Dense_0"]["kernel"], 1), grow(p["Dense_0"]["bias"], 1)
    w2 = jnp.zeros((A, q, H, q)).at[:, :, :, :Q].set(grow(p["Dense_1"]["kernel"], 1))
    b2 = jnp.zeros((A, q, q)).at[:, :, :Q].set(grow(p["Dense_1"]["bias"], 1))
    actions = jnp.broadcast_to(jax.nn.one_hot(jnp.array([2, 0, 1, 2, 0]), NA), (A, q, NA))
    params = {"Dense_0": {"kernel": w1, "bias": b1}, "Dense_1": {"kernel": w2, "bias": b2}}
    policy = NeuralPolicy(action_probs=actions, net_params={"params": params})
    center = jnp.full((A, F), 1.0)
    level, depth, hi, lo = COUNTER_LEVELS.index(0.5), 2, 3, 1
    arg = ((0 * len(COUNTER_LEVELS) + level) * 2 + depth - 1) * NA * NA + hi * NA + lo
    moved = apply_move(policy, jnp.array([COUNTER, 0, 0, 0, arg]), SCALE, SUPPORT, center)
    up, down, still = 1.0 + 0.5 * 0.5 + 0.01, 1.0 - 0.5 * 0.5 - 0.01, 1.0 + 0.2
    for agent in range(A):
        assert [node_choice(moved, agent, n, up) for n in range(q)] == [1, 3, 0, 0, 0]
        assert [node_choice(moved, agent, n, down) for n in range(q)] == [2, 0, 4, 0, 0]
        assert [node_choice(moved, agent, n, still) for n in range(q)] == [0, 1, 2, 0, 0]
        played = np.argmax(np.asarray(moved.action_probs[agent]), -1).tolist()
        # node 0's action while counting; agent 1 lacks action 3: its end keeps gathering
        assert played == [2, 2, 2, 3 if agent == 0 else 2, 1]


def node_choice(policy, agent: int, node: int, x: float) -> int:
    """The next node a one-feature policy's ``(agent, node)`` votes for at observation ``x``."""
    p = policy.net_params["params"]
    hidden = jax.nn.relu(
        x * p["Dense_0"]["kernel"][agent, node, 0] + p["Dense_0"]["bias"][agent, node]
    )
    logits = hidden @ p["Dense_1"]["kernel"][agent, node] + p["Dense_1"]["bias"][agent, node]
    return int(jnp.argmax(logits))


def test_an_axis_move_makes_the_weakest_unit_a_threshold_that_outvotes_the_others():
    policy = tied_policy()
    center = jnp.full((A, F), 2.0)
    # feature 0, side +, level 0 (at the mean, x = 2), target node 2: arg ((0*2+0)*L + l)*Q + 2
    level = AXIS_LEVELS.index(0.0)
    moved = apply_move(policy, jnp.array([AXIS, 0, 1, 0, level * Q + 2]), SCALE, SUPPORT, center)
    # unit 1 (spread 0.5 x vote 5) is weaker than unit 0 (1 x 5): it is the one rewritten, in
    # every copy; unit 0 keeps voting for node 1 past x = 0.5
    assert np.array_equal(leaves(moved)[0][..., 0], leaves(policy)[0][..., 0])
    past = 2.0 + 2 * AXIS_SHARPNESS * 0.5  # two sharpness widths past the threshold
    for agent in range(A):
        for node in range(Q):
            assert node_choice(policy, agent, node, past) == 1
            assert node_choice(moved, agent, node, past) == 2
            assert node_choice(moved, agent, node, 1.9) == 1
            assert node_choice(moved, agent, node, -3.0) == node_choice(policy, agent, node, 0.0)
    # without the features' mean (AXIS moves off) the same row changes nothing of that kind
    same = apply_move(policy, jnp.array([SHIFT, 0, 1, 0, 0]), SCALE, SUPPORT, center)
    for got, want in zip(
        leaves(same), leaves(apply_move(policy, jnp.array([SHIFT, 0, 1, 0, 0]), SCALE, SUPPORT))
    ):
        assert np.array_equal(got, want)


@pytest.mark.parametrize("every", [0, 1])
def test_a_start_move_swaps_the_roles_of_node_0_and_another(every):
    policy = tied_policy()
    center = jnp.zeros((A, F))
    moved = apply_move(policy, jnp.array([START, 1, every, 0, 1]), SCALE, SUPPORT, center)
    b1, w2, b2, actions = leaves(moved)
    old_b1, old_w2, old_b2, old_actions = leaves(policy)
    swapped = [0, 1] if every else [1]
    for agent in range(A):
        if agent not in swapped:
            assert np.array_equal(actions[agent], old_actions[agent])
            assert np.array_equal(w2[agent], old_w2[agent])
            continue
        # node 0 now acts as node 2 did and node 2 as node 0; unit 1 votes for node 0 (was 2)
        assert np.argmax(actions[agent], -1).tolist() == [2, 1, 0]
        assert np.allclose(w2[agent, :, 1], [5.0, 0.0, 0.0])
        assert np.allclose(w2[agent, :, 0], [0.0, 5.0, 0.0])
        assert np.allclose(b2[agent], [0.0, 0.0, 3.0])  # the default vote follows node 0's role
        # the same controller from node 2 on: node 0 of the new is node 2 of the old
        for x in (-3.0, 0.0, 2.0):
            old_next = node_choice(policy, agent, 2, x)
            assert node_choice(moved, agent, 0, x) == [2, 1, 0][old_next]


def test_a_shift_moves_every_copy_of_the_unit_by_its_spread():
    policy = tied_policy()
    b1, *_ = leaves(policy)
    i = SHIFTS.index(0.1)
    moved = apply_move(policy, jnp.array([SHIFT, 1, 2, 0, i]), SCALE, SUPPORT)
    b1_new, w2, b2, actions = leaves(moved)
    # |w * scale| = 2 * 0.5 = 1: the bias of unit 0 grows by 0.1 in every agent and node
    assert np.allclose(b1_new[..., 0], b1[..., 0] + 0.1)
    assert np.allclose(b1_new[..., 1], b1[..., 1])
    assert np.array_equal(w2, leaves(policy)[1]) and np.array_equal(actions, leaves(policy)[3])


def test_a_shift_of_an_untied_copy_leaves_the_others():
    policy = tied_policy()
    p = policy.net_params["params"]
    b1 = p["Dense_0"]["bias"].at[0, 1, 0].set(-2.0)  # node 1 of agent 0 has its own unit 0
    policy = policy.replace(net_params={"params": {**p, "Dense_0": {**p["Dense_0"], "bias": b1}}})
    moved = apply_move(policy, jnp.array([SHIFT, 0, 1, 0, 0]), SCALE, SUPPORT)
    new = leaves(moved)[0]
    changed = np.argwhere(new != np.asarray(b1))
    assert changed.tolist() == [[0, 1, 0]]


def test_target_default_and_action_moves_change_what_they_name():
    policy = tied_policy()
    _, w2, b2, actions = leaves(policy)
    _, w2_new, _, _ = leaves(apply_move(policy, jnp.array([TARGET, 0, 0, 0, 0]), SCALE, SUPPORT))
    # unit 0 voted for node 1: its first other node is 2, the vote's strength kept
    assert np.allclose(w2_new[..., 0, :], [0.0, 0.0, 5.0])
    assert np.allclose(w2_new[..., 1, :], w2[..., 1, :])
    _, _, b2_new, _ = leaves(apply_move(policy, jnp.array([DEFAULT, 1, 2, 0, 1]), SCALE, SUPPORT))
    assert np.allclose(b2_new[1, 2], [0.0, 0.0, 3.0])
    assert np.count_nonzero(b2_new != b2) == 2
    # node 2 runs action 2; arg 0 gives action 3, which agent 1 lacks: no change there
    *_, a0 = leaves(apply_move(policy, jnp.array([ACTION, 0, 2, 0, 0]), SCALE, SUPPORT))
    *_, a1 = leaves(apply_move(policy, jnp.array([ACTION, 1, 2, 0, 0]), SCALE, SUPPORT))
    assert np.argmax(a0[0, 2]) == 3 and np.array_equal(a1, actions)


def bias_values(target: float):
    """A stand-in for rollouts: the value of a policy falls with the distance of unit 0's
    bias (agent 0, node 0) from ``target``, the same for every key."""

    def values(key, policies):
        b1 = policies.net_params["params"]["Dense_0"]["bias"]
        return -jnp.abs(b1[:, 0, 0, 0] - target)

    return values


def exact_pair(values, stderr=0.01):
    """``paired`` of ``values``: the differences of the values, with ``stderr``."""

    def paired(key, policy, others):
        stack = jax.tree.map(lambda p, o: jnp.concatenate([p[None], o]), policy, others)
        v = values(key, stack)
        return v[1:] - v[0], jnp.full(v.shape[0] - 1, stderr)

    return paired


def test_a_sweep_applies_the_move_that_gains_most_and_stops_when_none_gains():
    moves = jnp.asarray(move_table(A, Q, H, NA))
    work = PolishWork.start(tied_policy(), jax.random.key(0))
    values = bias_values(-0.6)
    run = jax.jit(lambda w: sweep(w, moves, values, exact_pair(values), SCALE, SUPPORT))
    work = run(work)  # -1.0 -> -0.7 (the largest shift, 0.3)
    assert int(work.applied) == 1
    assert np.isclose(leaves(work.policy)[0][0, 0, 0], -0.7)
    assert np.isclose(float(work.gain), 0.3)
    work = run(work)  # -0.7 -> -0.6
    assert np.isclose(leaves(work.policy)[0][0, 0, 0], -0.6)
    before = leaves(work.policy)
    work = run(work)  # nothing gains: the policy as it was
    assert int(work.applied) == 2 and int(work.sweeps) == 3
    for got, want in zip(leaves(work.policy), before):
        assert np.array_equal(got, want)


def test_the_polish_goes_on_past_its_share_only_while_every_sweep_applies_a_move():
    """``finish_done``: ``polish_sweeps`` sweeps, then more while the last one moved, up to
    ``polish_sweep_cap``."""
    from cognet_jax.algorithms.weight_polish import PolishFinish

    class Fixed(PolishFinish):
        polish_sweeps, polish_sweep_cap = 3, 6

    done = Fixed().finish_done
    work = PolishWork.start(tied_policy(), jax.random.key(0))
    at = lambda n, moved: work.replace(sweeps=jnp.int32(n), moved=jnp.bool_(moved))  # noqa: E731
    assert not done(at(2, False)) and not done(at(2, True))
    assert done(at(3, False)) and not done(at(3, True)) and not done(at(5, True))
    assert done(at(4, False)) and done(at(6, True))


@pytest.mark.parametrize("gain, stderr", [(-0.1, 0.01), (0.1, 0.05)])
def test_a_move_that_does_not_win_clearly_on_the_confirming_rollouts_is_not_applied(gain, stderr):
    """The picking rollouts favour a move; the confirming ones give it ``gain`` +- ``stderr``:
    a loss, or a gain within 2.5 standard errors."""
    moves = jnp.asarray(move_table(A, Q, H, NA))

    def values(key, policies):
        return policies.net_params["params"]["Dense_0"]["bias"][:, 0, 0, 0]

    def paired(key, policy, others):
        return jnp.full(4, gain), jnp.full(4, stderr)

    start = PolishWork.start(tied_policy(), jax.random.key(0))
    work = sweep(start, moves, values, paired, SCALE, SUPPORT)
    assert int(work.applied) == 0 and int(work.sweeps) == 1
    assert np.array_equal(leaves(work.policy)[0], leaves(tied_policy())[0])


POLISHED_RUN = [
    "--set",
    "algorithm.iterations=20",
    "--set",
    "algorithm.candidates=64",
    "--set",
    "algorithm.eval_rollouts=100",
    "--set",
    "algorithm.elites=8",
    "--set",
    "algorithm.best_rollouts=50",
    "--set",
    "algorithm.polish_share=1.0",
    "--set",
    "evaluation.rollouts=2000",
    "--set",
    "run.plots=false",
    "--no-progress",
]


def test_a_run_records_its_polish_and_evaluate_gives_the_polished_policys_value(tmp_path, capsys):
    out = tmp_path / "run"
    code = cli_main(["train", "tagging-thesis-n3", "--seed", "1", "--out", str(out)] + POLISHED_RUN)
    assert code == 0
    results = json.loads((out / "results.json").read_text())
    polish = results["finish"]
    # 624 one-entry moves, 2 agents x 3 nodes x 42 AXIS moves (one feature), 3 x 2 START
    # moves; 20 x 64 x 100 rollouts over (882 moves + 1 + 10 x 5) x 50 per sweep: 2 sweeps,
    # 5 while each moves; before them a sweep of the 7 margins x 3 x 3 end actions of COUNTER
    # moves of depth 1
    assert polish["moves_per_sweep"] == 624 + 2 * 3 * axis_moves(1, 3) + 3 * 2 == 882
    assert polish["counter_moves"] == counter_moves(1, 3, 2, 3) == 63
    sweeps_cost = polish["sweeps"] * (882 + 1 + 50) * 50
    assert polish["rollouts"] == sweeps_cost + (63 + 1 + 50) * 50
    assert polish["sweeps"] == min(5, max(2, polish["moves_applied"] + 1))
    assert "polish:" in capsys.readouterr().out
    assert cli_main(["evaluate", str(out), "--rollouts", "2000"]) == 0
    shown = capsys.readouterr().out
    assert f"{results['final_value']['mean']:.3f}" in shown
