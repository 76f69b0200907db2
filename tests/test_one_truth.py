"""One result per experiment, whatever the door: the library's ``make_train`` returns the policy
``cognet-jax train`` writes (polish included), ``make_evaluate`` its ``final_value``,
``cognet-jax evaluate DIR`` reproduces ``final_value`` exactly, and the README's
domain-randomisation example searches every noise level as a single run would."""

import json
import re
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax.serialization import msgpack_restore
from shared_files import dpomdp_file

from cognet_jax.api import build_algorithm, make_evaluate, make_train, seed_key
from cognet_jax.cli import main
from cognet_jax.driver import train
from cognet_jax.registry import load_config

QUIET = ["run.plots=false", "run.progress=false"]


def _saved_policy(folder: Path):
    """The leaves of a policy file (its header wraps the policy's own msgpack)."""
    raw = msgpack_restore((folder / "policy.msgpack").read_bytes())
    return jax.tree.leaves(msgpack_restore(raw["policy"]))


def _same_policy(policy, folder: Path):
    for a, b in zip(jax.tree.leaves(policy), _saved_policy(folder), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


CASES = {
    # G-DICE with the exact polish and best responses: make_train runs ``finish`` too
    "gdice-dpomdp": [
        "problem.horizon=3",
        "algorithm.iterations=4",
        "algorithm.samples=60",
        "algorithm.nodes=2",
        "algorithm.repeats=2",  # repeated searches (the default "auto" gives 8 here)
        "evaluation.rollouts=2000",
    ],
    # the default COGNet-DICE: a policy of network weights
    "tagging-thesis-n3": [
        "algorithm.iterations=6",
        "algorithm.candidates=30",
        "algorithm.elites=4",
        "algorithm.eval_rollouts=40",
        "algorithm.best_rollouts=60",
        "evaluation.rollouts=2000",
    ],
}


@pytest.mark.parametrize("experiment", sorted(CASES))
def test_make_train_and_make_evaluate_give_what_train_writes(experiment, tmp_path):
    sets = [*CASES[experiment], *QUIET]
    if experiment.startswith("gdice"):
        sets.insert(0, f'problem.path="{dpomdp_file("dectiger")}"')
    config = load_config(experiment, sets)
    seed = 3
    record = train(config, seed, tmp_path / "run", log=lambda *_: None)
    if experiment.startswith("gdice"):
        assert record["finish"] is not None  # the CLI's run was polished
    key = seed_key(config, seed)
    state, metrics = jax.jit(make_train(config))(key)
    _same_policy(state.best_policy, tmp_path / "run")
    np.testing.assert_array_equal(
        np.asarray(metrics.value, np.float32), np.float32(record["values_per_iteration"])
    )
    mean, stderr = jax.jit(make_evaluate(config))(key, state.best_policy)
    final = record["final_value"]
    assert float(mean) == pytest.approx(final["mean"], rel=1e-6, abs=1e-6)
    assert float(stderr) == pytest.approx(final["stderr"], rel=1e-4)


def test_make_train_vmaps_over_seeds_and_params():
    config = load_config("tagging-thesis-cogdice-n3", ["algorithm.iterations=3", *QUIET])
    run = make_train(config)
    keys = jnp.stack([seed_key(config, s) for s in (0, 1)])
    _, batched = jax.jit(jax.vmap(run))(keys)
    for i in range(2):
        _, alone = jax.jit(run)(keys[i])
        np.testing.assert_array_equal(np.asarray(batched.value[i]), np.asarray(alone.value))


def test_evaluate_reproduces_final_value_and_seed_draws_afresh(tmp_path):
    sets = [*CASES["tagging-thesis-n3"], *QUIET]
    out = tmp_path / "run"
    assert (
        main(["train", "--seed", "2", "--out", str(out)] + [a for s in sets for a in ("--set", s)])
        == 0
    )
    final = json.loads((out / "results.json").read_text())["final_value"]
    log = out / "evaluations.jsonl"

    def last():
        return json.loads(log.read_text().splitlines()[-1])

    assert main(["evaluate", str(out)]) == 0
    again = last()
    assert (again["mean"], again["stderr"], again["rollouts"], again["seed"]) == (
        final["mean"],
        final["stderr"],
        final["rollouts"],
        2,
    )
    assert main(["evaluate", str(out), "--seed", "2"]) == 0
    assert last()["mean"] == final["mean"]  # the run's own seed: the same draws
    assert main(["evaluate", str(out), "--seed", "9"]) == 0
    fresh = last()
    assert fresh["seed"] == 9 and fresh["mean"] != final["mean"]
    assert abs(fresh["mean"] - final["mean"]) < 6 * np.hypot(fresh["stderr"], final["stderr"])


def _readme_block(title: str) -> str:
    text = (Path(__file__).parents[1] / "README.md").read_text()
    section = text.split(title, 1)[1]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


#: the README block's search, smaller (its code and the equalities are under test, not values)
README_SMALL = CASES["tagging-thesis-n3"]


def test_readme_domain_randomisation_example():
    """The README's block, run as written (on a smaller search): one program searches four
    noise levels, and the search of each level is the search a config with that noise level
    runs (its params as data instead of constants: the same numbers up to float rounding)."""
    code = _readme_block("### Domain randomisation")
    written = '["algorithm.iterations=20"]'
    assert written in code
    code = code.replace(written, repr(README_SMALL))
    namespace: dict = {}
    exec(compile(code, "README.md", "exec"), namespace)
    levels, metrics, mean = namespace["levels"], namespace["metrics"], namespace["mean"]
    assert mean.shape == (4,) and np.all(np.isfinite(np.asarray(mean)))
    config = namespace["config"]
    as_data = jax.jit(make_train(config))  # one program: each level's params as an argument
    for i, level in enumerate(np.asarray(levels)):
        alone = load_config("tagging-thesis-n3", [*README_SMALL, f"env.obs_noise={level}"])
        _, m = as_data(namespace["key"], build_algorithm(alone)[1])
        np.testing.assert_allclose(
            np.asarray(metrics.value[i]), np.asarray(m.value), rtol=1e-4, atol=1e-3
        )
    # and the noisiest level as `cognet-jax train` compiles it (its params as constants)
    _, m = jax.jit(make_train(alone))(namespace["key"])
    np.testing.assert_allclose(
        np.asarray(metrics.value[-1]), np.asarray(m.value), rtol=1e-4, atol=1e-3
    )
    assert config.env.obs_noise == 0.0
    # the noise reaches the searches: a noisy level ends with another value than a clean one
    assert float(mean[0]) != float(mean[3])
