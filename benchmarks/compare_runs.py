"""JAX timings of two benchmark runs side by side: every rollout, controller-kind and iteration
row the two ``results.json`` files share, the median seconds of each and their ratio, so a
change can be checked for "no slower" on the rows a quick run measures.

    python -m benchmarks --quick                                   # a fresh run (scratch)
    python -m benchmarks.compare_runs benchmarks/results.json $TMPDIR/cognet-benchmarks/results.json

Prints a Markdown table; ``--write FILE`` also writes it. Timings of one machine at different
times differ with its phase (up to 2-2.5x on this VM, benchmarks/README.md), so a ratio is
read against the spread of the rows, not as exact.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

#: (section of results.json, fields naming a row, JAX rows only when the section has ``impl``)
SECTIONS = (
    ("rollouts", ("impl", "nodes", "rollouts")),
    ("controller_kinds", ("kind", "nodes", "rollouts")),
    ("iterations", ("impl", "case")),
)


def rows(results: dict) -> dict[tuple, float]:
    """``{(section, *key): median seconds}`` of the JAX rows of ``results``."""
    out = {}
    for section, fields in SECTIONS:
        for r in results.get(section, []):
            if "impl" in r and not str(r["impl"]).startswith("jax"):
                continue
            out[(section, *(r[f] for f in fields))] = float(r["median_s"])
    return out


def table(before: dict, after: dict) -> list[str]:
    a, b = rows(before), rows(after)
    shared = [k for k in a if k in b]
    lines = [
        f"| row | before ms ({before.get('date', '?')}) | after ms ({after.get('date', '?')}) "
        "| after / before |",
        "|---|---|---|---|",
    ]
    ratios = []
    for key in shared:
        ratio = b[key] / a[key]
        ratios.append(ratio)
        name = " ".join(str(k) for k in key)
        lines.append(f"| {name} | {a[key] * 1e3:.3f} | {b[key] * 1e3:.3f} | {ratio:.2f} |")
    if ratios:
        lines.append(
            f"| median of {len(ratios)} rows | | | {statistics.median(ratios):.2f} "
            f"(range {min(ratios):.2f} - {max(ratios):.2f}) |"
        )
    lines += ["", "The machine's phase: every implementation's rows, after / before (median):", ""]
    for impl, found in sorted(by_impl(before, after).items()):
        lines.append(f"- {impl}: {statistics.median(found):.2f} over {len(found)} rows")
    return lines


def by_impl(before: dict, after: dict) -> dict[str, list[float]]:
    """after / before of every rollout and iteration row, by implementation (JAX and the
    references): when the references slowed as much as JAX, the machine did, not the code."""
    out: dict[str, list[float]] = {}
    for section in ("rollouts", "iterations"):
        old = {
            (r["impl"], r.get("nodes"), r.get("rollouts"), r.get("case")): r["median_s"]
            for r in before.get(section, [])
        }
        for r in after.get(section, []):
            key = (r["impl"], r.get("nodes"), r.get("rollouts"), r.get("case"))
            if key in old:
                out.setdefault(r["impl"], []).append(r["median_s"] / old[key])
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("before", type=Path)
    p.add_argument("after", type=Path)
    p.add_argument("--write", type=Path)
    args = p.parse_args(argv)
    lines = table(json.loads(args.before.read_text()), json.loads(args.after.read_text()))
    print("\n".join(lines))
    if args.write is not None:
        args.write.write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
