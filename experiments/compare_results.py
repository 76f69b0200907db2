"""Check that re-run experiments reproduce their saved results: every ``results.json`` below
experiments/results that differs from its committed version (``git show REV:path``) is compared
field by field, timings and versions aside (fields the saved file does not have yet, such as
config fields added later with their defaults, are not compared).

    python experiments/tagging.py tagging-thesis-n3 --seeds 0   # re-run something
    python experiments/compare_results.py                       # against HEAD
    python experiments/compare_results.py --rev main~3

Prints one line per changed file: ``same`` when only timings changed, else the fields that
differ. Exit status 1 when any result differs.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
#: fields that legitimately change from run to run on the same machine
VOLATILE = {
    "wall_s",
    "compile_s",
    "loop_s",
    "eval_s",
    "seconds",
    "jax_version",
    "backend",
    "timing",
}


def changed_files(rev: str) -> list[str]:
    out = subprocess.run(
        ["git", "diff", "--name-only", rev, "--", "experiments/results"],
        capture_output=True,
        text=True,
        check=True,
        cwd=HERE.parent,
    ).stdout
    return [line for line in out.splitlines() if line.endswith("results.json")]


def differences(old, new, path: str = "") -> list[str]:
    """Dotted paths where two JSON values differ (volatile keys skipped)."""
    if isinstance(old, dict) and isinstance(new, dict):
        out = []
        for key in sorted(set(old) | set(new)):
            if key in VOLATILE or key not in old:  # a field added since: not a result
                continue
            out += differences(old.get(key), new.get(key), f"{path}.{key}" if path else key)
        return out
    return [] if old == new else [path or "(value)"]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rev", default="HEAD")
    args = parser.parse_args(argv)
    bad = 0
    files = changed_files(args.rev)
    for name in files:
        shown = subprocess.run(
            ["git", "show", f"{args.rev}:{name}"], capture_output=True, text=True, cwd=HERE.parent
        )
        if shown.returncode != 0:
            print(f"{name}: new (no committed version)")
            continue
        diff = differences(json.loads(shown.stdout), json.loads((HERE.parent / name).read_text()))
        bad += bool(diff)
        print(f"{name}: {'same' if not diff else 'DIFFERS in ' + ', '.join(diff[:8])}")
    print(f"{len(files)} changed results files, {bad} with different results")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
