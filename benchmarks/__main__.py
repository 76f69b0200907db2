"""Benchmark runner: ``python -m benchmarks [--quick|--full]``.

Measures, in one process and one session, cognet_jax against the PyTorch references of
``benchmarks/torch_reference`` (when torch is installed) on the same machine and the same work,
then writes ``results.json`` and the generated ``README.md``: into ``benchmarks/`` (the published
table) for ``--full``, ``--parser`` and ``--report-only``; into a scratch folder
(``$TMPDIR/cognet-benchmarks``) for the default and ``--quick`` runs, so a smaller run never
overwrites the published figures; ``--out DIR`` chooses another folder.

* rollout throughput (agent-steps/s) on tagging (thesis setting, h 3) with 3- and 6-node neural
  controllers at 1e3, 1e4, 1e5 rollouts (``--quick``: 1e3, 1e4): JAX (default threefry2x32
  generator, and the opt-in ``hash`` generator), torch-vectorised, torch-loop, with ratios;
  the 10x targets' ratios at 1e5 (not with ``--quick``) in paired rounds, JAX and torch timed
  back to back (``benchmarks.paired``);
* one COGNet-DICE iteration at the thesis settings (3 and 6 nodes): JAX vs both references; one
  iteration of COG-DICE (region controllers) and G-DICE (tabular controllers) in JAX;
* time-to-value: a full ``tagging-thesis-spec-n3`` run (JAX, measured) against the references'
  per-iteration time x 500 (extrapolated);
* ``--pairs`` (and ``--full`` with torch): what a user runs against torch -- one whole search
  iteration of the thesis variant and of the default ``cognet-dice`` (3 and 6 nodes, and the
  paper setting at a tenth of its iteration) and rollouts at 1e4, in paired rounds
  (``benchmarks.iteration_pairs``), and a whole ``cognet-jax train`` against a whole torch run,
  cold and warm caches (``benchmarks.end_to_end``); ``--pairs`` alone merges them into
  ``benchmarks/results.json`` and README.md;
* ``--full``: scaling of the COGNet-DICE iteration time with rollouts (1e3..1e6), horizon
  (3..150) and nodes (3..32), XLA buffer memory vs rollouts, and a PNG of the curves; and the
  wall time of a 32-seed ``cognet-jax sweep tagging-thesis-spec-n3`` against one seed (fresh
  processes, median of 3 each).

Every timing is the median of >= 5 runs after a warm-up (min-max beside it), compile time apart;
a paired ratio is the median over 11 rounds of 3 calls each.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import jax

from benchmarks import jax_cases, numpy_reference, paired, torch_cases
from benchmarks.report import TORCH_VECTORISED, write_plots, write_readme
from benchmarks.timing import peak_rss_mib

HERE = Path(__file__).resolve().parent
RUNS = 5

#: (label, experiment, overrides) of the single-iteration cases
ITERATION_CASES = [
    ("COGNet-DICE thesis, 3 nodes", "tagging-thesis-spec-n3", []),
    ("COGNet-DICE thesis, 6 nodes", "tagging-thesis-spec-n6", []),
    ("COG-DICE thesis budget, 3 nodes", "tagging-thesis-cogdice-n3", []),
    ("COG-DICE paper setting (h 150)", "tagging-paper-cogdice", []),
    ("G-DICE paper setting, d = 1 (h 150)", "tagging-paper-gdice-d1", []),
]


def machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} logical CPUs"


def timing_row(timing, **fields) -> dict:
    return dict(
        fields,
        median_s=timing.median_s,
        min_s=timing.min_s,
        max_s=timing.max_s,
        runs=timing.runs,
        compile_s=timing.compile_s,
    )


#: the loop reference is measured up to this batch; larger batches are extrapolated from it
LOOP_MAX_ROLLOUTS = 10_000


def measure_rollouts(sizes: list[int], with_torch: bool, log) -> list[dict]:
    """Rollout throughput at each batch size: JAX (both generators) and, with torch, the eager
    and ``torch.compile``d vectorised references and the loop reference (measured up to
    ``LOOP_MAX_ROLLOUTS``; its rate at larger batches is that of the largest measured one)."""
    rows = []
    for nodes in (3, 6):
        for num in sizes:
            timing, rate = jax_cases.rollout_throughput(nodes, num, RUNS)
            rows.append(timing_row(timing, impl="jax", nodes=nodes, rollouts=num, rate=rate))
            log(f"rollouts jax       nodes={nodes} R={num}: {timing.row()}, {rate / 1e6:.2f} M/s")
            timing, rate = jax_cases.rollout_throughput(nodes, num, RUNS, prng="hash")
            rows.append(timing_row(timing, impl="jax-hash", nodes=nodes, rollouts=num, rate=rate))
            log(f"rollouts jax-hash  nodes={nodes} R={num}: {timing.row()}, {rate / 1e6:.2f} M/s")
            timing, rate = numpy_reference.throughput(nodes, num, RUNS)
            rows.append(timing_row(timing, impl="numpy", nodes=nodes, rollouts=num, rate=rate))
            log(f"rollouts numpy     nodes={nodes} R={num}: {timing.row()}, {rate / 1e6:.3f} M/s")
            if not with_torch:
                continue
            impls = ["torch-vectorized", "torch-compiled"]
            if num <= LOOP_MAX_ROLLOUTS:
                impls.append("torch-loop")
            for impl in impls:
                runs = 3 if impl == "torch-loop" and num > 1_000 else RUNS
                timing, rate = torch_cases.rollout_throughput(impl, nodes, num, runs)
                rows.append(timing_row(timing, impl=impl, nodes=nodes, rollouts=num, rate=rate))
                log(f"rollouts {impl} nodes={nodes} R={num}: {timing.row()}, {rate / 1e6:.4f} M/s")
    return rows


def measure_paired(log, num: int = 100_000) -> list[dict]:
    """The headline ratios in paired rounds (``benchmarks.paired``): at 3 and 6 nodes, ``num``
    rollouts, both JAX generators against the eager and ``torch.compile``d references."""
    rows = []
    for nodes in (3, 6):
        calls = {
            "jax": jax_cases.rollout_call(nodes, num),
            "jax-hash": jax_cases.rollout_call(nodes, num, prng="hash"),
            **{impl: torch_cases.rollout_call(impl, nodes, num) for impl in TORCH_VECTORISED},
        }
        seconds = paired.paired_rounds(calls)
        row = dict(nodes=nodes, rollouts=num, rounds=len(seconds["jax"]), seconds=seconds)
        for impl in ("jax", "jax-hash"):
            row[impl] = s = paired.summary(seconds, impl, list(TORCH_VECTORISED))
            log(
                f"paired {impl} nodes={nodes} R={num}: {s['ratio']:.2f}x the best torch "
                f"(rounds {s['ratio_min']:.2f}-{s['ratio_max']:.2f}x; "
                + ", ".join(f"{k} {v * 1e3:.2f} ms" for k, v in s["median_s"].items())
                + ")"
            )
        rows.append(row)
    return rows


def measure_controller_kinds(sizes: list[int], log) -> list[dict]:
    """JAX rollout throughput of each controller kind (neural, regions, tabular), 6 nodes."""
    rows = []
    for kind in jax_cases.CONTROLLER_KINDS:
        for num in sizes:
            timing, rate = jax_cases.controller_throughput(kind, 6, num, RUNS)
            rows.append(timing_row(timing, kind=kind, nodes=6, rollouts=num, rate=rate))
            log(f"rollouts {kind} nodes=6 R={num}: {timing.row()}, {rate / 1e6:.2f} M/s")
    return rows


def measure_iterations(with_torch: bool, quick: bool, log) -> list[dict]:
    rows = []
    for label, experiment, sets in ITERATION_CASES:
        timing, memory = jax_cases.iteration(experiment, sets, runs=10)
        rows.append(timing_row(timing, impl="jax", case=label, experiment=experiment, **memory))
        log(f"iteration jax {label}: {timing.row()}, compile {timing.compile_s:.2f} s")
    if with_torch:
        for nodes in (3, 6):
            label = f"COGNet-DICE thesis, {nodes} nodes"
            for impl in ("torch-vectorized", "torch-compiled", "torch-loop"):
                runs = 2 if (quick and impl == "torch-loop") else RUNS
                timing = torch_cases.iteration(impl, nodes, runs)
                rows.append(timing_row(timing, impl=impl, case=label))
                log(f"iteration {impl} {label}: {timing.row()}")
    return rows


#: (algorithm, experiment, rollout-axis cases): one size varied at a time from each base.
#: COGNet-DICE varies K_roll (its 100 candidates x 100 evaluations stay); the sample-based
#: algorithms vary the number of samples, so the rollouts per iteration are samples x N_sim.
SCALING_BASES = (
    (
        "COGNet-DICE",
        "tagging-thesis-spec-n3",
        [(n, [f"algorithm.rollouts={n}"]) for n in (1_000, 10_000, 100_000, 1_000_000)],
    ),
    (
        "COG-DICE",
        "tagging-thesis-cogdice-n3",  # 100 samples x 100 rollouts, h 3
        [(s * 100, [f"algorithm.samples={s}"]) for s in (10, 100, 1_000, 10_000)],
    ),
    (
        "G-DICE",
        "tagging-paper-gdice-d1",  # 4000 samples x 25 rollouts, h 150
        [(s * 25, [f"algorithm.samples={s}"]) for s in (100, 400, 4_000, 40_000)],
    ),
)


def scaling_cases() -> list[tuple[str, str, str, int, list[str]]]:
    """``(algorithm, experiment, axis, value, overrides)`` of every scaling measurement, each
    config checked (``load_config``) so that a bad case fails before the long measurements."""
    from cognet_jax.registry import load_config

    cases = []
    for algorithm, experiment, rollout_cases in SCALING_BASES:
        cases += (
            [(algorithm, experiment, "rollouts", n, sets) for n, sets in rollout_cases]
            + [
                (algorithm, experiment, "horizon", h, [f"env.horizon={h}"])
                for h in (3, 10, 30, 100, 150)
            ]
            + [
                (algorithm, experiment, "nodes", n, [f"algorithm.nodes={n}"])
                for n in (3, 6, 12, 24, 32)
            ]
        )
    for _, experiment, _, _, sets in cases:
        load_config(experiment, sets)
    return cases


def measure_scaling(cases, log) -> list[dict]:
    """Iteration time of each algorithm (from its base experiment) when one size changes:
    rollouts per iteration, horizon, nodes."""
    rows = []
    for algorithm, experiment, axis, value, sets in cases:
        runs = 3 if (axis == "rollouts" and value >= 1_000_000) else RUNS
        timing, memory = jax_cases.iteration(experiment, sets, runs=runs)
        rows.append(
            timing_row(
                timing,
                algorithm=algorithm,
                experiment=experiment,
                axis=axis,
                value=value,
                rss_mib=peak_rss_mib(),
                **memory,
            )
        )
        log(f"scaling {algorithm} {axis}={value}: {timing.row()}, compile {timing.compile_s:.2f} s")
    return rows


def output_dir(args: argparse.Namespace) -> Path:
    """Where results.json and README.md go: the published ``benchmarks/`` only for ``--full``
    (and ``--parser`` / ``--report-only``, which update it), a scratch folder otherwise."""
    if args.out is not None:
        return args.out
    if args.full or args.parser or args.pairs or args.report_only:
        return HERE
    return Path(tempfile.gettempdir()) / "cognet-benchmarks"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description="cognet_jax benchmarks against PyTorch references")
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--quick", action="store_true", help="smaller sizes (about 2 minutes)")
    mode.add_argument("--full", action="store_true", help="also the scaling curves")
    p.add_argument("--no-torch", action="store_true", help="JAX only")
    p.add_argument("--no-write", action="store_true", help="print only, write nothing")
    p.add_argument("--report-only", action="store_true", help="rewrite README.md from results.json")
    p.add_argument(
        "--out",
        type=Path,
        default=None,
        help="folder for results.json, README.md and plots (default: benchmarks/ for --full, "
        "--parser and --report-only; a scratch folder under the system temp dir otherwise, so "
        "a smaller run never overwrites the published table)",
    )
    p.add_argument(
        "--pairs",
        action="store_true",
        help="measure only what a user runs against torch (whole iterations in paired rounds, "
        "whole runs end to end) and merge it into results.json and README.md",
    )
    p.add_argument(
        "--parser",
        action="store_true",
        help="measure only the MADP parser row and merge it into results.json and README.md",
    )
    args = p.parse_args(argv)
    out_dir = output_dir(args)
    out_dir.mkdir(parents=True, exist_ok=True)
    if args.parser:
        from benchmarks.parser import measure_parser

        row = measure_parser(Path(tempfile.mkdtemp(prefix="cognet-parser-")))
        row.update(
            command="python -m benchmarks --parser",
            date=time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        )
        if not args.no_write:
            out = json.loads((out_dir / "results.json").read_text())
            out["parser"] = row
            (out_dir / "results.json").write_text(json.dumps(out, indent=1))
            write_readme(out, out_dir / "README.md")
        return 0
    if args.pairs:
        from benchmarks import end_to_end, iteration_pairs

        out = json.loads((out_dir / "results.json").read_text())
        load = os.getloadavg()
        out["iteration_pairs"] = iteration_pairs.measure(print)
        out["end_to_end"] = end_to_end.measure(print)
        out["pairs_run"] = dict(
            command="python -m benchmarks --pairs",
            date=time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
            load_average=load,
        )
        if not args.no_write:
            (out_dir / "results.json").write_text(json.dumps(out, indent=1))
            write_readme(out, out_dir / "README.md")
        return 0
    if args.report_only:
        out = json.loads((out_dir / "results.json").read_text())
        if out.get("scaling"):
            write_plots(out, out_dir)
        write_readme(out, out_dir / "README.md")
        return 0
    with_torch = not args.no_torch and torch_cases.available()

    def log(text: str) -> None:
        print(text, flush=True)

    flag = " --quick" if args.quick else " --full" if args.full else ""
    command = "python -m benchmarks" + flag
    out: dict = {
        "machine": machine(),
        "cores": os.cpu_count(),
        "python": platform.python_version(),
        "jax": jax.__version__,
        "torch": torch_cases.version() if with_torch else None,
        "command": command,
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "load_average_before": os.getloadavg(),
    }
    cases = scaling_cases() if args.full else []
    t0 = time.perf_counter()
    sizes = [1_000, 10_000] if args.quick else [1_000, 10_000, 100_000]
    out["rollouts"] = measure_rollouts(sizes, with_torch, log)
    if with_torch and not args.quick:
        out["paired"] = measure_paired(log)
    out["controller_kinds"] = measure_controller_kinds(sizes, log)
    out["iterations"] = measure_iterations(with_torch, args.quick, log)
    wall, results = jax_cases.full_run()
    out["full_run"] = dict(
        experiment="tagging-thesis-spec-n3",
        wall_s=wall,
        compile_s=results["compile_s"],
        loop_s=results["loop_s"],
        iterations=results["iterations"],
        final_value=results["final_value"],
    )
    log(f"full tagging-thesis-spec-n3 run: {wall:.1f} s (compile {results['compile_s']:.1f} s)")
    if args.full and with_torch:
        from benchmarks import end_to_end, iteration_pairs

        out["iteration_pairs"] = iteration_pairs.measure(log)
        out["end_to_end"] = end_to_end.measure(log)
    if args.full:
        out["scaling"] = measure_scaling(cases, log)
        out["sweep"] = jax_cases.sweep_ratio()
        s = out["sweep"]
        log(
            f"sweep {s['seeds']} seeds vs 1: {s['median_many_s']:.1f} s / {s['median_one_s']:.1f} s"
        )
    from benchmarks.parser import measure_parser

    out["parser"] = measure_parser(Path(tempfile.mkdtemp(prefix="cognet-parser-")), log=log)
    out["parser"].update(command=command, date=out["date"])
    out["machine_peak"] = jax_cases.machine_peak()
    neural = next(iter(jax_cases.CONTROLLER_KINDS))
    out["rollout_cost"] = [jax_cases.rollout_cost(neural, 3)] + [
        jax_cases.rollout_cost(kind, 6) for kind in jax_cases.CONTROLLER_KINDS
    ]
    log(f"machine peak: {out['machine_peak']}; rollout cost: {out['rollout_cost']}")
    out["peak_rss_mib"] = peak_rss_mib()
    out["load_average_after"] = os.getloadavg()
    out["benchmark_s"] = time.perf_counter() - t0
    if not args.no_write:
        (out_dir / "results.json").write_text(json.dumps(out, indent=1))
        if args.full:
            write_plots(out, out_dir)
        write_readme(out, out_dir / "README.md")
        log(f"wrote {out_dir / 'results.json'} and {out_dir / 'README.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
