"""The benchmark-model generators of experiments/models.py: box pushing gives MADP's lines
(those quoted below are verbatim lines of MADP's ``boxPushingUAI07.dpomdp``), fire fighting
reproduces the published optimum at horizon 2 with MADP's rounding, and both parse."""

import importlib.util
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from shared_files import as_a_user

from cognet_jax.exact import brute_force_optimum
from cognet_jax.io.dpomdp import parse_dpomdp

PATH = Path(__file__).resolve().parents[1] / "experiments" / "models.py"


@pytest.fixture(scope="module")
def models():
    spec = importlib.util.spec_from_file_location("models", PATH)
    module = importlib.util.module_from_spec(spec)
    sys.modules["models"] = module
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def box(models):
    return parse_dpomdp(models.box_pushing())


def _row(model, s, a1, a2):
    ja = model.joint_action_index([a1, a2])
    row = model.transition[s, ja]
    return {int(k): round(float(row[k]), 6) for k in np.flatnonzero(row)}, model.reward[s, ja]


@pytest.mark.parametrize(
    "s,actions,row,reward",
    [
        # both enter the same empty cell; only one succeeding moves it
        (23, (2, 2), {19: 0.09, 23: 0.82, 63: 0.09}, -10.2),
        (17, (2, 2), {17: 0.1, 21: 0.9}, -5.2),  # the follower is blocked
        (19, (2, 2), {19: 1.0}, -10.2),  # facing each other
        (15, (2, 0), {0: 0.9, 14: 0.09, 15: 0.01}, 9.8),  # a small box, the other turns
        (53, (2, 3), {53: 1.0}, -5.2),  # the large box alone
        (52, (2, 2), {3: 0.81, 52: 0.19}, 99.8),  # the large box together
        (12, (2, 2), {0: 0.09, 1: 0.09, 2: 0.81, 12: 0.01}, 19.8),  # both small boxes
        (39, (2, 3), {39: 1.0}, -5.2),  # facing south
        (27, (2, 2), {23: 0.09, 27: 0.01, 63: 0.81, 67: 0.09}, -0.2),  # the start state
        (3, (1, 2), {27: 1.0}, 0.0),  # a pushed box: the episode begins again
        (67, (2, 2), {63: 0.09, 67: 0.82, 90: 0.09}, -10.2),  # MADP's odd line (rules: 91)
    ],
)
def test_box_pushing_gives_madps_lines(box, s, actions, row, reward):
    got_row, got_reward = _row(box, s, *actions)
    assert got_row == row
    assert got_reward == pytest.approx(reward, abs=1e-5)


def test_box_pushing_header_observations_and_rules_only_variant(box, models):
    assert box.transition.shape == (100, 16, 100) and box.observation.shape == (16, 100, 25)
    assert box.initial_belief[27] == 1.0 and box.discount == 1.0
    sees = {s: int(np.argmax(box.observation[0, s])) for s in (0, 11, 14, 53, 57, 90, 91)}
    # joint observation index = 5 * o1 + o2 (MADP's lines 'O: .. : s' : o1 o2 : 1.0')
    assert sees == {0: 0, 11: 15, 14: 16, 53: 20, 57: 21, 90: 11, 91: 12}
    rules = parse_dpomdp(models.box_pushing(madp_quirk=False))
    assert _row(rules, 67, 2, 2)[0] == {63: 0.09, 67: 0.82, 91: 0.09}


def test_fire_fighting_reproduces_the_published_horizon_2_optimum(models):
    """Fire fighting 2 agents, 3 houses, 3 levels: 432 states (the positions are part of the
    state, as in MADP's file); with MADP's two-decimal rounding the optimum at horizon 2 is
    the published -4.383496 (Oliehoek et al.; masplan)."""
    rounded = parse_dpomdp(models.fire_fighting(3, 3, madp_rounding=True))
    assert rounded.transition.shape == (432, 9, 432)
    assert rounded.initial_belief.sum() == pytest.approx(1.0)
    assert np.count_nonzero(rounded.initial_belief) == 27
    assert brute_force_optimum(rounded, 2).value == pytest.approx(-4.383496, abs=1e-6)
    exact = parse_dpomdp(models.fire_fighting(3, 3))
    assert brute_force_optimum(exact, 2).value == pytest.approx(-4.383579, abs=1e-6)


def test_fire_fighting_four_houses_is_the_2025_state_model(models):
    text = models.fire_fighting(4, 3)
    states = next(line for line in text.splitlines() if line.startswith("states:"))
    assert len(states.split()) == 1 + 2025
    with pytest.raises(ValueError, match="sum to 1.02"):
        models.fire_fighting(4, 3, madp_rounding=True)


#: runs ``cognet-jax`` (as its ``cli.run`` does) and prints the process's own peak RSS
#: (``VmHWM``, KiB) on stderr: the parent's ``ru_maxrss`` of a child counts the memory of the
#: process it was forked from
PEAK_RSS = (
    "import sys; from cognet_jax.cli import main, set_up_process; "
    "set_up_process(); code = main(sys.argv[1:]); "
    "hwm = [l for l in open('/proc/self/status') if l.startswith('VmHWM')][0].split()[1]; "
    "print('peak-rss-kib', hwm, file=sys.stderr); sys.exit(code)"
)


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs Linux /proc")
def test_tiny_run_on_the_2025_state_model_is_quick_and_small(models, tmp_path):
    """Issue 33's case: ``cognet-jax train gdice-dpomdp`` on the 2025-state fire fighting model
    with 2 iterations of 20 samples, in a fresh process with the default compilation-cache
    settings (a fresh folder), parse included: at most 60 s wall and 1 GB peak RSS (the dense
    transition table is neither copied into every program nor kept beside its sparse rows)."""
    model = tmp_path / "ff243.dpomdp"
    model.write_text(models.fire_fighting(4, 3))
    args = ["train", "gdice-dpomdp", "--set", f"problem.path={str(model)!r}"]
    args += ["--set", "algorithm.iterations=2", "--set", "algorithm.samples=20"]
    args += ["--set", "run.plots=false", "--out", str(tmp_path / "run"), "--no-progress"]
    root = Path(__file__).resolve().parents[1]
    env = as_a_user(dict(os.environ))  # as a user's run compiles (conftest.py)
    env.update(JAX_COMPILATION_CACHE_DIR=str(tmp_path / "cache"), PYTHONPATH=str(root))
    t0 = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-c", PEAK_RSS, *args], env=env, capture_output=True, text=True
    )
    wall = time.perf_counter() - t0
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert wall <= 60, wall
    peak = int(next(x for x in proc.stderr.splitlines() if x.startswith("peak-rss-kib")).split()[1])
    assert peak <= 2**20, f"peak RSS {peak / 2**10:.0f} MB"  # KiB
    record = json.loads((tmp_path / "run" / "results.json").read_text())
    # one polish sweep of this model at h 3 costs 1.5e9 multiply-adds, within
    # POLISH_SWEEP_LIMIT: the polish runs, within its budget (tests/test_polish.py): the
    # exact evaluations of the search's 2 x 20 samples at most
    finish = record["finish"]
    assert finish is not None and finish["exact_evaluations"] <= finish["budget"], finish


def test_mars_rovers_sizes_rows_and_the_horizon_1_optimum(models):
    """Mars rovers as MADP's ``Mars`` file: 256 states, 6 actions and 8 observations per agent;
    every transition row sums to 1; the rovers start together on drill site 0, so at horizon 1
    the best joint action is both drilling, worth 6 (the published optimum at horizon 2, 5.80,
    is that and two moves at -0.1 each); the last site done sends the rovers back to state 0."""
    mars = parse_dpomdp(models.mars_rovers())
    assert mars.transition.shape == (256, 36, 256)
    assert mars.observation.shape[-1] == 64
    np.testing.assert_allclose(mars.transition.sum(-1), 1.0, atol=1e-9)
    assert np.flatnonzero(mars.initial_belief).tolist() == [0]
    assert brute_force_optimum(mars, 1).value == pytest.approx(6.0, abs=1e-9)
    drill = mars.joint_action_index([4, 4])
    assert mars.reward[0, drill] == 6.0  # both on drill site 0, nothing done
    assert mars.reward[64 + 16, drill] == 0.0  # both drilling sample site 1
    assert mars.reward[64 + 16 + 0b0010, drill] == -2.0  # ... once it is done
    last_site_left = 64 * 1 + 16 * 2 + 0b1011  # rovers on cells 1 and 2; only site 2 not done
    row = mars.transition[last_site_left, mars.joint_action_index([0, 5])]
    assert np.flatnonzero(row).tolist() == [0]  # the last site done: state 0 again
    down = mars.transition[0, mars.joint_action_index([1, 0])]
    assert down[64] == pytest.approx(0.9) and down[0] == pytest.approx(0.1)  # bit 0: the row


def test_meeting_grid_rewards_only_the_two_corners(models):
    """Meeting in a 3 x 3 grid as MADP's ``Grid3x3corners`` file: 81 states, 5 actions and 9
    observations per agent (its own cell), reward 1 when both share the top-left or
    bottom-right corner; a move goes its way with 0.6 and each other way, or nowhere, with 0.1;
    from the other two corners nobody meets within 2 steps (optimum 0 at horizon 2, the
    published value)."""
    grid = parse_dpomdp(models.meeting_grid())
    assert grid.transition.shape == (81, 25, 81)
    np.testing.assert_allclose(grid.transition.sum(-1), 1.0, atol=1e-9)
    assert {int(s) for s in np.flatnonzero(grid.reward.max(1))} == {0, 80}
    assert brute_force_optimum(grid, 1).value == 0.0
    assert int(np.argmax(grid.initial_belief)) == 9 * 2 + 6
    assert models.grid_outcomes(4, 0) == pytest.approx({4: 0.1, 1: 0.6, 7: 0.1, 3: 0.1, 5: 0.1})
    assert models.grid_outcomes(0, 0) == pytest.approx({0: 0.8, 3: 0.1, 1: 0.1})
