"""A whole training run of the torch weight-space reference, as a user runs one: one process,
torch imported, the search compiled (``--compiled``: ``torch.compile``), every iteration, then
the kept policy's honest value on ``--eval-rollouts`` fresh rollouts; prints one JSON line.

    python -m benchmarks.torch_run --settings '{"nodes": 3, ...}' --env '{"horizon": 3, ...}' \\
        --iterations 600 --compiled

The settings and the simulator come as JSON (``end_to_end`` writes them from a cognet_jax
config), so this process imports torch and the reference only, never JAX.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

T_START = time.perf_counter()


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--settings", required=True, help="WeightsSettings fields as JSON")
    p.add_argument("--env", required=True, help="TaggingConfig fields as JSON")
    p.add_argument("--iterations", type=int, required=True)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--eval-rollouts", type=int, default=10_000)
    p.add_argument("--compiled", action="store_true", help="torch.compile the time step")
    args = p.parse_args(argv)

    from benchmarks.torch_reference.tagging import TaggingConfig
    from benchmarks.torch_reference.weights import (
        TorchWeightsCompiled,
        TorchWeightsSearch,
        WeightsSettings,
    )

    t_import = time.perf_counter()
    cls = TorchWeightsCompiled if args.compiled else TorchWeightsSearch
    search = cls(
        WeightsSettings(**json.loads(args.settings)),
        TaggingConfig(**json.loads(args.env)),
        args.seed,
    )
    first = time.perf_counter()
    search.step()  # the first iteration compiles (torch.compile), timed apart
    first = time.perf_counter() - first
    t0 = time.perf_counter()
    for _ in range(args.iterations - 1):
        search.step()
    loop_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    returns = search.returns(search.best, args.eval_rollouts, crn=False)[0]
    eval_s = time.perf_counter() - t0
    print(
        json.dumps(
            dict(
                value=float(returns.mean()),
                stderr=float(returns.std() / args.eval_rollouts**0.5),
                import_s=t_import - T_START,
                first_iteration_s=first,
                loop_s=loop_s,
                eval_s=eval_s,
                in_process_s=time.perf_counter() - T_START,
            )
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
