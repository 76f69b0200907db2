"""Same numbers across a change of the code: the first iterations of every built-in experiment,
run by one version of the package and by another, compared bit for bit.

    git worktree add /tmp/before REV                     # the code before the change
    python -m benchmarks.same_numbers run /tmp/sn-before --code /tmp/before  # [NAMES after OUT]
    python -m benchmarks.same_numbers run /tmp/sn-after  # this checkout
    python -m benchmarks.same_numbers compare /tmp/sn-before /tmp/sn-after

``run`` trains each experiment (default: every built-in one of ``--code``) for ``--iterations``
iterations, seed 0, with ``cognet-jax train`` in a fresh process and a compilation cache of its
own, and keeps each results.json; ``compare`` prints one line per experiment, ``same`` or the
fields that differ (``FIELDS``), and exits 1 when any differs. The search's numbers are the
per-iteration records and the honest final value; timings, versions and fields one version
does not write are not compared.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

#: the numbers of a run that a change of the house must not move
FIELDS = (
    "values_per_iteration",
    "in_loop_best_per_iteration",
    "threshold_per_iteration",
    "kept_per_iteration",
    "in_loop_best",
    "final_value",
    "simulated_agent_steps",
)
HERE = Path(__file__).resolve().parent


def experiments(code: Path) -> list[str]:
    """The built-in experiments of the package at ``code``."""
    return sorted(p.stem for p in (code / "cognet_jax" / "experiments").glob("*.toml"))


def run(out: Path, code: Path, names: list[str], iterations: int, overrides: list[str]) -> None:
    out.mkdir(parents=True, exist_ok=True)
    env = {**os.environ, "PYTHONPATH": str(code), "COGNET_JAX_CACHE": str(out / ".cache")}
    for i, name in enumerate(names, 1):
        folder = out / name
        if (folder / "results.json").is_file():
            print(f"[{i}/{len(names)}] {name}: kept", flush=True)
            continue
        cmd = [sys.executable, "-m", "cognet_jax", "train", name, "--seed", "0"]
        cmd += ["--out", str(folder), "--no-progress"]
        cmd += ["--set", f"algorithm.iterations={iterations}"]
        for o in ["run.plots=false", *overrides]:
            cmd += ["--set", o]
        print(f"[{i}/{len(names)}] {name}", flush=True)
        done = subprocess.run(cmd, env=env, cwd=out, capture_output=True, text=True)
        if done.returncode != 0:
            last = (done.stderr.strip().splitlines() or ["(no output)"])[-1]
            (out / f"{name}.failed").write_text(done.stderr)
            print(f"    failed (exit {done.returncode}): {last}", flush=True)


#: results.json fields renamed since: old name -> name of now
RENAMED = {"best_per_iteration": "in_loop_best_per_iteration"}


def _named_now(results: dict) -> dict:
    """``results`` with its fields under the names of now (``RENAMED``): runs of code from
    before a rename compare with runs of now."""
    return {RENAMED.get(k, k): v for k, v in results.items()}


def compare(a: Path, b: Path, write: Path | None = None) -> int:
    lines, differ = [], 0
    for folder in sorted(p for p in a.iterdir() if (p / "results.json").is_file()):
        other = b / folder.name / "results.json"
        if not other.is_file():
            lines.append(f"{folder.name}: missing in {b}")
            differ += 1
            continue
        x, y = (_named_now(json.loads(p.read_text())) for p in (folder / "results.json", other))
        fields = [f for f in FIELDS if f in x and f in y]
        changed = [f for f in fields if x[f] != y[f]]
        lines.append(
            f"{folder.name}: " + (f"DIFFERS in {', '.join(changed)}" if changed else "same")
        )
        differ += bool(changed)
    lines.append(f"{len(lines) - differ} of {len(lines)} experiments the same")
    print("\n".join(lines))
    if write is not None:
        write.write_text("\n".join(lines) + "\n")
    return 1 if differ else 0


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="command", required=True)
    r = sub.add_parser("run", help="train the experiments' first iterations into OUT")
    r.add_argument("out", type=Path)
    r.add_argument("--code", type=Path, default=HERE.parent, help="the checkout to run")
    r.add_argument("--iterations", type=int, default=2)
    r.add_argument("--set", dest="overrides", action="append", default=[])
    r.add_argument("names", nargs="*", help="default: every built-in experiment of --code")
    c = sub.add_parser("compare", help="compare two folders of `run`")
    c.add_argument("a", type=Path)
    c.add_argument("b", type=Path)
    c.add_argument("--write", type=Path, help="also write the lines to this file")
    args = p.parse_args(argv)
    if args.command == "compare":
        return compare(args.a, args.b, args.write)
    code = args.code.resolve()
    run(args.out.resolve(), code, args.names or experiments(code), args.iterations, args.overrides)
    return 0


if __name__ == "__main__":
    sys.exit(main())
