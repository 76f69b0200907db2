"""``run.probe_seconds``: the anytime best is kept whenever it changed, at most once per period,
and each kept policy gets the honest evaluation after the search (issue 52, time to a good
controller): the last probe's policy is the final best, so its value is the final value."""

from __future__ import annotations

import json

from shared_files import TINY_TRAIN

from cognet_jax import cli

SIX = [*TINY_TRAIN, "--set", "algorithm.iterations=6"]


def test_probes_record_when_the_best_changed_with_honest_values(tmp_path):
    out = tmp_path / "run"
    assert cli.main(["train", "--out", str(out), "--set", "run.probe_seconds=1e-9", *SIX]) == 0
    record = json.loads((out / "results.json").read_text())
    probes = record["probes"]
    assert probes and [p["iteration"] for p in probes] == sorted({p["iteration"] for p in probes})
    walls = [p["wall_s"] for p in probes]
    assert walls == sorted(walls) and walls[-1] <= record["wall_s"]
    assert probes[-1]["value"] == record["final_value"]["mean"]
    plain = tmp_path / "plain"
    assert cli.main(["train", "--out", str(plain), *SIX]) == 0
    assert "probes" not in json.loads((plain / "results.json").read_text())
