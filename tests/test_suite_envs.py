"""The continuous-observation suite (issue 52): each simulator's step against an independent
plain-numpy re-statement on random states and actions, its hand-written controller's rule, the
grid search, and the upper bounds."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.special import ndtri
from shared_files import SUITE_EXPERIMENTS

from cognet_jax import baselines
from cognet_jax.envs import beacon, bearing_chase, box_push, hearing_tiger, plume
from cognet_jax.registry import env_entry, load_config

RNG = np.random.default_rng(0)
MOVES = [(0, 0), (1, 0), (-1, 0), (0, 1), (0, -1)]


def _normal(u):
    return ndtri(np.clip(u, 1e-7, 1 - 1e-7))


def _close(a, b):
    np.testing.assert_allclose(np.asarray(a, np.float64), np.asarray(b, np.float64), atol=1e-4)


def test_hearing_tiger_step_is_dec_tiger_with_gaussian_hearing():
    env, params = hearing_tiger.HearingTiger(), hearing_tiger.TigerParams(hearing_std=0.7)
    step = jax.jit(env.step)
    table = {  # (tiger, a0, a1) -> reward, written out from MADP's dectiger
        (0, 0, 0): -2, (0, 0, 1): -101, (0, 0, 2): 9, (0, 1, 1): -50, (0, 2, 2): 20,
        (0, 1, 2): -100, (1, 0, 1): 9, (1, 0, 2): -101, (1, 1, 1): 20, (1, 2, 2): -50,
    }  # fmt: skip
    for (tiger, a0, a1), r in table.items():
        for actions in ((a0, a1), (a1, a0)):
            u = RNG.uniform(size=3).astype(np.float32)
            nxt, obs, reward = step(u, jnp.int32(tiger), jnp.array(actions), params)
            assert float(reward) == r
            listened = actions == (0, 0)
            want_tiger = tiger if listened else int(u[0] >= 0.5)
            assert int(nxt) == want_tiger
            side = (1.0 if want_tiger else -1.0) if listened else 0.0
            _close(obs, side + 0.7 * _normal(u[1:]))


def test_hearing_tiger_counting_controller_opens_away_from_the_tiger():
    env = hearing_tiger.HearingTiger()
    ctrl, policy = hearing_tiger.hand_controller(env, count=2, margin=0.5)
    step = jax.jit(ctrl.next_node)
    nodes = jnp.zeros(2, jnp.int32)
    for z, want in [(0.9, 1), (0.2, 1), (0.8, 3), (0.0, 0)]:  # right, nothing, right: open-left
        nodes = step(None, policy, nodes, jnp.full(2, z, jnp.float32))
        assert nodes.tolist() == [want, want]
    assert ctrl.act(None, policy, jnp.array([3, 4])).tolist() == [1, 2]
    nodes = jnp.zeros(2, jnp.int32)
    for z, want in [(-0.9, 2), (0.9, 0), (-2.0, 2), (-1.0, 4)]:
        nodes = step(None, policy, nodes, jnp.full(2, z, jnp.float32))
        assert nodes.tolist() == [want, want]


def test_beacon_step_against_numpy():
    env = beacon.Beacon(num_agents=3)
    params = beacon.BeaconParams(obs_noise=0.4, motion_noise=0.2)
    for _ in range(20):
        agents = RNG.uniform(0, 10, (3, 2)).astype(np.float32)
        b = RNG.uniform(0, 10, 2).astype(np.float32)
        actions = RNG.integers(0, 5, 3)
        u = RNG.uniform(size=12).astype(np.float32)
        state = beacon.BeaconState(jnp.asarray(agents), jnp.asarray(b))
        nxt, obs, reward = jax.jit(env.step)(u, state, jnp.asarray(actions), params)
        want_r = sum(np.linalg.norm(a - b) <= 1.0 for a in agents)
        moved = agents + np.array([MOVES[a] for a in actions]) + 0.2 * _normal(u[:6]).reshape(3, 2)
        moved = np.clip(moved, 0, 10)
        assert float(reward) == want_r
        _close(nxt.agents, moved)
        _close(obs, b - moved + 0.4 * _normal(u[6:]).reshape(3, 2))


def test_bearing_chase_step_against_numpy():
    env, params = bearing_chase.BearingChase(), bearing_chase.ChaseParams()
    for _ in range(20):
        agents = RNG.uniform(0, 10, (2, 2)).astype(np.float32)
        target = RNG.uniform(0, 10, 2).astype(np.float32)
        heading = np.float32(RNG.uniform(-np.pi, np.pi))
        actions = RNG.integers(0, 5, 2)
        u = RNG.uniform(size=3).astype(np.float32)
        state = bearing_chase.ChaseState(jnp.asarray(agents), jnp.asarray(target), heading)
        nxt, obs, reward = jax.jit(env.step)(u, state, jnp.asarray(actions), params)
        near = [np.linalg.norm(a - target) <= 1.5 for a in agents]
        assert float(reward) == sum(near) + (1.0 if all(near) else 0.0)
        moved = np.clip(agents + np.array([MOVES[a] for a in actions]), 0, 10)
        h = heading + 0.3 * _normal(u[0])
        pos = target + 0.5 * np.array([math.cos(h), math.sin(h)])
        pos = np.where(pos < 0, -pos, np.where(pos > 10, 20 - pos, pos))
        _close(nxt.target, pos)
        bearing = np.arctan2(pos[1] - moved[:, 1], pos[0] - moved[:, 0]) + 0.3 * _normal(u[1:])
        want = np.angle(np.exp(1j * bearing))  # wrapped to (-pi, pi]
        diff = np.angle(np.exp(1j * (np.asarray(obs, np.float64) - want)))
        assert np.all(np.abs(diff) < 1e-4) and np.all(np.abs(obs) <= math.pi + 1e-6)


def test_plume_step_against_numpy():
    env, params = plume.Plume(), plume.PlumeParams(obs_noise=0.1, spread=2.0)
    for _ in range(20):
        agents = RNG.integers(0, 10, (2, 2))
        source = RNG.integers(0, 10, 2)
        actions = RNG.integers(0, 5, 2)
        u = RNG.uniform(size=18).astype(np.float32)
        state = plume.PlumeState(jnp.asarray(agents, jnp.int32), jnp.asarray(source, jnp.int32))
        nxt, obs, reward = jax.jit(env.step)(u, state, jnp.asarray(actions), params)
        assert float(reward) == sum(np.array_equal(a, source) for a in agents)
        moved = np.clip(agents + np.array([MOVES[a] for a in actions]), 0, 9)
        np.testing.assert_array_equal(np.asarray(nxt.agents), moved)
        noise = 0.1 * _normal(u).reshape(2, 9)
        for i, (x, y) in enumerate(moved):
            for k, (dx, dy) in enumerate((dx, dy) for dx in (-1, 0, 1) for dy in (-1, 0, 1)):
                cx, cy = x + dx, y + dy
                inside = 0 <= cx < 10 and 0 <= cy < 10
                d2 = (cx - source[0]) ** 2 + (cy - source[1]) ** 2
                clean = math.exp(-d2 / 8.0) if inside else 0.0
                assert abs(float(obs[i, k]) - (clean + noise[i, k])) < 1e-4


def test_box_push_step_against_numpy():
    env, params = box_push.BoxPush(), box_push.BoxPushParams(motion_noise=0.3)
    cases = 0
    for _ in range(60):
        box = np.float32(RNG.uniform(0, 10))
        agents = np.clip(box + RNG.uniform(-2, 2, 2), 0, 10).astype(np.float32)
        actions = RNG.integers(0, 3, 2)
        u = RNG.uniform(size=5).astype(np.float32)
        state = box_push.BoxPushState(jnp.asarray(agents), jnp.asarray(box))
        nxt, obs, reward = jax.jit(env.step)(u, state, jnp.asarray(actions), params)
        reach = np.abs(agents - box) <= 1.0
        push = actions == 2
        delivered = bool(np.all(push & reach))
        each = np.where(push, np.where(reach, -1.0, -5.0), -0.5)
        assert float(reward) == (20.0 if delivered else each.sum())
        moved = agents + np.where(actions == 0, -1, np.where(actions == 1, 1, 0))
        moved = np.clip(moved + 0.3 * _normal(u[:2]), 0, 10)
        new_box = u[2] * 10 if delivered else box
        _close(nxt.agents, moved)
        _close(obs, new_box - moved + 1.0 * _normal(u[3:]))
        cases += delivered
    assert cases > 0  # the joint push was exercised


def test_plume_bound_by_brute_force_on_a_small_grid():
    env = plume.Plume(horizon=3, size=3)
    total = 0.0
    for start in np.ndindex(3, 3):
        for source in np.ndindex(3, 3):
            d = abs(start[0] - source[0]) + abs(start[1] - source[1])
            total += max(0, 3 - d)
    assert plume.upper_bound(env) == pytest.approx(2 * total / 81)


@pytest.mark.parametrize("name", ["hearing-tiger", "beacon", "bearing-chase", "plume", "box-push"])
def test_grid_search_keeps_the_best_point_and_stays_below_the_bound(name):
    entry = env_entry(name)
    env, params = entry.build(entry.section(), None)
    tuned = baselines.tune(name, env, params, rollouts_per_point=500)
    values = [v for _, v in tuned.values]
    assert len(values) == np.prod([len(v) for v in tuned.grid.values()])
    assert dict(tuned.values[int(np.argmax(values))][0]) == tuned.best
    assert max(values) > min(values)  # the thresholds matter
    bound = {
        "hearing-tiger": lambda: hearing_tiger.upper_bound(env.horizon, 1.0),
        "beacon": lambda: sum(beacon.upper_bound(env, params, samples=20_000)),
        "plume": lambda: plume.upper_bound(env),
    }.get(name)
    if bound is not None:
        assert tuned.honest[0] <= bound()


@pytest.mark.parametrize("experiment", SUITE_EXPERIMENTS)
def test_suite_experiments_set_only_env_and_nodes(experiment):
    from cognet_jax.config import read_experiment

    data = read_experiment(experiment)
    assert set(data) == {"experiment", "env", "algorithm"}
    assert set(data["algorithm"]) == {"nodes"}
    load_config(experiment)  # valid
