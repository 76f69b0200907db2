"""Time to value, measured: a whole ``cognet-jax train`` against a whole torch run of the same
algorithm, sizes and iterations (``benchmarks.torch_run``), each in a fresh process, compile
included on both sides.

* cold: each side with an empty compilation cache of its own (``COGNET_JAX_CACHE`` for JAX,
  ``TORCHINDUCTOR_CACHE_DIR`` for inductor), as on a fresh machine;
* warm: the same command again with the cache the cold run filled, as when a user repeats a
  run (median of ``WARM_REPEATS``, the two sides alternating).

The process wall time is measured by this parent process (interpreter start, imports, compile,
every iteration, the honest evaluation of 10,000 rollouts and the outputs).
"""

from __future__ import annotations

import dataclasses
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.iteration_pairs import LIBRARY_DEFAULTS

#: the pair measured: the default cognet-dice at the thesis setting, 3 nodes
EXPERIMENT = "tagging-thesis-n3"
SETS = LIBRARY_DEFAULTS
WARM_REPEATS = 3


def _timed(cmd: list[str], env: dict) -> tuple[float, str]:
    t0 = time.perf_counter()
    done = subprocess.run(
        cmd, check=True, capture_output=True, text=True, env={**os.environ, **env}
    )
    return time.perf_counter() - t0, done.stdout


def jax_command(out: Path) -> list[str]:
    sets = [a for s in [*SETS, "run.plots=false"] for a in ("--set", s)]
    return [sys.executable, "-m", "cognet_jax", "train", EXPERIMENT, *sets, "--no-progress"] + [
        "--out",
        str(out),
    ]


def torch_command() -> list[str]:
    from benchmarks.torch_reference.weights import env_from_config, settings_from_config
    from cognet_jax.registry import load_config

    config = load_config(EXPERIMENT, SETS)
    settings = dataclasses.asdict(settings_from_config(config))
    env = dataclasses.asdict(env_from_config(config))
    return [
        sys.executable,
        "-m",
        "benchmarks.torch_run",
        "--settings",
        json.dumps(settings),
        "--env",
        json.dumps(env),
        "--iterations",
        str(config.algorithm.iterations),
        "--compiled",
    ]


def measure(log) -> dict:
    """Cold and warm process walls of both sides, the values they reached, and the ratios."""
    root = Path(__file__).resolve().parent.parent
    walls: dict = {"jax": {"cold": [], "warm": []}, "torch": {"cold": [], "warm": []}}
    details: dict = {"jax": [], "torch": []}
    with tempfile.TemporaryDirectory() as tmp:
        jax_env = {"COGNET_JAX_CACHE": f"{tmp}/jax-cache"}
        torch_env = {"TORCHINDUCTOR_CACHE_DIR": f"{tmp}/inductor", "PYTHONPATH": str(root)}
        torch_cmd = torch_command()
        for i in range(1 + WARM_REPEATS):
            phase = "cold" if i == 0 else "warm"
            out = Path(tmp) / f"run{i}"
            wall, _ = _timed(jax_command(out), jax_env)
            results = json.loads((out / "results.json").read_text())
            walls["jax"][phase].append(wall)
            details["jax"].append(
                dict(
                    phase=phase,
                    wall_s=wall,
                    compile_s=results["compile_s"],
                    loop_s=results["loop_s"],
                    value=results["final_value"]["mean"],
                )
            )
            wall, stdout = _timed(torch_cmd, torch_env)
            walls["torch"][phase].append(wall)
            details["torch"].append(dict(phase=phase, wall_s=wall, **json.loads(stdout)))
            log(
                f"end to end {phase}: jax {walls['jax'][phase][-1]:.1f} s "
                f"(value {details['jax'][-1]['value']:.3f}), torch.compile {wall:.1f} s "
                f"(value {details['torch'][-1]['value']:.3f})"
            )
    med = {side: {p: statistics.median(v) for p, v in w.items()} for side, w in walls.items()}
    return dict(
        experiment=EXPERIMENT,
        sets=SETS,
        walls=walls,
        median_s=med,
        ratio_cold=med["torch"]["cold"] / med["jax"]["cold"],
        ratio_warm=med["torch"]["warm"] / med["jax"]["warm"],
        details=details,
    )
