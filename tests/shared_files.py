"""The standard benchmark problem files of ../shared/dpomdp, for tests (skipped when absent)."""

from pathlib import Path

import pytest

DPOMDP_DIR = Path(__file__).resolve().parents[2] / "shared" / "dpomdp"


def dpomdp_file(name: str) -> Path:
    """``../shared/dpomdp/NAME.dpomdp``, or skip the calling test when it is not there."""
    path = DPOMDP_DIR / f"{name}.dpomdp"
    if not path.is_file():
        pytest.skip(f"benchmark file not found at {path}")
    return path
