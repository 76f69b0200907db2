"""The benchmark runner publishes only full runs (issue: --quick overwrote the published table)."""

import argparse
from pathlib import Path

import pytest

from benchmarks.__main__ import HERE, output_dir


def _args(**kw) -> argparse.Namespace:
    base = dict(quick=False, full=False, parser=False, pairs=False, report_only=False, out=None)
    return argparse.Namespace(**{**base, **kw})


@pytest.mark.parametrize("flags", [{}, {"quick": True}])
def test_smaller_runs_never_write_the_published_table(flags):
    assert output_dir(_args(**flags)) != HERE


@pytest.mark.parametrize(
    "flags", [{"full": True}, {"parser": True}, {"pairs": True}, {"report_only": True}]
)
def test_full_runs_and_updates_write_the_published_table(flags):
    assert output_dir(_args(**flags)) == HERE


def test_out_overrides(tmp_path: Path):
    assert output_dir(_args(quick=True, out=tmp_path)) == tmp_path
    assert output_dir(_args(full=True, out=tmp_path)) == tmp_path


def test_torch_headline_is_the_least_favourable_size():
    from benchmarks.report import smallest_torch_ratio

    rows = [
        {"impl": "jax", "nodes": 3, "rollouts": 100_000, "rate": 84.0},
        {"impl": "torch-compiled", "nodes": 3, "rollouts": 100_000, "rate": 16.8},
        {"impl": "torch-vectorized", "nodes": 3, "rollouts": 100_000, "rate": 5.0},
        {"impl": "jax", "nodes": 6, "rollouts": 100_000, "rate": 69.0},
        {"impl": "torch-compiled", "nodes": 6, "rollouts": 100_000, "rate": 4.6},
        {"impl": "jax", "nodes": 6, "rollouts": 10_000, "rate": 1.0},
    ]
    ratio, nodes, best, each = smallest_torch_ratio(rows, "jax", 100_000)
    assert (round(ratio, 6), nodes, best["impl"]) == (5.0, 3, "torch-compiled")
    assert each == "3 nodes 5.0x, 6 nodes 15.0x"


def test_roofline_section_defines_its_columns_and_reads_its_numbers(tmp_path: Path):
    """The README's roofline paragraph, written from the published results.json: the columns
    defined, and each controller kind named on the side of half its compute bound that its
    table row shows (it once printed a stray 'cache).' instead, when a kind ran near it)."""
    import json

    from benchmarks.report import write_readme

    write_readme(json.loads((HERE / "results.json").read_text()), tmp_path / "README.md")
    section = (tmp_path / "README.md").read_text().split("## Roofline")[1].split("\n## ")[0]
    assert "compute bound = matmul peak / flops" in section
    rows = [line.split(" | ") for line in section.splitlines() if line.startswith("| ")][2:]
    assert rows
    far = section.split("Far below the compute bound")[-1].split(";")[0]
    near = section.split("At half the compute bound or more")[-1].split(";")[0]
    for row in rows:
        name = f"{row[0].strip('| ')} at {row[1]} nodes"
        assert name in (near if float(row[7]) >= 0.5 else far), (name, row[7])


def test_paired_rounds_time_every_implementation_in_each_round(monkeypatch):
    """Each round calls every implementation in turn; a round's ratio is the fastest torch
    reference's seconds over JAX's, and the headline the median over rounds."""
    from benchmarks import paired

    order = []
    monkeypatch.setattr(paired, "warm_up", lambda call, **kw: order.append("settle"))
    calls = {name: (lambda n=name: order.append(n)) for name in ("jax", "tv", "tc")}
    seconds = paired.paired_rounds(calls, rounds=2, per_round=1)
    assert order[:3] == ["settle"] * 3  # each warmed up once first
    assert order[3:] == ["settle", "jax", "settle", "tv", "settle", "tc"] * 2
    assert all(len(s) == 2 for s in seconds.values())
    fake = {"jax": [1.0, 2.0, 1.0], "tv": [30.0, 30.0, 30.0], "tc": [12.0, 40.0, 9.0]}
    assert paired.round_ratios(fake, "jax", ["tv", "tc"]) == [12.0, 15.0, 9.0]
    s = paired.summary(fake, "jax", ["tv", "tc"])
    assert (s["ratio"], s["ratio_min"], s["ratio_max"]) == (12.0, 9.0, 15.0)


def test_paired_headline_is_the_least_favourable_size():
    from benchmarks.report import smallest_paired_ratio

    def size(nodes, ratio):
        s = dict(ratio=ratio, ratio_min=ratio - 1, ratio_max=ratio + 1)
        return {"nodes": nodes, "rollouts": 100_000, "rounds": 11, "jax": s}

    row = smallest_paired_ratio([size(3, 9.5), size(6, 19.0)], "jax")
    assert "| 9.50x | **missed** |" in row and "(3 nodes;" in row
    assert "3 nodes 9.5x (rounds 8.5-10.5x), 6 nodes 19.0x (rounds 18.0-20.0x)" in row
    assert smallest_paired_ratio([size(3, 9.5)], "jax-hash") is None


def test_headline_is_the_least_favourable_of_every_ratio_against_its_target():
    """Iterations, rollouts and whole runs: the headline is the row furthest below its
    target (a whole cold run at 1.5x of a 2x target is worse than an iteration at 9x of 10x)."""
    from benchmarks.report_pairs import headline

    def pair(case, ratio):
        return dict(case=case, ratio=ratio, rounds=11)

    out = {
        "iteration_pairs": [pair("iteration: default, 3 nodes", 9.0), pair("rollouts", 14.0)],
        "paired": [{"nodes": 3, "rollouts": 100_000, "jax": {"ratio": 13.0}}],
        "end_to_end": {"experiment": "e", "ratio_warm": 12.0, "ratio_cold": 1.5},
    }
    line = headline(out)
    assert "cold caches, target 2x | 1.50x | **missed** |" in line
    assert "(3 of 5 rows at their target)" in line
    out["end_to_end"]["ratio_cold"] = 2.5
    assert "iteration: default, 3 nodes (paired rounds, median of 11), target 10x | 9.00x" in (
        headline(out)
    )
    assert headline({}) is None
