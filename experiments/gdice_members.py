"""Which member searches of the default ``gdice-dpomdp`` portfolio end at the best value: each
member search's best exact value before and after its own polish, per seed.

    python experiments/gdice_members.py --model dectiger --horizons 8 9 10 --seeds 8

One line of JSON per seed in ``experiments/results/gdice-members/<model>-h<H>.jsonl``:
``before`` (per kind of search -- independent, shared, explore -- the exact best value of
each of its repeats at the end of the iterations), ``after`` (each member's best after the
polish, in the same order, flattened), ``best`` (the portfolio's polished value, what
``cognet-jax train`` keeps) and ``s`` (wall seconds of the seed, the first including
compilation). It is what showed that one search of a kind reaches the optimum of Dec-Tiger
h 8-10 on only 1 to 3 seeds of 8, the reason for ``algorithm.repeats = "auto"``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import jax
import numpy as np
from gdice_scale import DPOMDP_DIR

from cognet_jax import api
from cognet_jax.registry import load_config

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results" / "gdice-members"


def member_values(config, seeds: int):
    """Yield one record per seed (see the module docstring)."""
    algorithm, params = api.build_algorithm(config)
    step = api.iteration_step(algorithm)
    iterations = config.algorithm.iterations

    @jax.jit
    def search(key):
        k_init, k_run, _ = api.split_seed_key(key)
        state = algorithm.init(k_init, params)
        scan = jax.lax.scan(lambda s, _: step(k_run, s, params), state, None, length=iterations)
        return scan[0]

    start = jax.jit(lambda s: algorithm.finish_start(s, params))
    advance = jax.jit(lambda w: algorithm.finish_advance(w, params))
    for seed in range(seeds):
        t0 = time.perf_counter()
        state = search(api.seed_key(config, seed))
        before = [np.asarray(m.progress.in_loop_best).round(4).tolist() for m in state.members]
        work = start(state)
        while not bool(algorithm.finish_done(work)):
            work = advance(work)
        values = np.asarray(work.value)
        yield {
            "seed": seed,
            "s": round(time.perf_counter() - t0, 1),
            "before": before,
            "after": values[1:].round(4).tolist(),  # [0] is the portfolio's best
            "best": float(values.max()),
        }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="dectiger", help="a file name of ../shared/dpomdp")
    parser.add_argument("--horizons", type=int, nargs="+", default=[8, 9, 10])
    parser.add_argument("--seeds", type=int, default=8)
    args = parser.parse_args(argv)
    RESULTS.mkdir(parents=True, exist_ok=True)
    for horizon in args.horizons:
        path = DPOMDP_DIR / f"{args.model}.dpomdp"
        sets = [f"problem.path={str(path)!r}", f"problem.horizon={horizon}", "problem.discount=1"]
        config = load_config("gdice-dpomdp", sets)
        out = RESULTS / f"{args.model}-h{horizon}.jsonl"
        with out.open("w") as f:
            for record in member_values(config, args.seeds):
                f.write(json.dumps(record) + "\n")
                f.flush()
                print(horizon, json.dumps(record)[:120], file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
