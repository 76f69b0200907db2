"""Turns the benchmark runner's measurements into benchmarks/README.md (generated) and, with
``--full``, benchmarks/scaling.png."""

from __future__ import annotations

from pathlib import Path

from benchmarks.paired import CALLS_PER_ROUND, SETTLE_S
from benchmarks.report_pairs import end_to_end_lines, headline, pairs_table

#: Targets of the benchmark issue (2-core CPU).
ROLLOUT_TARGET_RATE = 20e6  # agent-steps/s, 6 nodes, 1e5 rollouts
VEC_RATIO_TARGET = 10.0
LOOP_RATIO_TARGET = 1000.0
SWEEP_RATIO_TARGET = 4.0  # issue 7: 32 seeds in one sweep vs one seed
ITERATION_TARGET_S = 0.050
FULL_RUN_TARGET_S = 30.0
COMPILE_TARGET_S = 10.0


def _ms(row: dict) -> str:
    return f"{row['median_s'] * 1e3:.2f} ({row['min_s'] * 1e3:.2f}-{row['max_s'] * 1e3:.2f})"


def _find(rows: list[dict], **match) -> dict | None:
    for row in rows:
        if all(row.get(k) == v for k, v in match.items()):
            return row
    return None


def _verdict(ok: bool) -> str:
    return "met" if ok else "**missed**"


TORCH_VECTORISED = ("torch-vectorized", "torch-compiled")


def best_torch(rows: list[dict], nodes: int, rollouts: int) -> dict | None:
    """The faster of the eager and the ``torch.compile``d vectorised reference at this size."""
    found = [_find(rows, impl=i, nodes=nodes, rollouts=rollouts) for i in TORCH_VECTORISED]
    found = [r for r in found if r]
    return max(found, key=lambda r: r["rate"]) if found else None


def smallest_torch_ratio(rows: list[dict], impl: str, rollouts: int):
    """``(ratio, nodes, torch row, every ratio as text)`` of the node count where ``impl`` is
    the least ahead of the best torch-vectorised reference at ``rollouts``: the headline is
    the least favourable size measured, not the best. None when nothing is measured."""
    found = []
    for nodes in sorted({r["nodes"] for r in rows if r.get("rollouts") == rollouts}):
        mine, best = (
            _find(rows, impl=impl, nodes=nodes, rollouts=rollouts),
            best_torch(rows, nodes, rollouts),
        )
        if mine and best:
            found.append((mine["rate"] / best["rate"], nodes, best))
    if not found:
        return None
    each = ", ".join(f"{n} nodes {r:.1f}x" for r, n, _ in found)
    ratio, nodes, best = min(found, key=lambda f: f[0])
    return ratio, nodes, best, each


def smallest_paired_ratio(paired: list[dict], impl: str) -> str | None:
    """The target row of ``impl`` against the best torch-vectorised reference in paired rounds
    (``benchmarks.paired``): the size with the smallest median ratio, every size's median and
    its lowest and highest round beside it. None when nothing was measured."""
    found = [(p[impl]["ratio"], p) for p in paired if impl in p]
    if not found:
        return None
    label = ', `run.prng_impl = "hash"` (opt-in generator)' if impl == "jax-hash" else ""
    each = ", ".join(
        f"{p['nodes']} nodes {p[impl]['ratio']:.1f}x (rounds {p[impl]['ratio_min']:.1f}-"
        f"{p[impl]['ratio_max']:.1f}x)"
        for _, p in found
    )
    ratio, worst = min(found, key=lambda f: f[0])
    return (
        f"| >= 10x the best torch-vectorised reference at every size measured, "
        f"{worst['rollouts']:.0e} rollouts{label}, paired rounds (median of "
        f"{worst['rounds']}): the smallest ratio ({worst['nodes']} nodes; {each}) | "
        f"{ratio:.2f}x | {_verdict(ratio >= VEC_RATIO_TARGET)} |"
    )


def paired_table(out: dict) -> list[str]:
    """Each implementation's median ms per call over the paired rounds, and the ratios."""
    paired = out.get("paired") or []
    if not paired:
        return []
    names = list(paired[0]["seconds"])
    lines = [
        "| nodes | rollouts | rounds | "
        + " | ".join(f"{n} ms" for n in names)
        + " | JAX / best torch: median (lowest-highest round) | hash / best torch |",
        "|---" * (len(names) + 5) + "|",
    ]
    for p in paired:
        cells = [f"{p['nodes']}", f"{p['rollouts']:.0e}", f"{p['rounds']}"]
        cells += [f"{p['jax']['median_s'][n] * 1e3:.2f}" for n in names]
        for impl in ("jax", "jax-hash"):
            s = p[impl]
            cells.append(f"{s['ratio']:.1f}x ({s['ratio_min']:.1f}-{s['ratio_max']:.1f}x)")
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def loop_at(rows: list[dict], nodes: int, rollouts: int) -> tuple[dict | None, bool]:
    """The loop reference at this batch size, or (extrapolated) at the largest measured batch
    below it: ``(row, extrapolated)``."""
    exact = _find(rows, impl="torch-loop", nodes=nodes, rollouts=rollouts)
    if exact:
        return exact, False
    below = [
        r
        for r in rows
        if r.get("impl") == "torch-loop" and r["nodes"] == nodes and r["rollouts"] < rollouts
    ]
    if not below:
        return None, False
    return max(below, key=lambda r: r["rollouts"]), True


def _per_core(out: dict, rate: float) -> str:
    cores = out.get("cores")
    return f"{rate / cores / 1e6:.2f}" if cores else ""


def rollout_table(out: dict) -> list[str]:
    rows = out["rollouts"]
    lines = [
        "| nodes | rollouts | JAX ms (min-max) | JAX M agent-steps/s | JAX M/s per core | "
        "JAX hash-PRNG M/s | numpy 1-thread M/s | JAX per core / numpy | torch eager M/s | "
        "torch.compile M/s | JAX / best torch-vec | torch-loop M/s | JAX / torch-loop |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in (r for r in rows if r["impl"] == "jax"):
        n, num = r["nodes"], r["rollouts"]
        fast = _find(rows, impl="jax-hash", nodes=n, rollouts=num)
        eager = _find(rows, impl="torch-vectorized", nodes=n, rollouts=num)
        compiled = _find(rows, impl="torch-compiled", nodes=n, rollouts=num)
        numpy_row = _find(rows, impl="numpy", nodes=n, rollouts=num)
        cores = out.get("cores") or 1
        best = best_torch(rows, n, num)
        loop, extrapolated = loop_at(rows, n, num)
        mark = f" (extrapolated from {loop['rollouts']:.0e})" if loop and extrapolated else ""
        cells = [
            f"{n}",
            f"{num:.0e}",
            _ms(r),
            f"{r['rate'] / 1e6:.2f}",
            _per_core(out, r["rate"]),
            f"{fast['rate'] / 1e6:.2f}" if fast else "",
            f"{numpy_row['rate'] / 1e6:.3f}" if numpy_row else "",
            f"{r['rate'] / cores / numpy_row['rate']:.1f}x" if numpy_row else "",
            f"{eager['rate'] / 1e6:.3f}" if eager else "",
            f"{compiled['rate'] / 1e6:.3f}" if compiled else "",
            f"{r['rate'] / best['rate']:.1f}x" if best else "",
            f"{loop['rate'] / 1e6:.5f}{mark}" if loop else "",
            f"{r['rate'] / loop['rate']:.0f}x{mark}" if loop else "",
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def iteration_table(out: dict) -> list[str]:
    rows = out["iterations"]
    lines = [
        "| case | implementation | ms per iteration (min-max) | compile s | XLA buffers MiB "
        "(args + temps) |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        compile_s = f"{r['compile_s']:.2f}" if r.get("compile_s") is not None else ""
        mem = ""
        if "temp_bytes" in r:
            mem = f"{(r['argument_bytes'] + r['temp_bytes']) / 2**20:.1f}"
        lines.append(f"| {r['case']} | {r['impl']} | {_ms(r)} | {compile_s} | {mem} |")
    return lines


def time_to_value(out: dict) -> list[str]:
    full = out["full_run"]
    n = full["iterations"]
    fv = full["final_value"]
    lines = [
        f"- JAX, measured: `cognet-jax train tagging-thesis-spec-n3` ({n} iterations, no plots) "
        "took "
        f"{full['wall_s']:.1f} s wall, of which {full['compile_s']:.1f} s compile and "
        f"{full['loop_s']:.1f} s for the iterations; honest value {fv['mean']:.3f} +- "
        f"{fv['stderr']:.3f}.",
    ]
    for impl in ("torch-vectorized", "torch-loop"):
        r = _find(out["iterations"], impl=impl, case="COGNet-DICE thesis, 3 nodes")
        if r:
            total = r["median_s"] * n
            lines.append(
                f"- {impl}, **extrapolated** ({n} x the measured median iteration): "
                f"{total:.0f} s ({total / 60:.1f} min), {total / full['wall_s']:.0f}x the JAX run."
            )
    return lines


def targets(out: dict) -> list[str]:
    lines = ["| target | measured | verdict |", "|---|---|---|"]
    first = headline(out)
    if first:
        lines.append(first)
    rows = out["rollouts"]
    for impl, label in (("jax", ""), ("jax-hash", ', `run.prng_impl = "hash"` (opt-in generator)')):
        r6 = _find(rows, impl=impl, nodes=6, rollouts=100_000)
        if not r6:
            continue
        core = _per_core(out, r6["rate"])
        lines.append(
            f"| >= 20 M agent-steps/s, 6 nodes, 1e5 rollouts{label} | {r6['rate'] / 1e6:.2f} M/s"
            f"{f' ({core} per core)' if core else ''} | "
            f"{_verdict(r6['rate'] >= ROLLOUT_TARGET_RATE)} |"
        )
        worst = smallest_torch_ratio(rows, impl, 100_000)
        paired_worst = smallest_paired_ratio(out.get("paired") or [], impl)
        if paired_worst:
            lines.append(paired_worst)
        elif worst:
            ratio, nodes, best, each = worst
            lines.append(
                f"| >= 10x the best torch-vectorised reference at every size measured, 1e5 "
                f"rollouts{label}: the smallest ratio ({nodes} nodes, {best['impl']}; {each}) "
                f"| {ratio:.2f}x | {_verdict(ratio >= VEC_RATIO_TARGET)} |"
            )
        for num in (10_000, 100_000):
            loop, extrapolated = loop_at(rows, 6, num)
            jax_row = _find(rows, impl=impl, nodes=6, rollouts=num)
            if not (loop and jax_row):
                continue
            how = (
                f"loop rate of {loop['rollouts']:.0e} rollouts, extrapolated"
                if extrapolated
                else "both measured"
            )
            ratio = jax_row["rate"] / loop["rate"]
            lines.append(
                f"| >= 1000x torch-loop at {num:.0e} rollouts ({how}){label} | {ratio:.0f}x | "
                f"{_verdict(ratio >= LOOP_RATIO_TARGET)} |"
            )
    sweep = out.get("sweep")
    if sweep:
        how = "each process compiling, cache off, " if sweep.get("cache") == "off" else ""
        lines.append(
            f"| {sweep['seeds']}-seed sweep <= 4x one seed (process wall, {how}median of "
            f"{len(sweep['walls_one'])}) | {sweep['ratio']:.2f}x ({sweep['median_many_s']:.1f} s / "
            f"{sweep['median_one_s']:.1f} s) | {_verdict(sweep['ratio'] <= SWEEP_RATIO_TARGET)} |"
        )
        warm = sweep.get("warm")
        if warm:
            lines.append(
                f"| the same with a warm compilation cache (information: no compile left, the "
                f"32 runs' iterations against one run's) | {warm['ratio']:.2f}x "
                f"({warm['median_many_s']:.1f} s / {warm['median_one_s']:.1f} s) | - |"
            )
    it = _find(out["iterations"], impl="jax", case="COGNet-DICE thesis, 3 nodes")
    if it:
        lines.append(
            f"| thesis iteration <= 50 ms | {it['median_s'] * 1e3:.1f} ms | "
            f"{_verdict(it['median_s'] <= ITERATION_TARGET_S)} |"
        )
        lines.append(
            f"| compile of one iteration <= 10 s | {it['compile_s']:.2f} s | "
            f"{_verdict(it['compile_s'] <= COMPILE_TARGET_S)} |"
        )
    full = out["full_run"]
    lines.append(
        f"| full 500-iteration run <= 30 s incl. compile | {full['wall_s']:.1f} s | "
        f"{_verdict(full['wall_s'] <= FULL_RUN_TARGET_S)} |"
    )
    return lines


def _measured_rate(out: dict, cost: dict) -> float | None:
    """The measured JAX rate of a roofline row: its controller kind at 1e5 rollouts (1e4 when
    absent); rows of older results without a kind are neural controllers."""
    kind, nodes = cost.get("kind"), cost["nodes"]
    for num in (100_000, 10_000):
        row = None
        if kind is not None:
            row = _find(out.get("controller_kinds", []), kind=kind, nodes=nodes, rollouts=num)
        if row is None and (kind is None or kind.startswith("neural")):
            row = _find(out["rollouts"], impl="jax", nodes=nodes, rollouts=num)
        if row:
            return row["rate"]
    return None


def _compute_bound(peak: dict, cost: dict) -> float:
    """Agent-steps/s (millions) if every flop of ``cost`` ran at the measured matmul peak."""
    return peak["matmul_gflops"] * 1e3 / cost["flops"]


def _kind(cost: dict) -> str:
    return cost.get("kind", "neural (COGNet-DICE)")


def roofline(out: dict) -> list[str]:
    """Bound on agent-steps/s from XLA's cost analysis and the measured machine peaks, one
    line per controller kind, and which bound the measured rate is nearer."""
    peak = out.get("machine_peak")
    if not peak:
        return []
    lines = [
        f"Measured peaks: float32 matmul {peak['matmul_gflops']:.0f} GFLOP/s, streaming "
        f"bandwidth {peak['bandwidth_gbs']:.1f} GB/s.",
        "",
        "| controller | nodes | flops / agent-step | bytes / agent-step | compute bound M/s | "
        "all bytes from DRAM M/s | measured M/s (1e5 rollouts) | measured / compute bound | "
        "measured / DRAM estimate |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for c in out.get("rollout_cost", []):
        compute = _compute_bound(peak, c)
        memory = peak["bandwidth_gbs"] * 1e9 / c["bytes"] / 1e6
        rate = _measured_rate(out, c)
        measured = rate / 1e6 if rate else float("nan")
        lines.append(
            f"| {_kind(c)} | {c['nodes']} | {c['flops']:.0f} | "
            f"{c['bytes']:.0f} | {compute:.0f} | {memory:.1f} | {measured:.2f} | "
            f"{measured / compute:.2f} | {measured / memory:.2f} |"
        )
    return lines


def roofline_verdict(out: dict) -> str:
    """What the roofline table says, from its numbers: which kinds run far below their compute
    bound (then moving fewer bytes between kernels is the next factor) and which near it."""
    peak, far, near = out.get("machine_peak"), [], []
    for c in out.get("rollout_cost", []) if peak else []:
        rate = (_measured_rate(out, c) or 0) / 1e6
        name = f"{_kind(c)} at {c['nodes']} nodes"
        (far if rate < 0.5 * _compute_bound(peak, c) else near).append(name)
    text = []
    if far:
        text.append(
            f"Far below the compute bound and near (or above) the DRAM estimate: {', '.join(far)}; "
            "there the next factor comes from moving fewer bytes between kernels (fusing the "
            "simulator step, the controller and the draws of one time step into fewer kernels), "
            "not from faster arithmetic."
        )
    if near:
        text.append(
            f"At half the compute bound or more: {', '.join(near)}; there the operations XLA "
            "counts are the bound, and the next factor needs fewer of them per agent-step (a "
            "rate above the bound means they ran faster than the matmul peak measured)."
        )
    return " ".join(text + ["benchmarks/NOTES.md: the cycles per agent-step by part."])


def parser_table(row: dict) -> list[str]:
    """The parser benchmark row (``benchmarks/parser.py``)."""
    return [
        "| file | states | joint actions / observations | parse s (median) | MB/s | "
        "peak RSS MiB (process) | target |",
        "|---|---|---|---|---|---|---|",
        f"| {row['file_mb']:.1f} MB generated | {row['states']} | {row['joint_actions']} / "
        f"{row['joint_observations']} | {row['parse_s']:.2f} | {row['mb_per_s']:.2f} | "
        f"{row['peak_rss_mib']:.0f} | < 10 s and < 500 MB: "
        f"{_verdict(row['parse_s'] < 10 and row['peak_rss_mib'] * 2**20 < 500e6)} |",
        "",
        f"`{row['command']}`, measured {row['date']}: the model of benchmarks/parser.py (full "
        "2025-number T rows, 640 overriding rows, full O rows, one R line per state and joint "
        f"action), each parse in a fresh process (median of {row['repeats']}; peak RSS is the "
        f"whole process, Python and numpy included, {row['baseline_rss_mib']:.0f} MiB before "
        "the parse). T of this size is stored in float32 (`FLOAT64_T_ENTRIES`).",
    ]


def _algorithm(row: dict) -> str:
    return row.get("algorithm", "COGNet-DICE")  # results written before COG-DICE / G-DICE rows


def controller_kinds_table(out: dict) -> list[str]:
    lines = [
        "| controller | rollouts | ms (min-max) | M agent-steps/s |",
        "|---|---|---|---|",
    ]
    for r in out.get("controller_kinds", []):
        lines.append(f"| {r['kind']} | {r['rollouts']:.0e} | {_ms(r)} | {r['rate'] / 1e6:.2f} |")
    return lines


def scaling_table(out: dict) -> list[str]:
    lines = [
        "| algorithm (base experiment) | varied | value | ms per iteration (min-max) | "
        "compile s | XLA temps MiB | process peak RSS MiB |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in out.get("scaling", []):
        temps = f"{r['temp_bytes'] / 2**20:.1f}" if "temp_bytes" in r else ""
        base = f" ({r['experiment']})" if "experiment" in r else ""
        lines.append(
            f"| {_algorithm(r)}{base} | {r['axis']} | {r['value']} | {_ms(r)} | "
            f"{r['compile_s']:.2f} | {temps} | {r['rss_mib']:.0f} |"
        )
    return lines


def write_plots(out: dict, folder: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = out["scaling"]
    algorithms = list(dict.fromkeys(_algorithm(r) for r in rows))
    axes_names = ["rollouts", "horizon", "nodes"]
    fig, axes = plt.subplots(1, 4, figsize=(17, 4))
    for algorithm in algorithms:
        mine = [r for r in rows if _algorithm(r) == algorithm]
        for ax, name in zip(axes, axes_names, strict=False):
            pts = [r for r in mine if r["axis"] == name]
            ax.plot(
                [r["value"] for r in pts],
                [r["median_s"] * 1e3 for r in pts],
                "o-",
                label=algorithm,
            )
        pts = [r for r in mine if r["axis"] == "rollouts" and "temp_bytes" in r]
        axes[3].plot(
            [r["value"] for r in pts], [r["temp_bytes"] / 2**20 for r in pts], "o-", label=algorithm
        )
    for ax, name in zip(axes, axes_names, strict=False):
        ax.set_xlabel(f"{name} per iteration" if name == "rollouts" else name)
        ax.set_ylabel("ms per iteration")
        ax.set_yscale("log")
        if name == "rollouts":
            ax.set_xscale("log")
        ax.grid(alpha=0.3)
    axes[0].legend()
    axes[3].set_xscale("log")
    axes[3].set_yscale("log")
    axes[3].set_xlabel("rollouts per iteration")
    axes[3].set_ylabel("XLA temporaries, MiB")
    axes[3].grid(alpha=0.3)
    fig.suptitle(
        "iteration time, one size varied (COGNet-DICE: tagging thesis, 3 nodes; COG-DICE: "
        "tagging thesis budget; G-DICE: tagging paper setting, d = 1)"
    )
    fig.tight_layout()
    path = folder / "scaling.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def _pairs_run(out: dict) -> str:
    """When the paired iterations and the end-to-end pair were measured, if apart from the
    rest (``--pairs``)."""
    run = out.get("pairs_run")
    if not run:
        return ""
    return f"Measured {run['date']} (load average {run['load_average'][0]:.2f}). "


def write_readme(out: dict, path: Path, notes: str = "") -> None:
    """The generated README: machine, command, every table; ``notes`` (hand-written analysis
    kept in benchmarks/NOTES.md) is appended as is."""
    notes_file = path.parent / "NOTES.md"
    if not notes and notes_file.exists():
        notes = notes_file.read_text()
    lines = [
        "# Benchmarks",
        "",
        "Generated by `python -m benchmarks` (do not edit by hand; the analysis at the end is "
        "benchmarks/NOTES.md).",
        "",
        f"- Machine: {out['machine']}; Python {out['python']}, jax {out['jax']}, "
        f"{out['torch'] or 'torch not installed'}.",
        f"- Command: `{out['command']}`, run {out['date']}; load average before "
        f"{out['load_average_before'][0]:.2f}, after {out['load_average_after'][0]:.2f}; "
        f"whole benchmark {out['benchmark_s']:.0f} s; peak RSS {out['peak_rss_mib']:.0f} MiB.",
        "- Timings: median of >= 5 calls (min-max in brackets) after a warm-up call and at "
        "least 0.5 s of further calls (`benchmarks.timing.WARMUP_S`, JAX and torch alike), "
        "compile time measured apart (ahead-of-time `lower().compile()`).",
        "",
        "## Targets",
        "",
        *targets(out),
        "",
        "## Rollout throughput (tagging, thesis setting, h 3, 2 agents, neural controllers)",
        "",
        *rollout_table(out),
        "",
        "Agent-steps/s = rollouts x horizon x agents / seconds; per core = that / the machine's "
        "logical CPUs (every implementation may use all of them: XLA's and torch's thread pools). "
        "Every ratio divides rates at the same batch size; the loop reference is measured up to "
        "1e4 rollouts, and a cell marked 'extrapolated' uses its 1e4 rate at 1e5. The JAX "
        "policy is an argument of the compiled program (as in the search), not a constant. "
        "torch eager / torch.compile: the vectorised reference as written, and with each time "
        "step compiled by `torch.compile` (inductor); both draw only the uniforms the setting "
        "uses (none for the noise-free simulator here, as XLA drops them on the JAX side); "
        "'best torch-vec' is the faster of the two at that size. JAX hash-PRNG: the same "
        'rollouts driven by the opt-in counter-based generator (`run.prng_impl = "hash"`, '
        "`cognet_jax/prng.py`); the ratio columns use the default generator. numpy 1-thread: "
        "the same rollouts vectorised in numpy (`benchmarks/numpy_reference.py`; elementwise "
        "kernels and `np.einsum` on one thread), compared with JAX's rate per core.",
        "",
    ]
    if out.get("paired"):
        lines += [
            "### Paired rounds (the 10x targets)",
            "",
            *paired_table(out),
            "",
            f"Each round runs every implementation in turn, {SETTLE_S:g} s of untimed calls "
            f"(at least one), then {CALLS_PER_ROUND} timed calls (their median), so "
            "JAX and torch meet the same phase of this VM, which runs for seconds at a time up "
            "to 2-2.5x slower; a round's ratio is the faster torch reference's time over "
            "JAX's, and the targets take the median over the rounds (`benchmarks/paired.py`). "
            "The table above times each implementation in a block of its own, seconds apart.",
            "",
        ]
    if out.get("controller_kinds"):
        lines += [
            "### Every controller kind (JAX, tagging h 3, 6 nodes, default generator)",
            "",
            *controller_kinds_table(out),
            "",
            "One controller drawn from each algorithm's initial distribution: the neural one "
            "(the rows above), the region controller of COG-DICE, and the tabular controller of "
            "G-DICE on observations discretised by 1 (tagging-paper-gdice-d1's env at h 3). "
            "No torch reference exists for the last two.",
            "",
        ]
    if out.get("iteration_pairs"):
        lines += [
            "## What a user runs, against torch (paired rounds)",
            "",
            *pairs_table(out),
            "",
            _pairs_run(out)
            + "`python -m benchmarks --pairs` (`benchmarks/iteration_pairs.py`): one whole search "
            "iteration as a run compiles it (state carried from call to call), against the same "
            "algorithm and sizes in `benchmarks/torch_reference` (the thesis variant: "
            "`vectorized.py`; the default: `weights.py`), eager and `torch.compile`d, in paired "
            "rounds as above; the ratio takes the faster torch reference of each round. The "
            "default runs the library's defaults (tied structures, restarts, a pool of 4 best "
            "policies raced on fresh rollouts). The ceiling bounds the ratio from the rollouts "
            "alone: the row's faster torch time over the time its agent-steps take at the rate "
            "of JAX's rollout kernel in this run (the rollouts row of the same nodes); where it "
            "is below the target, no cheaper rest of the iteration reaches the target without "
            "a faster rollout kernel.",
            "",
        ]
    if out.get("end_to_end"):
        lines += ["## Time to value, end to end (measured)", "", *end_to_end_lines(out), ""]
    lines += [
        "## One search iteration",
        "",
        *iteration_table(out),
        "",
        "## Time to value (tagging-thesis-spec-n3)",
        "",
        *time_to_value(out),
        "",
        "## Roofline (rollouts, JAX)",
        "",
        *roofline(out),
        "",
        "Flops and bytes per agent-step are XLA's cost analysis of the compiled rollout program "
        "(bytes = traffic between compiled kernels); compute bound = matmul peak / flops; "
        "all bytes from DRAM = streaming bandwidth / bytes, the rate if every byte between "
        "kernels went to main memory (measured above it means part of that traffic stays in "
        "cache).",
        "",
        roofline_verdict(out),
        "",
    ]
    if out.get("parser"):
        lines += ["## MADP parser", "", *parser_table(out["parser"]), ""]
    if out.get("scaling"):
        lines += [
            "## Scaling (one size varied from each algorithm's base experiment)",
            "",
            *scaling_table(out),
            "",
            "![scaling](scaling.png)",
            "",
        ]
    if notes:
        lines += [notes.rstrip(), ""]
    path.write_text("\n".join(lines))
