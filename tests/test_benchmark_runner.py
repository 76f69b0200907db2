"""The benchmark runner publishes only full runs (issue: --quick overwrote the published table)."""

import argparse
from pathlib import Path

import pytest

from benchmarks.__main__ import HERE, output_dir


def _args(**kw) -> argparse.Namespace:
    base = dict(quick=False, full=False, parser=False, report_only=False, out=None)
    return argparse.Namespace(**{**base, **kw})


@pytest.mark.parametrize("flags", [{}, {"quick": True}])
def test_smaller_runs_never_write_the_published_table(flags):
    assert output_dir(_args(**flags)) != HERE


@pytest.mark.parametrize("flags", [{"full": True}, {"parser": True}, {"report_only": True}])
def test_full_runs_and_updates_write_the_published_table(flags):
    assert output_dir(_args(**flags)) == HERE


def test_out_overrides(tmp_path: Path):
    assert output_dir(_args(quick=True, out=tmp_path)) == tmp_path
    assert output_dir(_args(full=True, out=tmp_path)) == tmp_path
