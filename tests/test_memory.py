"""Memory budget: candidates evaluated in chunks give the unchunked numbers, one candidate
over the budget and arrays that cannot fit are refused before compiling, with one line."""

import json
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from shared_files import dpomdp_file

from cognet_jax import memory
from cognet_jax.algorithms.cognet_thesis import NeuralPolicy
from cognet_jax.api import build_algorithm
from cognet_jax.cli import main
from cognet_jax.registry import load_config
from cognet_jax.rollout import evaluate_candidates, rollouts
from tests.test_cli_errors import one_line_error, sets


def candidates_of(name, overrides=(), count=13):
    alg, params = build_algorithm(load_config(name, list(overrides)))
    state = alg.init(jax.random.key(0), params)
    policies = alg.sample_policies(jax.random.key(1), state.distribution)
    policies = getattr(policies, "policy", policies)  # COG-DICE: the sample's policy
    return alg, params.env, jax.tree.map(lambda x: x[:count], policies)


def run_of(env, ctrl):
    """The rollout function ``memory`` measures (as ``rollout.evaluate_candidates`` passes)."""
    return lambda k, p, n, e: rollouts(env, ctrl, k, n, e, p)


@pytest.mark.parametrize("crn", [True, False])
def test_chunked_candidates_equal_unchunked(crn):
    alg, params, policies = candidates_of("tagging-thesis-cogdice-n3")
    env, ctrl, num = alg.env, alg.controller, 200
    one = jax.tree.map(lambda x: x[0], policies)
    per_rollout = memory.rollout_bytes(run_of(env, ctrl), params, one)
    # three candidates at once (in the chunks' share of the budget): chunks 3,3,3,3 + 1
    budget = int(3.5 * num * per_rollout / memory.CHUNK_SHARE)

    assert memory.candidate_chunk(run_of(env, ctrl), params, one, 13, num, budget) == 3

    def values(mem):
        fn = lambda k, p: evaluate_candidates(  # noqa: E731
            env, ctrl, k, num, params, p, memory=mem, common_random_numbers=crn
        )
        return jax.jit(fn)(jax.random.key(7), policies)

    full, chunked = values(None), values(budget)
    np.testing.assert_allclose(chunked, full, rtol=1e-6, atol=1e-6)
    assert not np.array_equal(full, np.full_like(full, full[0]))  # distinct candidates

    # every rollout's return is bit for bit the same: the chunks only change the batch shape
    keys = jax.random.split(jax.random.key(7), 13)

    def returns(c):
        k = jax.random.key(7) if crn else keys[c]
        return rollouts(env, ctrl, k, num, params, jax.tree.map(lambda x: x[c], policies))

    batched = jax.jit(jax.vmap(returns))(jnp.arange(13))
    mapped = jax.jit(lambda i: jax.lax.map(returns, i, batch_size=3))(jnp.arange(13))
    assert np.array_equal(batched, mapped)


def test_the_bound_of_all_candidates_traced_is_below_the_per_rollout_bound(monkeypatch):
    """``evaluate_candidates`` bounds its memory by the arrays of the traced evaluation of all
    candidates: within ``candidates x rollouts x`` the arrays of one traced rollout (the bound
    used before), so what fitted the budget still does."""
    import cognet_jax.rollout as rollout

    alg, params, policies = candidates_of("tagging-thesis-cogdice-n3")
    seen = []

    def spy(run, env_params, policy, candidates, rollouts, mem, *args, upper_bound, **kw):
        seen.append((upper_bound, candidates * rollouts))
        return memory.candidate_chunk(run, env_params, policy, candidates, rollouts, mem)

    monkeypatch.setattr(rollout, "candidate_chunk", spy)
    one = jax.tree.map(lambda x: x[0], policies)
    jax.eval_shape(
        lambda p: evaluate_candidates(alg.env, alg.controller, jax.random.key(0), 200, params, p),
        policies,
    )
    [(traced, in_flight)] = seen
    per_rollout = memory._step_upper_bound(run_of(alg.env, alg.controller), params, one)
    assert 0 < traced <= in_flight * per_rollout, (traced, in_flight * per_rollout)


def test_shared_network_candidates_are_chunked_too():
    """COGNet-DICE's candidates batch only the action tables (``policy_axes``)."""
    alg, search_params = build_algorithm(load_config("tagging-thesis-spec-n3"))
    policy = alg.init(jax.random.key(0), search_params).policy
    probs = jax.random.dirichlet(
        jax.random.key(2),
        jnp.ones(policy.action_probs.shape[-1]),
        (5, *policy.action_probs.shape[:-1]),
    )
    cands = policy.replace(action_probs=probs)
    axes = NeuralPolicy(action_probs=0, net_params=None)
    env, ctrl, params = alg.env, alg.controller, search_params.env
    one = policy.replace(action_probs=probs[0])
    budget = int(2.5 * 100 * memory.rollout_bytes(run_of(env, ctrl), params, one))

    def values(mem):
        return evaluate_candidates(
            env, ctrl, jax.random.key(3), 100, params, cands, policy_axes=axes, memory=mem
        )

    chunked, whole = jax.jit(lambda: (values(budget), values(None)))()  # one program
    np.testing.assert_allclose(chunked, whole, rtol=1e-6, atol=1e-6)


def test_one_candidate_over_the_budget_is_refused_with_the_numbers():
    alg, params, policies = candidates_of("tagging-thesis-cogdice-n3")
    with pytest.raises(memory.ResourceError) as err:
        evaluate_candidates(
            alg.env, alg.controller, jax.random.key(0), 10_000, params, policies, memory=1e5
        )
    line = str(err.value)
    assert "algorithm.eval_rollouts: 10000 rollouts" in line and "run.memory_gb" in line
    assert "\n" not in line


def test_a_run_within_a_small_budget_matches_the_unchunked_run(tmp_path):
    """A run whose candidates are chunked (``run.memory_gb`` small) reproduces the run without
    a budget: the same values per iteration up to the last bits of the means."""
    base = ["--no-progress", *sets("algorithm.iterations=3", "run.plots=false")]
    small = f"run.memory_gb={50 * 1000 * 100 / 1e9}"  # about 10 of 50 candidates at once
    for name, extra in (("full", []), ("small", sets(small))):
        out = tmp_path / name
        assert main(["train", "tagging-thesis-cogdice-n3", "--out", str(out), *base, *extra]) == 0
    a, b = (json.loads((tmp_path / n / "results.json").read_text()) for n in ("full", "small"))
    np.testing.assert_allclose(a["values_per_iteration"], b["values_per_iteration"], rtol=1e-5)


@pytest.mark.parametrize(
    "experiment,override,expected",
    [
        ("tagging-thesis-cogdice-n3", "algorithm.nodes=1000000000", "the initial state needs"),
        ("tagging-thesis-cogdice-n3", "algorithm.samples=1000000", "one iteration needs"),
        ("tagging-thesis-n3", "algorithm.candidates=300000", "one iteration needs"),
        ("tagging-thesis-cogdice-n3", "algorithm.eval_rollouts=1000000", "eval_rollouts"),
    ],
)
def test_sizes_over_the_budget_are_refused_before_compiling(
    capsys, tmp_path, experiment, override, expected
):
    out = tmp_path / "never"
    argv = ["train", experiment, "--out", str(out), *sets(override, "run.memory_gb=0.01")]
    line = one_line_error(capsys, argv, expected, "GB", "run.memory_gb")
    assert not out.exists(), line


def _dectiger_train_argv(out, *overrides):
    """``cognet-jax train gdice-dpomdp`` on Dec-Tiger with ``overrides``, writing to ``out``."""
    path = f"problem.path={json.dumps(str(dpomdp_file('dectiger')))}"
    return ["train", "gdice-dpomdp", "--out", str(out), *sets(path, *overrides)]


def test_a_size_past_32_bit_integers_is_refused_in_one_line(capsys, tmp_path):
    """A layered controller of 10^9 nodes per layer x 3 layers: the node count overflows int32
    while the initial state is traced; refused with the number, nothing written."""
    out = tmp_path / "never"
    argv = _dectiger_train_argv(out, "problem.horizon=3", "algorithm.nodes=1000000000")
    one_line_error(capsys, argv, "the initial state", "2999999999", "32-bit", "nodes")
    assert not out.exists()


def test_a_horizon_of_a_million_is_refused_in_seconds(capsys, tmp_path):
    """``problem.horizon=1000000`` on Dec-Tiger (gdice-dpomdp: a layer per step): the cost
    estimates stay small numbers (no integer of a million digits) and the size check refuses
    the 5-million-node controller before anything compiles."""
    out = tmp_path / "never"
    t0 = time.perf_counter()
    one_line_error(capsys, _dectiger_train_argv(out, "problem.horizon=1000000"), "GB")
    assert time.perf_counter() - t0 < 60
    assert not out.exists()


def test_memory_gb_must_not_be_negative_or_round_to_nothing(capsys):
    one_line_error(capsys, ["train", *sets("run.memory_gb=-1")], "run.memory_gb")
    # 1e-300 GB is no byte: refused, not "over the memory budget of 0 GB"
    one_line_error(capsys, ["train", *sets("run.memory_gb=1e-300")], "at least 0.001 GB")


@pytest.mark.parametrize("command", ["check", "train"])
def test_a_policy_over_the_budget_is_refused_before_the_noise_pilot_makes_it(
    capsys, tmp_path, command
):
    """``algorithm.nodes=100000`` on the weight search: one joint policy is 880 GB; ``check``
    and ``train`` both refuse it in one line (exit 2) before the noise pilot or the input
    statistics allocate it."""
    out = tmp_path / "never"
    argv = [command, "hearing-tiger-n7", *sets("algorithm.nodes=100000")]
    argv += ["--out", str(out)] if command == "train" else []
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()  # the pilot's line, then the refusal
    assert err[-1].startswith("error: one joint policy") and "Traceback" not in "".join(err)
    assert "880 GB" in err[-1] and "algorithm.nodes" in err[-1]
    assert not out.exists()


def test_made_arrays_over_the_budget_are_refused_without_making_them():
    """``check_made_fits`` sizes what a function returns by its shapes only."""

    def make(key, rows):
        return jax.random.normal(key, (rows.shape[0], 1000))

    key = jax.random.key(0)
    memory.check_made_fits(make, (key, jnp.zeros(10)), 40_000, "ten rows")
    with pytest.raises(memory.ResourceError, match="ten thousand rows take 0.04 GB"):
        memory.check_made_fits(make, (key, jnp.zeros(10_000)), 40_000, "ten thousand rows")


@pytest.mark.parametrize("command", ["check", "train"])
def test_temporaries_over_the_budget_are_refused_after_compiling(capsys, tmp_path, command):
    """10^8 rollouts per candidate: no single array is over the budget, but XLA's
    temporaries of one iteration are (26.8 GB); ``check`` and ``train`` both refuse it in one
    line, exit 2, by XLA's memory analysis of the compiled iteration (``check_compiled``),
    instead of an out-of-memory error when it runs."""
    out = tmp_path / "never"
    argv = [command, "tagging-thesis-n3", *sets("algorithm.eval_rollouts=100000000")]
    argv += ["--out", str(out), "--no-progress"] if command == "train" else []
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("error: one iteration needs about"), err
    assert "XLA's temporaries" in err[-1] and "Traceback" not in "".join(err)
    assert "(algorithm.eval_rollouts = 100000000, " in err[-1]  # the config's own sizes
    assert not out.exists()


def test_the_pilots_candidates_are_sized_before_the_input_statistics_compile(capsys):
    """3000 nodes: one policy fits, the noise pilot's 64 candidates (50.7 GB) do not. They are
    sized first, by their shapes, so the refusal comes in seconds (the input statistics'
    rollouts of a 3000-node controller compiled for minutes before it)."""
    start = time.perf_counter()
    assert main(["check", "hearing-tiger-n7", *sets("algorithm.nodes=3000")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("error: the noise pilot's 64 candidates take"), err
    assert time.perf_counter() - start < 60


def test_a_program_over_several_devices_counts_every_devices_buffers():
    """XLA's memory analysis counts one device's buffers: a program whose arguments are laid
    over two devices holds twice as much, and is refused when that is over the budget."""
    code = """
import jax, jax.numpy as jnp, numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec as P
from cognet_jax.memory import MemoryOverBudget, check_compiled, program_devices
mesh = Mesh(np.array(jax.devices()), ("r",))
f = jax.shard_map(lambda x: x * 2, mesh=mesh, in_specs=P("r"), out_specs=P("r"))
arg = jax.ShapeDtypeStruct((2, 250_000), jnp.float32, sharding=NamedSharding(mesh, P("r")))
compiled = jax.jit(f).lower(arg).compile()
assert program_devices(compiled) == 2
check_compiled(compiled, 4_100_000)  # 2 x (1 MB in + 1 MB out): fits
try:
    check_compiled(compiled, 3_900_000)
except MemoryOverBudget as err:
    assert err.needed == 4_000_000, err.needed
else:
    raise SystemExit("not refused")
"""
    import os
    import subprocess
    import sys

    env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=2"}
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-2000:]


def test_a_refusal_names_the_field_that_made_the_array(capsys):
    """G-DICE's layered controller at horizon 100000 (500000 nodes): the refusal names
    problem.horizon, the config's largest size, not a generic list of words."""
    path = dpomdp_file("dectiger")
    argv = ["check", "gdice-dpomdp", *sets(f"problem.path={path}", "problem.horizon=100000")]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert "over the memory budget" in err[-1], err
    assert "lower the sizes in the config (problem.horizon = 100000, " in err[-1]


def test_a_built_in_experiment_with_its_own_budget_fits_it(capsys):
    """The paper setting's full budget sets ``run.memory_gb`` (chunks of candidates kept in
    the CPU's cache) and passes ``check``: the chunk leaves the rest of the iteration room
    (``CHUNK_SHARE``; at the whole budget it, and the COG-DICE one, were refused after
    compiling)."""
    name = "tagging-paper-cognet-full"
    assert load_config(name).run.memory_gb > 0
    assert main(["check", name]) == 0, capsys.readouterr().err
    assert f"{name}: valid" in capsys.readouterr().out
