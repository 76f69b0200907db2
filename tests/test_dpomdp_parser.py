"""Tests of the MADP .dpomdp parser (SPEC section 7.3)."""

from __future__ import annotations

import gzip
import random
import re
import time
from pathlib import Path

import numpy as np
import pytest

from cognet_jax.io.dpomdp import DpomdpParseError, TabularModel, load_dpomdp, parse_dpomdp

DPOMDP_DIR = Path(__file__).resolve().parents[2] / "shared" / "dpomdp"
FILES = ["dectiger", "broadcastChannel", "recycling", "GridSmall"]


@pytest.fixture(scope="module")
def dpomdp_dir() -> Path:
    if not DPOMDP_DIR.is_dir():
        pytest.skip(f"benchmark files not found at {DPOMDP_DIR}")
    return DPOMDP_DIR


def _model(dpomdp_dir: Path, name: str) -> TabularModel:
    return parse_dpomdp(dpomdp_dir / f"{name}.dpomdp")


# --------------------------------------------------------------------------------------------
# The four benchmark files

EXPECTED = {
    # name: (|S|, action counts, obs counts, discount, b0)
    "dectiger": (2, (3, 3), (2, 2), 1.0, [0.5, 0.5]),
    "broadcastChannel": (4, (2, 2), (2, 2), 1.0, [0, 0, 0, 1]),
    "recycling": (4, (3, 3), (2, 2), 0.9, [1, 0, 0, 0]),
    "GridSmall": (16, (5, 5), (2, 2), 0.9, np.eye(16)[6]),
}


@pytest.mark.parametrize("name", FILES)
def test_benchmark_files_parse(dpomdp_dir, name):
    m = _model(dpomdp_dir, name)
    nS, ac, oc, gamma, b0 = EXPECTED[name]
    assert m.num_agents == 2 and m.num_states == nS
    assert m.action_counts == ac and m.obs_counts == oc
    assert m.num_joint_actions == ac[0] * ac[1] and m.num_joint_obs == oc[0] * oc[1]
    assert m.discount == gamma
    np.testing.assert_allclose(m.initial_belief, b0)
    assert m.transition.shape == (nS, m.num_joint_actions, nS)
    assert m.observation.shape == (m.num_joint_actions, nS, m.num_joint_obs)
    assert m.reward.shape == (nS, m.num_joint_actions)
    for arr in (m.transition, m.observation, m.reward, m.initial_belief):
        assert arr.dtype == np.float64 and not arr.flags.writeable
    np.testing.assert_allclose(m.transition.sum(-1), 1.0, atol=1e-9)
    np.testing.assert_allclose(m.observation.sum(-1), 1.0, atol=1e-9)
    assert m.source.endswith(f"{name}.dpomdp")


def test_dectiger_entries(dpomdp_dir):
    m = _model(dpomdp_dir, "dectiger")
    assert m.state_names == ("tiger-left", "tiger-right")
    assert m.action_names == (("listen", "open-left", "open-right"),) * 2
    assert m.observation_names == (("hear-left", "hear-right"),) * 2
    ll = m.joint_action_index(["listen", "listen"])
    assert ll == 0 and m.joint_action_index([1, 2]) == 1 * 3 + 2
    np.testing.assert_allclose(m.reward[:, ll], [-2, -2])
    tl, tr = 0, 1
    ol_ol = m.joint_action_index(["open-left", "open-left"])
    assert m.reward[tl, ol_ol] == -50 and m.reward[tr, ol_ol] == 20
    assert m.reward[tl, m.joint_action_index(["listen", "open-left"])] == -101
    assert m.reward[tr, m.joint_action_index(["open-left", "listen"])] == 9
    assert m.reward[tl, m.joint_action_index(["open-left", "open-right"])] == -100
    # listening: identity transition, 0.85 per-agent accuracy
    np.testing.assert_array_equal(m.transition[:, ll, :], np.eye(2))
    hl_hl = m.joint_obs_index(["hear-left", "hear-left"])
    assert m.observation[ll, tl, hl_hl] == pytest.approx(0.7225)
    hl_hr = m.joint_obs_index(["hear-left", "hear-right"])
    assert hl_hr == 1 and m.split_joint_obs(hl_hr) == (0, 1)
    agent0_hears_left = m.observation[ll, tl].reshape(2, 2).sum(1)[0]
    assert agent0_hears_left == pytest.approx(0.85)
    # opening resets: uniform transition and uninformative observations
    np.testing.assert_allclose(m.transition[:, ol_ol, :], 0.5)
    np.testing.assert_allclose(m.observation[ol_ol], 0.25)


def test_broadcast_entries(dpomdp_dir):
    m = _model(dpomdp_dir, "broadcastChannel")
    assert m.state_names == ("S00", "S01", "S10", "S11")
    send_send = m.joint_action_index(["send", "send"])
    wait_send = m.joint_action_index(["wait", "send"])
    s10 = m.state_names.index("S10")
    np.testing.assert_allclose(m.transition[:, send_send, s10], 0.81)
    # O: the wildcard line is overwritten for (send, send) only
    cc = m.joint_obs_index(["Collision", "Collision"])
    assert m.observation[send_send, 2, cc] == pytest.approx(0.81)
    assert m.observation[wait_send, 2, cc] == pytest.approx(0.01)
    assert m.reward[m.state_names.index("S01"), wait_send] == 1
    assert m.reward[m.state_names.index("S10"), wait_send] == 0


def test_recycling_counts_are_names(dpomdp_dir):
    m = _model(dpomdp_dir, "recycling")
    assert m.state_names == ("0", "1", "2", "3")
    assert m.observation_names == (("0", "1"), ("0", "1"))
    assert m.action_names[0] == ("searchbig", "searchlittle", "waitandrecharge")
    assert m.reward[0, m.joint_action_index([2, 2])] == 5.0
    assert m.reward[3, m.joint_action_index([1, 2])] == -3.88
    assert m.transition[1, m.joint_action_index([1, 1]), 3] == pytest.approx(0.24)
    assert m.reward[0, 0] == 0.0  # never set


def test_gridsmall_rewards_from_end_states(dpomdp_dir):
    """GridSmall gives R only as 'R: * : * : s' : * : 1': R(s, ja) = sum_{s' meet} T(s'|s,ja)."""
    m = _model(dpomdp_dir, "GridSmall")
    meet = [0, 5, 10, 15]
    np.testing.assert_allclose(m.reward, m.transition[:, :, meet].sum(-1), atol=1e-12)
    up_up = m.joint_action_index(["up", "up"])
    assert m.transition[0, up_up, 0] == pytest.approx(0.64)


def test_discount_override_and_alias(dpomdp_dir):
    path = dpomdp_dir / "recycling.dpomdp"
    assert parse_dpomdp(path, 0.5).discount == 0.5
    assert load_dpomdp(path).discount == 0.9
    assert load_dpomdp(str(path), discount=1.0).discount == 1.0
    assert parse_dpomdp(path).with_discount(0.3).discount == 0.3
    with pytest.raises(ValueError):
        parse_dpomdp(path, 1.5)


def test_text_and_gzip_inputs(dpomdp_dir, tmp_path):
    path = dpomdp_dir / "dectiger.dpomdp"
    ref = parse_dpomdp(path)
    text = path.read_text()
    from_text = parse_dpomdp(text)
    assert from_text.source == "<string>"
    gz = tmp_path / "dectiger.dpomdp.gz"
    gz.write_bytes(gzip.compress(path.read_bytes()))
    from_gz = parse_dpomdp(gz)
    from_bytes = parse_dpomdp(gzip.compress(path.read_bytes()))
    for m in (from_text, from_gz, from_bytes):
        np.testing.assert_array_equal(m.transition, ref.transition)
        np.testing.assert_array_equal(m.observation, ref.observation)
        np.testing.assert_array_equal(m.reward, ref.reward)
    assert parse_dpomdp(text, name="tiger").source == "tiger"


def test_corrupt_gzip(tmp_path):
    bad = tmp_path / "bad.dpomdp.gz"
    bad.write_bytes(b"\x1f\x8b" + b"garbage" * 10)
    with pytest.raises(DpomdpParseError, match="gzip"):
        parse_dpomdp(bad)


# --------------------------------------------------------------------------------------------
# Synthetic texts: every line form

HEAD = """\
agents: 2
discount: 0.95
values: reward
states: s0 s1 s2
start: uniform
actions:
a b
2
observations:
x y
u v w
"""
# |S| = 3, actions (2, 2) -> |JA| = 4, observations (2, 3) -> |JO| = 6
FULL_T = "T: * :\nuniform\n"
FULL_O = "O: * :\nuniform\n"


def parse(body: str, head: str = HEAD, **kw) -> TabularModel:
    """``head + body``; a body without rewards gets an all-zero ``R:`` line (a file without
    one is refused)."""
    if "R:" not in body:
        body += "R: * : * : * : * : 0\n"
    return parse_dpomdp(head + body, **kw)


def test_synthetic_header_names_and_counts():
    m = parse(FULL_T + FULL_O)
    assert m.agent_names == ("0", "1")
    assert m.state_names == ("s0", "s1", "s2")
    assert m.action_names == (("a", "b"), ("0", "1"))
    assert m.observation_names == (("x", "y"), ("u", "v", "w"))
    assert m.discount == 0.95 and m.num_joint_actions == 4 and m.num_joint_obs == 6
    np.testing.assert_allclose(m.initial_belief, 1 / 3)
    named = parse(FULL_T + FULL_O, head=HEAD.replace("agents: 2", "agents: alice bob-2"))
    assert named.agent_names == ("alice", "bob-2")


def test_joint_indices_last_agent_fastest():
    m = parse(FULL_T + FULL_O)
    assert m.joint_action_index(["b", 0]) == 2
    assert m.joint_action_index([0, 1]) == 1
    assert m.split_joint_action(3) == (1, 1)
    assert m.joint_obs_index(["y", "u"]) == 3
    assert m.split_joint_obs(5) == (1, 2)
    assert m.split_joint_obs(np.arange(6))[1].tolist() == [0, 1, 2, 0, 1, 2]
    assert m.joint_action_name(2) == "b 0" and m.joint_obs_name(4) == "y v"


def test_t_line_forms():
    body = (
        "T: * :\nidentity\n"  # matrix keyword, all joint actions
        "T: a 1 :\nuniform\n"  # per-agent names + index
        "T: 2 : s0 :\n0.2 0.3 0.5\n"  # joint index 2 = (b, 0), row form
        "T: b * : s1 : * : 0.0\n"  # wildcards in ja and s'
        "T: b * : s1 : s2 : 1.0\n"
        "T: 3 :\n0.1 0.9 0\n0 1 0\n1 0 0\n"  # explicit matrix
        "T: 3 : 2 : 0 : 0.25\n"  # indices
        "T: 3 : 2 : 2 : 0.75\n"
    )
    m = parse(body + FULL_O)
    T = m.transition
    np.testing.assert_array_equal(T[:, 0, :], np.eye(3))
    np.testing.assert_allclose(T[:, 1, :], 1 / 3)
    np.testing.assert_allclose(T[0, 2], [0.2, 0.3, 0.5])
    np.testing.assert_allclose(T[1, 2], [0, 0, 1])
    np.testing.assert_allclose(T[2, 2], [0, 0, 1])  # identity row from the first line
    np.testing.assert_allclose(T[0, 3], [0.1, 0.9, 0])
    np.testing.assert_allclose(T[1, 3], [0, 1, 0])  # the matrix overwrote "T: b * : s1"
    np.testing.assert_allclose(T[2, 3], [0.25, 0, 0.75])


def test_t_row_and_matrix_without_trailing_colon():
    m = parse("T: *\nidentity\nT: 1 : s1\n0 0 1\n" + FULL_O)
    np.testing.assert_allclose(m.transition[1, 1], [0, 0, 1])
    np.testing.assert_allclose(m.transition[0, 1], [1, 0, 0])


def test_o_line_forms():
    body = FULL_T + (
        "O: * :\nuniform\n"
        "O: a * : s0 : x u : 1.0\n"  # overwrite ...
        "O: a * : s0 : x v : 0.0\n"
        "O: a * : s0 : x w : 0\n"
        "O: a * : s0 : y * : 0\n"  # per-agent wildcard in jo
        "O: 3 : s1 :\n0.5 0.5 0 0 0 0\n"
        "O: 3 : * :\nuniform\n"  # ... then overwritten again
        "O: 2 :\n" + "0 0 0 0 0 1\n" * 3
    )
    m = parse(body)
    obs = m.observation
    for ja in (0, 1):
        np.testing.assert_allclose(obs[ja, 0], [1, 0, 0, 0, 0, 0])
        np.testing.assert_allclose(obs[ja, 1], 1 / 6)
    np.testing.assert_allclose(obs[3], 1 / 6)
    np.testing.assert_allclose(obs[2], np.tile([0, 0, 0, 0, 0, 1.0], (3, 1)))


def test_reward_set_overwrite_and_accumulate():
    rng = np.random.default_rng(0)
    tm = rng.dirichlet(np.ones(3), size=(3, 4))
    om = rng.dirichlet(np.ones(6), size=(4, 3))
    rows_t = "".join(
        f"T: {ja} : {s} :\n{' '.join(repr(float(p)) for p in tm[s, ja])}\n"
        for s in range(3)
        for ja in range(4)
    )
    rows_o = "".join(
        f"O: {ja} : {s} :\n{' '.join(repr(float(p)) for p in om[ja, s])}\n"
        for s in range(3)
        for ja in range(4)
    )
    tm = parse(rows_t + FULL_O).transition  # as stored (row sums exactly as parsed)
    om = parse(FULL_T + rows_o).observation
    body = (
        rows_t
        + rows_o
        + (
            "R: * : * : * : * : 1\n"  # set everything to 1
            "R: a 0 : s0 : * : * : 5\n"  # overwrite one entry
            "R: 1 : s1 : s2 : * : 10\n"  # add T(s2|s1,1) * 10
            "R: 1 : s1 : s0 : * : -4\n"  # add T(s0|s1,1) * -4
            "R: 2 : s2 : s1 : y w : 7\n"  # add T * O * 7
            "R: 3 : s0 : * : x * : 2\n"  # add sum_{s'} T * (O(x,u)+O(x,v)+O(x,w)) * 2
            "R: 0 : s1 : s0 :\n1 2 3 4 5 6\n"  # add T(s0|s1,0) * sum_jo O * row
            "R: 0 : s2 :\n" + "1 0 0 0 0 1\n" * 3  # add sum_{s', jo} T O M
        )
    )
    m = parse(body)
    R = np.ones((3, 4))
    R[0, 0] = 5
    R[1, 1] += tm[1, 1, 2] * 10 - 4 * tm[1, 1, 0]
    R[2, 2] += tm[2, 2, 1] * om[2, 1, 1 * 3 + 2] * 7
    R[0, 3] += 2 * (tm[0, 3, :] * om[3, :, 0:3].sum(-1)).sum()
    R[1, 0] += tm[1, 0, 0] * om[0, 0] @ np.arange(1, 7)
    R[2, 0] += (tm[2, 0, :] * (om[0, :, 0] + om[0, :, 5])).sum()
    np.testing.assert_allclose(m.reward, R, atol=1e-12)
    # A later set overwrites the accumulated value.
    m2 = parse(body + "R: 1 : s1 : * : * : -3\n")
    assert m2.reward[1, 1] == -3


def test_values_cost_negates():
    body = FULL_T + FULL_O + "R: * : * : * : * : 2\nR: 0 : s0 : * : * : -1\n"
    m = parse(body, head=HEAD.replace("values: reward", "values: cost"))
    assert m.reward[0, 0] == 1 and m.reward[2, 3] == -2


@pytest.mark.parametrize(
    "start, b0",
    [
        ("start: uniform", [1 / 3] * 3),
        ("start:\nuniform", [1 / 3] * 3),
        ("start: s1", [0, 1, 0]),
        ("start: 2", [0, 0, 1]),
        ("start:\ns2", [0, 0, 1]),
        ("start: 0.2 0.3 0.5", [0.2, 0.3, 0.5]),
        ("start:\n0.2 0.3 .5", [0.2, 0.3, 0.5]),
        ("start include: s0 2", [0.5, 0, 0.5]),
        ("start include: s1", [0, 1, 0]),
        ("start exclude: s1", [0.5, 0, 0.5]),
        ("start exclude: 0 s1", [0, 0, 1]),
    ],
)
def test_start_forms(start, b0):
    m = parse(FULL_T + FULL_O, head=HEAD.replace("start: uniform", start))
    np.testing.assert_allclose(m.initial_belief, b0)


def test_comments_spacing_and_signs():
    head = HEAD.replace("discount: 0.95", "discount:0.95   # inline comment\n# full line")
    body = (
        "T:*:\nuniform # trailing\n\n\nO: * :  \n  uniform\n"
        "R:a 0:s0:*:*:+2.5e0\nR: 1 : * : * : * : -.5\n"
    )
    m = parse(body, head=head)
    assert m.discount == 0.95 and m.reward[0, 0] == 2.5
    np.testing.assert_allclose(m.reward[:, 1], -0.5)


def test_large_model_parses_fast():
    """A few hundred states and ~0.8 MB of T lines parse in a couple of seconds."""
    rng = np.random.default_rng(0)
    S = 300
    lines = [
        "agents: 2",
        "discount: 0.95",
        "values: reward",
        "states: " + " ".join(f"s{i}" for i in range(S)),
        "start: uniform",
        "actions:",
        "a0 a1 a2 a3",
        "4",
        "observations:",
        "3",
        "z0 z1 z2",
    ]
    succ = np.stack([rng.choice(S, 5, replace=False) for _ in range(16 * S)])
    probs = np.full(5, 0.2)
    for a0 in range(4):
        for a1 in range(4):
            for s in range(S):
                for t, p in zip(succ[(a0 * 4 + a1) * S + s], probs, strict=True):
                    lines.append(f"T: a{a0} {a1} : s{s} : s{t} : {p}")
    lines += ["O: * :", "uniform"]
    lines += [f"R: * : s{s} : * : * : {s % 7}" for s in range(S)]
    text = "\n".join(lines) + "\n"
    assert len(text) > 600_000
    t0 = time.perf_counter()
    m = parse_dpomdp(text)
    elapsed = time.perf_counter() - t0
    assert m.num_states == S and m.transition.shape == (S, 16, S)
    assert elapsed < 5.0, elapsed


# --------------------------------------------------------------------------------------------
# Errors: file, line and what is wrong


def error_of(text: str, name: str = "model.dpomdp") -> DpomdpParseError:
    with pytest.raises(DpomdpParseError) as info:
        parse_dpomdp(text, name=name)
    return info.value


def line_of(text: str, needle: str, after: int = 0) -> int:
    """1-based number of the first line after line ``after`` containing ``needle``."""
    for i, line in enumerate(text.splitlines(), start=1):
        if i > after and needle in line:
            return i
    raise AssertionError(needle)


def test_error_str_format(dpomdp_dir, tmp_path):
    text = (dpomdp_dir / "dectiger.dpomdp").read_text()
    text = text.replace("R: listen listen: * :", "R: listen listen: foo :", 1)
    path = tmp_path / "dectiger.dpomdp"
    path.write_text(text)
    with pytest.raises(DpomdpParseError) as info:
        parse_dpomdp(path)
    err = info.value
    line = line_of(text, "foo")
    assert err.path == str(path) and err.line == line
    assert err.message == "start state: unknown state name 'foo'"
    assert str(err) == f"{path}:{line}: start state: unknown state name 'foo'"
    assert str(err).endswith(f"dectiger.dpomdp:{line}: start state: unknown state name 'foo'")
    assert isinstance(err, ValueError)


BAD_BODIES = [
    # (body, text on the offending line, message pattern)
    ("T: a 0 : s9 : s0 : 1\n", "s9", r"unknown state name 's9'"),
    ("T: a 0 : s0 : 3 : 1\n", ": 3 :", r"state index 3 out of range"),
    ("T: c 0 : s0 : s0 : 1\n", "c 0", r"unknown action name 'c' for agent 0"),
    ("T: a 2 : s0 : s0 : 1\n", "a 2", r"action index 2 of agent 1 out of range"),
    ("T: 4 : s0 : s0 : 1\n", "T: 4", r"joint action index 4 out of range"),
    ("T: a 0 1 : s0 : s0 : 1\n", "a 0 1", r"expected '\*', one joint index or 2 per-agent"),
    ("T: a 0 : s0 s1 : s0 : 1\n", "s0 s1", r"expected one state, found 2"),
    ("T: a 0 : s0 : s0 : abc\n", "abc", r"expected a number, found 'abc'"),
    ("T: a 0 : s0 : s0 : 1.5\n", "1.5", r"probability 1.5 is not in \[0, 1\]"),
    ("T: a 0 : s0 : s0 : -0.1\n", "-0.1", r"not in \[0, 1\]"),
    ("T: a 0 : s0 : s0 : 1e999\n", "1e999", r"out of range"),
    ("T: a 0 : s0 : s0 : nan\n", "nan", r"expected a number"),
    ("T: a 0 : s0 : s0 : 0.5 0.5\n", "0.5 0.5", r"expected one number, found 2"),
    ("T: a 0 : s0 :\n0.5 0.5\n", "0.5 0.5", r"expected 3 numbers, found 2 entries"),
    ("T: a 0 : s0 :\n0.5 0.25 0.25 0\n", "0.25 0", r"expected 3 numbers, found 4"),
    ("T: a 0 :\n1 0 0\n0 1 0\n", "0 1 0", r"file ends here.*row 3 of 3 of the matrix"),
    ("T: a 0 :\n1 0 0\n0 1 0\nT: * :\nuniform\n", "T: * :", r"matrix for T has 2 rows"),
    ("T: a 0 :\nidentity 1\n", "identity 1", r"expected 3 numbers"),
    ("O: a 0 :\nidentity\n", "identity", r"expected 6 numbers"),
    ("T: a 0 : s0 : s0\n", "T: a 0", r"malformed T line"),
    ("T: a 0 : s0 : s0 : :\n", "T: a 0", r"malformed T line"),
    ("T: : s0 : s0 : 1\n", "T: :", r"missing joint action"),
    ("O: a 0 : s0 : x : 1\n", "x : 1", r"joint observation 'x'"),
    ("O: a 0 : s0 : x q : 1\n", "x q", r"unknown observation name 'q' for agent 1"),
    ("O: a 0 : s0 : x 3 : 1\n", "x 3", r"observation index 3 of agent 1 out of range"),
    ("O: a 0 : s0 : 6 : 1\n", ": 6 :", r"joint observation index 6 out of range"),
    ("O: a 0 : s0 :\n0.5 0.5\n", "0.5 0.5", r"expected 6 numbers, found 2"),
    ("O: a 0 : s0 : x u : 0.5 : 1\n", "O: a 0", r"malformed O line"),
    ("R: a 0 : s0 : * : * : r\n", "R: a 0", r"reward: expected a number, found 'r'"),
    ("R: a 0 : s0 : * : *\n", "R: a 0", r"malformed R line"),
    ("R: a 0 : s0 : * :\n1 2\n", "1 2", r"expected 6 numbers"),
    ("R: a 0 : s0 :\n1 2 3 4 5 6\n6 5 4 3 2 1\n", "6 5 4", r"row 3 of 3"),
    ("X: a 0 : s0 : s0 : 1\n", "X:", r"expected a T:, O: or R: line, found 'X'"),
    ("T a 0 : s0 : s0 : 1\n", "T a 0", r"expected a T:, O: or R: line"),
    ("states: 3\n", "states: 3", r"'states:' out of place"),
    ("T: a 0 : s0 : s0 : 1 @\n", "@", r"expected one number"),
    ("T: a 0 : s@ : s0 : 1\n", "s@", r"unknown state name 's@'"),
]


@pytest.mark.parametrize("body, needle, pattern", BAD_BODIES)
def test_bad_body_lines(body, needle, pattern):
    prefix = HEAD + FULL_T + FULL_O
    text = prefix + body
    err = error_of(text)
    assert err.path == "model.dpomdp"
    assert err.line == line_of(text, needle, after=len(prefix.splitlines())), err
    assert re.search(pattern, err.message), err.message
    assert str(err).startswith(f"model.dpomdp:{err.line}: ")


def test_truncated_row_at_end_of_file():
    text = HEAD + FULL_T + FULL_O + "T: a 0 : s0 :\n"
    err = error_of(text)
    assert err.line == line_of(text, "T: a 0 : s0 :")
    assert "file ends here" in err.message


def test_truncated_matrix_at_end_of_file():
    text = HEAD + FULL_T + FULL_O + "O: 1 :\n" + "1 0 0 0 0 0\n" * 2
    err = error_of(text)
    assert err.line == len(text.splitlines()) and "row 3 of 3" in err.message


def test_row_sums_checked_with_line():
    text = HEAD + FULL_T + FULL_O + "T: a 1 : s2 : s0 : 0.5\n"
    err = error_of(text)
    assert err.line == line_of(text, "T: a 1 : s2 : s0 : 0.5")
    assert "T(.|s=s2, ja=a,1) sums to 1.16666666667" in err.message
    text = HEAD + FULL_T + FULL_O + "O: b 0 : s1 :\n0.5 0.5 0 0 0 0.000001\n"
    err = error_of(text)
    assert err.line == line_of(text, "0.000001") and "O(.|ja=b,0, s'=s1) sums to" in err.message
    # within 1e-9 is accepted
    parse(FULL_T + FULL_O + "T: a 1 : s2 :\n0.5 0.2 0.3000000001\n")


def test_never_specified_rows():
    err = error_of(HEAD + "T: a * :\nidentity\n" + FULL_O)
    assert err.line is None
    assert err.message == "T(.|s=s0, ja=b,0) never specified (and 5 more rows of T)"
    assert str(err) == "model.dpomdp: " + err.message
    err = error_of(HEAD + FULL_T + "O: * : s0 :\nuniform\n")
    assert err.line is None and err.message.startswith("O(.|ja=a,0, s'=s1) never specified")
    err = error_of(HEAD)
    assert err.line is None and "never specified" in err.message


def test_reward_needs_complete_t_and_o():
    text = HEAD + "R: a 0 : s0 : s1 : * : 1\n" + FULL_T + FULL_O
    err = error_of(text)
    assert err.line == line_of(text, "R: a 0") and "T(.|s=s0, ja=a,0)" in err.message
    text = HEAD + FULL_T + "R: a 0 : s0 : s1 : x u : 1\n" + FULL_O
    err = error_of(text)
    assert err.line == line_of(text, "R: a 0") and "O(.|ja=a,0, s'=s1)" in err.message
    text = HEAD + FULL_T + FULL_O + "R: a 0 : s0 : s1 : * : 1\nT: a 0 : s0 :\n0 1 0\n"
    err = error_of(text)
    assert err.line == line_of(text, "0 1 0") and "already used" in err.message
    text = HEAD + FULL_T + FULL_O + "R: a 0 : * : * : x u : 1\nO: a 0 : s2 : x u : 1\n"
    err = error_of(text)
    assert err.line == line_of(text, "O: a 0 : s2") and "already used" in err.message
    # unrelated rows may still change afterwards
    parse(FULL_T + FULL_O + "R: a 0 : s0 : s1 : * : 1\nT: b 0 : s0 :\n0 1 0\n")


HEADER_CASES = [
    # (replace, by, expected line, pattern); HEAD's lines: 1 agents, 2 discount, 3 values,
    # 4 states, 5 start, 6 actions, 7-8 per agent, 9 observations, 10-11 per agent, 12- body
    ("discount: 0.95\n", "", 2, r"missing 'discount:' before 'values:'"),
    ("agents: 2\n", "", 1, r"missing 'agents:' before 'discount:'"),
    ("values: reward\n", "values: reward\nvalues: reward\n", 4, r"'values:' given twice"),
    (
        "values: reward\nstates: s0 s1 s2\n",
        "states: s0 s1 s2\nvalues: reward\n",
        3,
        r"missing 'values:' before 'states:'",
    ),
    ("agents: 2", "agents: 0", 1, r"count must be at least 1"),
    ("agents: 2", "agents: 2.5", 1, r"expected a count or names"),
    ("agents: 2", "agents: 3", 9, r"actions: expected one line per agent \(3\), found only 2"),
    ("agents: 2", "agents:", 2, r"agents: expected a count or names"),
    ("discount: 0.95", "discount: 1.5", 2, r"not in \[0, 1\]"),
    ("discount: 0.95", "discount: high", 2, r"expected a number, found 'high'"),
    ("discount: 0.95", "discount: 0.9 0.9", 2, r"expected one number, found 2"),
    ("values: reward", "values: money", 3, r"expected 'reward' or 'cost'"),
    ("states: s0 s1 s2", "states: s0 s1 s1", 4, r"'s1' appears twice"),
    ("states: s0 s1 s2", "states: s0 1s", 4, r"found '1s'"),
    ("states: s0 s1 s2", "states: -3", 4, r"found '-3'"),
    ("start: uniform", "start: 0.5 0.5", 5, r"found 2 entries"),
    ("start: uniform", "start: 0.5 0.6 0", 5, r"sum to 1.1"),
    ("start: uniform", "start: 0.5 -0.5 1", 5, r"not in \[0, 1\]"),
    ("start: uniform", "start: s7", 5, r"unknown state name 's7'"),
    ("start: uniform", "start: 3", 5, r"state index 3 out of range"),
    ("start: uniform", "start include: s0 s9", 5, r"unknown state name 's9'"),
    ("start: uniform", "start exclude: s0 s1 s2", 5, r"every state is excluded"),
    ("start: uniform", "start maybe: s0", 5, r"'start include:'"),
    ("start: uniform", "start:", 6, r"start: expected 'uniform', one state or 3 probabilities"),
    ("a b\n2\nobservations", "a b\nobservations", 8, r"found only 1"),
    ("x y\nu v w\n", "x y\n", 11, r"observations: expected one line per agent \(2\)"),
    ("a b\n", "a a\n", 7, r"'a' appears twice"),
]


@pytest.mark.parametrize("old, new, line, pattern", HEADER_CASES)
def test_bad_headers(old, new, line, pattern):
    assert old in HEAD
    text = HEAD.replace(old, new, 1) + FULL_T + FULL_O
    err = error_of(text)
    assert re.search(pattern, err.message), err.message
    assert err.line == line, (err.line, err.message)


def test_empty_and_truncated_header():
    err = error_of("# nothing but a comment\n\n")
    assert "file ends before 'agents:'" in err.message and err.line is not None
    text = HEAD.split("actions:")[0]
    err = error_of(text)
    assert "file ends before 'actions:'" in err.message
    err = error_of("agents: 2\ndiscount: 1\n")
    assert "'values:'" in err.message


def test_too_large_model_is_a_parse_error():
    head = HEAD.replace("states: s0 s1 s2", "states: 100000")
    err = error_of(head + FULL_T)
    assert err.line == 4 and "count 100000 is too large" in err.message
    head = HEAD.replace("states: s0 s1 s2", "states: 10000")
    err = error_of(head + FULL_T)
    assert err.line == 9 and "model too large" in err.message


# --------------------------------------------------------------------------------------------
# Fuzz: random mutations of the real files only ever raise DpomdpParseError


def _mutate(text: str, rnd: random.Random) -> str:
    lines = text.splitlines()
    numbers = ["0", "1", "2", "3", "-1", "0.5", "1.0000001", "17", "1e999", "nan", "x", "*", ":"]
    for _ in range(rnd.randint(1, 3)):
        if not lines:
            break
        op = rnd.randrange(9)
        i = rnd.randrange(len(lines))
        toks = lines[i].replace(":", " : ").split()
        if op == 0:
            del lines[i]
        elif op == 1:
            lines.insert(i, lines[i])
        elif op == 2:
            j = rnd.randrange(len(lines))
            lines[i], lines[j] = lines[j], lines[i]
        elif op == 3:
            cut = rnd.randrange(len(text) + 1)
            return text[:cut]
        elif toks:
            k = rnd.randrange(len(toks))
            if op == 4:
                del toks[k]
            elif op == 5:
                toks.insert(k, toks[k])
            elif op == 6:
                m = rnd.randrange(len(toks))
                toks[k], toks[m] = toks[m], toks[k]
            elif op == 7:
                toks[k] = rnd.choice(numbers)
            else:
                toks[k] = toks[k] + rnd.choice(["#", "@", "-", "0", "\x00", "é"])
            lines[i] = " ".join(toks)
    return "\n".join(lines) + "\n"


def test_fuzz_only_parse_errors(dpomdp_dir):
    rnd = random.Random(1234)
    texts = {n: (dpomdp_dir / f"{n}.dpomdp").read_text() for n in FILES}
    plan = [n for n in FILES[:3] for _ in range(900)] + ["GridSmall"] * 60
    outcomes = {"ok": 0, "error": 0}
    for n in plan:
        mutated = _mutate(texts[n], rnd)
        try:
            parse_dpomdp(mutated.encode(), name=n)
            outcomes["ok"] += 1
        except DpomdpParseError as err:
            outcomes["error"] += 1
            assert "cannot parse this line" not in err.message, (err, mutated)
            assert err.line is None or isinstance(err.line, int)
    assert outcomes["error"] > 1000 and outcomes["ok"] > 100, outcomes


def test_values_may_be_quoted(dpomdp_dir):
    """MADP's own box-pushing file writes ``values: "reward"``."""
    text = (dpomdp_dir / "dectiger.dpomdp").read_text()
    plain = parse_dpomdp(text)
    quoted = parse_dpomdp(re.sub(r"values:\s*reward", 'values: "reward"', text))
    np.testing.assert_array_equal(plain.reward, quoted.reward)
    cost = parse_dpomdp(re.sub(r"values:\s*reward", 'values: "cost"', text))
    np.testing.assert_array_equal(cost.reward, -plain.reward)


def test_large_transition_tables_are_float32_and_still_checked(dpomdp_dir, monkeypatch):
    """Above ``FLOAT64_T_ENTRIES`` T is stored in float32 (half the memory); rows are still
    summed in float64, within ``PROB_TOL`` plus float32's rounding."""
    import cognet_jax.io.dpomdp as parser
    from cognet_jax.exact import exact_value
    from cognet_jax.io.dpomdp import PROB_TOL

    path = dpomdp_dir / "dectiger.dpomdp"
    dense = load_dpomdp(path)
    monkeypatch.setattr(parser, "FLOAT64_T_ENTRIES", 0)
    small = load_dpomdp(path)
    assert dense.transition.dtype == np.float64 and small.transition.dtype == np.float32
    np.testing.assert_array_equal(small.transition, dense.transition.astype(np.float32))
    policy = np.zeros((2, 1), int), np.zeros((2, 1, 2), int)  # listen forever
    v64, v32 = (exact_value(m, *policy, 4, 1.0) for m in (dense, small))
    assert abs(v64 - v32) < 1e-6
    # a row off by 1e-6 is refused in float32 as in float64
    off = "T: * : s0 :\n0.5 0.499999 0\nT: * : s1 :\nuniform\nT: * : s2 :\nuniform\n"
    for limit in (0, 2**25):
        monkeypatch.setattr(parser, "FLOAT64_T_ENTRIES", limit)
        with pytest.raises(DpomdpParseError, match=r"s=s0, ja=a,0\) sums to 0\.99999"):
            parse(off + FULL_O)
        # within the tolerance: accepted in both
        ok = off.replace("0.499999", f"{0.5 - PROB_TOL / 2:.12f}")
        assert parse(ok + FULL_O).transition.shape == (3, 4, 3)


def test_the_parser_loads_without_jax():
    """``import cognet_jax`` is lazy, so the parser (and ``benchmarks/parser.py``'s memory
    figure) carries numpy only."""
    import subprocess
    import sys

    code = "import sys, cognet_jax.io.dpomdp; print('jax' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_a_binary_or_oversized_file_is_refused_before_it_is_read(tmp_path, monkeypatch):
    """A sparse or binary file (NUL bytes in its first 64 KiB) is refused naming the line of
    its first NUL, and a file over ``MAX_FILE_BYTES`` by its size, both without reading it
    whole (a 3 GB sparse file took 6.5 GB of memory before)."""
    import os

    from cognet_jax.io import dpomdp

    sparse = tmp_path / "sparse.dpomdp"
    sparse.write_bytes(b"agents: 2\n")
    os.truncate(sparse, 3 * 2**30)  # no disk used
    with pytest.raises(dpomdp.DpomdpParseError, match=r"sparse.dpomdp:2: a NUL byte"):
        dpomdp.parse_dpomdp(sparse)
    big = tmp_path / "big.dpomdp"
    big.write_text("agents: 2\n" + "# a comment\n" * 200)
    monkeypatch.setattr(dpomdp, "MAX_FILE_BYTES", 1000)
    with pytest.raises(dpomdp.DpomdpParseError, match=r"big.dpomdp: .*GiB, over the"):
        dpomdp.parse_dpomdp(big)


def test_a_long_parse_says_how_far_it_is(monkeypatch):
    """A parse past ``PROGRESS_AFTER_S`` says which phase and line it is at (a 50 MB file took
    28 s without a word); a quick one says nothing."""
    from cognet_jax import status
    from cognet_jax.io import dpomdp

    heard = []
    monkeypatch.setattr(status, "listener", heard.append)
    body = FULL_T + FULL_O + "R: * : * : * : * : 1\n" * 20000
    parse(body)
    assert heard == []
    monkeypatch.setattr(dpomdp, "PROGRESS_AFTER_S", 0.0)
    monkeypatch.setattr(dpomdp, "PROGRESS_EVERY_S", 0.0)
    monkeypatch.setattr(dpomdp, "PROGRESS_LINES", 4096)
    model = parse(body)
    assert model.reward.max() == 1.0
    assert any(line.startswith("reading <string>: splitting, line ") for line in heard), heard
    assert any("reading the entries, line " in line and "%)" in line for line in heard), heard
