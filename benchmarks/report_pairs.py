"""The README's tables of what a user runs against torch: whole iterations and rollouts at 1e4
in paired rounds (``benchmarks.iteration_pairs``), whole runs end to end
(``benchmarks.end_to_end``), and the headline: the least favourable of all these ratios."""

from __future__ import annotations

import math
import statistics

#: issue 55's targets: every search-iteration row, and a whole run warm / cold
ITERATION_RATIO_TARGET = 10.0
END_TO_END_WARM_TARGET = 10.0
END_TO_END_COLD_TARGET = 2.0


def _verdict(ok: bool) -> str:
    return "met" if ok else "**missed**"


def ratios(out: dict) -> list[tuple[str, float, float]]:
    """``(what, ratio, target)`` of every measured row: the paired iterations and rollouts
    (``iteration_pairs``), the rollouts at 1e5 (``paired``) and the end-to-end pair."""
    found = [
        (
            f"{r['case']} (paired rounds, median of {r['rounds']})",
            r["ratio"],
            ITERATION_RATIO_TARGET,
        )
        for r in out.get("iteration_pairs") or []
    ]
    for p in out.get("paired") or []:
        what = f"rollouts: {p['rollouts']:.0e}, {p['nodes']} nodes (paired rounds)"
        found.append((what, p["jax"]["ratio"], ITERATION_RATIO_TARGET))
    e2e = out.get("end_to_end")
    if e2e:
        run = f"whole run `cognet-jax train {e2e['experiment']}` against the torch.compile run"
        found.append((f"{run}, warm caches", e2e["ratio_warm"], END_TO_END_WARM_TARGET))
        found.append((f"{run}, cold caches", e2e["ratio_cold"], END_TO_END_COLD_TARGET))
    return found


def headline(out: dict) -> str | None:
    """The targets table's first row: the ratio furthest below (or least above) its target."""
    found = ratios(out)
    if not found:
        return None
    what, ratio, target = min(found, key=lambda f: f[1] / f[2])
    met = sum(r >= t for _, r, t in found)
    return (
        f"| **headline**: the least favourable of every ratio against torch below ({met} of "
        f"{len(found)} rows at their target): {what}, target {target:g}x | {ratio:.2f}x | "
        f"{_verdict(ratio >= target)} |"
    )


#: agent-steps of one rollout of the rollouts rows and of the thesis-setting iterations (h 3,
#: 2 agents)
STEPS_PER_ROLLOUT = 6


def kernel_rates(out: dict) -> dict:
    """``{(nodes, rollouts): JAX seconds per agent-step}`` of the rollout kernel measured in
    paired rounds in this run (h 3, 2 agents): the rollouts rows of ``iteration_pairs`` (1e4)
    and of ``paired`` (1e5)."""
    rates = {}
    for r in out.get("iteration_pairs") or []:
        if r["case"].startswith("rollouts"):
            nodes = int(r["case"].split(", ")[1].split()[0])
            per_step = r["median_s"]["jax"] / r["agent_steps"]
            rates[nodes, int(r["agent_steps"] // STEPS_PER_ROLLOUT)] = per_step
    for p in out.get("paired") or []:
        steps = p["rollouts"] * STEPS_PER_ROLLOUT
        rates[p["nodes"], p["rollouts"]] = p["jax"]["median_s"]["jax"] / steps
    return rates


def rollout_ceiling(row: dict, rates: dict) -> float | None:
    """The largest ratio an iteration ``row`` could reach if everything but its rollouts took
    no time: its faster torch reference's median time over the time its agent-steps take at
    the rate of JAX's rollout kernel measured in the same run (``kernel_rates``: one policy,
    no per-candidate weights; the rate of the batch size nearest the iteration's rollouts, the
    faster one where two are as near). ``None`` where no rollouts row has its simulator (the
    paper setting, h 150)."""
    nodes = next((n for n in (3, 6) if f"{n} nodes" in row["case"]), None)
    if not row["case"].startswith("iteration") or "paper" in row["case"] or nodes is None:
        return None
    sizes = [(k, v) for (n, k), v in rates.items() if n == nodes]
    if not sizes:
        return None
    rollouts = row["agent_steps"] / STEPS_PER_ROLLOUT
    nearest = min(abs(math.log(k / rollouts)) for k, _ in sizes)
    per_step = min(v for k, v in sizes if abs(math.log(k / rollouts)) <= nearest + 1e-9)
    torch_s = min(row["median_s"]["torch-vectorized"], row["median_s"]["torch-compiled"])
    return torch_s / (row["agent_steps"] * per_step)


def pairs_table(out: dict) -> list[str]:
    rows = out.get("iteration_pairs") or []
    if not rows:
        return []
    lines = [
        "| what the user runs | agent-steps per call | rounds x calls | JAX ms | torch eager ms "
        "| torch.compile ms | JAX / best torch: median (lowest-highest round) | ceiling: "
        "rollouts alone at the kernel's rate | target |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    rates = kernel_rates(out)
    for r in rows:
        ms = r["median_s"]
        ceiling = rollout_ceiling(r, rates)
        lines.append(
            f"| {r['case']} | {r['agent_steps']:.3g} | {r['rounds']} x {r['calls_per_round']} | "
            f"{ms['jax'] * 1e3:.2f} | {ms['torch-vectorized'] * 1e3:.2f} | "
            f"{ms['torch-compiled'] * 1e3:.2f} | {r['ratio']:.1f}x ({r['ratio_min']:.1f}-"
            f"{r['ratio_max']:.1f}x) | {'-' if ceiling is None else f'{ceiling:.1f}x'} | "
            f"{_verdict(r['ratio'] >= ITERATION_RATIO_TARGET)} |"
        )
    return lines


def end_to_end_lines(out: dict) -> list[str]:
    e2e = out.get("end_to_end")
    if not e2e:
        return []
    med = e2e["median_s"]
    jax_d = [d for d in e2e["details"]["jax"] if d["phase"] == "warm"]
    torch_d = [d for d in e2e["details"]["torch"] if d["phase"] == "warm"]
    cold_j = next(d for d in e2e["details"]["jax"] if d["phase"] == "cold")
    cold_t = next(d for d in e2e["details"]["torch"] if d["phase"] == "cold")
    sets = " ".join(f"--set {s}" for s in e2e["sets"])
    return [
        "| run | JAX process s | torch.compile process s | ratio | target |",
        "|---|---|---|---|---|",
        f"| cold caches (1 run each) | {med['jax']['cold']:.1f} (compile "
        f"{cold_j['compile_s']:.1f}) | {med['torch']['cold']:.1f} (first iteration "
        f"{cold_t['first_iteration_s']:.1f}) | "
        f"{e2e['ratio_cold']:.2f}x | >= {END_TO_END_COLD_TARGET:g}x: "
        f"{_verdict(e2e['ratio_cold'] >= END_TO_END_COLD_TARGET)} |",
        f"| warm caches (median of {len(jax_d)}) | {med['jax']['warm']:.1f} | "
        f"{med['torch']['warm']:.1f} | {e2e['ratio_warm']:.2f}x | >= "
        f"{END_TO_END_WARM_TARGET:g}x: {_verdict(e2e['ratio_warm'] >= END_TO_END_WARM_TARGET)} |",
        "",
        f"Command on both sides: `cognet-jax train {e2e['experiment']} {sets}` (no plots) and "
        "`python -m benchmarks.torch_run` with the same settings, iterations and a 10,000-rollout "
        "honest evaluation (`benchmarks/end_to_end.py`), each in a fresh process timed from "
        "outside. Honest values of the warm runs: JAX "
        + ", ".join(f"{d['value']:.3f}" for d in jax_d)
        + "; torch "
        + ", ".join(f"{d['value']:.3f}" for d in torch_d)
        + ". Inside the torch process (warm, median): "
        + f"imports {_median(torch_d, 'import_s'):.1f} s, first iteration "
        + f"{_median(torch_d, 'first_iteration_s'):.1f} s, the other iterations "
        + f"{_median(torch_d, 'loop_s'):.1f} s; JAX (warm, median): compile "
        + f"{_median(jax_d, 'compile_s'):.1f} s, iterations {_median(jax_d, 'loop_s'):.1f} s.",
    ]


def _median(rows: list[dict], key: str) -> float:
    return statistics.median(r[key] for r in rows)
