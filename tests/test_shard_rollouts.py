"""One run's rollouts (and candidate evaluations) laid over 2 local devices
(``run.shard_rollouts``): the same numbers as on one device."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).parents[1]
SMALL = [
    "algorithm.iterations=4",
    "algorithm.rollouts=200",
    "algorithm.top=20",
    "algorithm.keep=5",
    "algorithm.eval_rollouts=20",
    "evaluation.rollouts=400",
    "run.plots=false",
    "run.progress=false",
]

SCRIPT = """
import json, sys
import jax
from cognet_jax.cli import set_up_process
from cognet_jax.driver import train
from cognet_jax.compiled import rollout_mesh
from cognet_jax.registry import load_config
set_up_process()  # as the executable's process
assert jax.local_device_count() == 2, jax.local_devices()
out, sets = sys.argv[1], sys.argv[2:]
for shard in ("false", "true"):
    config = load_config("tagging-thesis-spec-n3", sets + [f"run.shard_rollouts={shard}"])
    train(config, 0, f"{out}/{shard}", log=lambda *_: None)
# the sharded step really is partitioned over both devices
from cognet_jax.api import make_step, seed_key, split_seed_key
k_init, k_run, _ = split_seed_key(seed_key(config, 0))
with rollout_mesh(config):
    algorithm, params, step = make_step(config)
    state = algorithm.init(k_init, params)
    text = jax.jit(lambda k, s: step(k, s, params)).lower(k_run, state).as_text()
assert "mhlo.num_partitions = 2" in text, "step not partitioned"
"""


def test_sharded_rollouts_give_the_same_run(tmp_path):
    # (the suite's XLA flags kept: conftest.py)
    flags = f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count=2"
    env = dict(os.environ, XLA_FLAGS=flags.strip())
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    proc = subprocess.run(
        [sys.executable, "-c", SCRIPT, str(tmp_path), *SMALL],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    one, two = (json.loads((tmp_path / s / "results.json").read_text()) for s in ("false", "true"))
    assert two["config"]["run"]["shard_rollouts"] is True
    # per-shard partial sums may round differently; the search itself must not change
    np.testing.assert_allclose(two["values_per_iteration"], one["values_per_iteration"], rtol=1e-5)
    np.testing.assert_array_equal(two["kept_per_iteration"], one["kept_per_iteration"])
    np.testing.assert_allclose(two["final_value"]["mean"], one["final_value"]["mean"], rtol=1e-5)
