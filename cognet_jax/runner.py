"""Drives a search from the command line: compile once, iterate with a progress bar, evaluate
the best policy honestly, write ``results.json``, the policy and plots.

Files written to ``out_dir``:

* ``results.json`` -- experiment, algorithm, seed, full config, ``final_value`` {mean, stderr,
  rollouts} (fresh evaluation of the best policy with the seed's reserved evaluation key),
  ``in_loop_best`` (the search's own, optimistically biased, estimate), iterations, wall and
  compile seconds, per-iteration values;
* ``policy.msgpack`` -- the best policy (Flax serialization), loadable with ``load_policy``;
* PNG plots (``run.plots``).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from flax import serialization

from cognet_jax.api import build_algorithm, make_step, seed_key, split_seed_key
from cognet_jax.config import Config, config_from_dict


def _progress_bar(total: int, enabled: bool, desc: str):
    from tqdm.auto import tqdm

    return tqdm(total=total, disable=not enabled, desc=desc, unit="it", dynamic_ncols=True)


def honest_evaluation(algorithm, key, policy, rollouts: int, batch: int) -> dict:
    """Mean and standard error of ``rollouts`` fresh rollouts of ``policy``."""
    fn = jax.jit(algorithm.policy_returns, static_argnums=(2, 3))
    returns = np.asarray(fn(key, policy, rollouts, batch), dtype=np.float64)
    return {
        "mean": float(returns.mean()),
        "stderr": float(returns.std(ddof=1) / np.sqrt(returns.size)),
        "rollouts": int(returns.size),
    }


def exact_evaluation(config: Config, policy) -> dict | None:
    """Exact values of a deterministic tabular controller on a ``.dpomdp`` problem:
    ``{"exact": finite-horizon value at problem.horizon (backward DP)}`` plus
    ``"exact_infinite"`` (Bellman iteration to 1e-10) when the discount is below 1; ``None`` for
    other problems or policies."""
    from cognet_jax.config import DpomdpEnvSection

    if not isinstance(config.env, DpomdpEnvSection) or not hasattr(policy, "transitions"):
        return None
    from cognet_jax.api import load_problem
    from cognet_jax.exact import exact_value

    model = load_problem(config)
    actions, transitions = np.asarray(policy.actions), np.asarray(policy.transitions)
    out = {
        "exact": float(
            exact_value(model, actions, transitions, config.problem.horizon, model.discount)
        )
    }
    if model.discount < 1:
        out["exact_infinite"] = float(
            exact_value(model, actions, transitions, None, model.discount)
        )
    return out


def save_policy(path: Path, policy) -> None:
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_bytes(serialization.to_bytes(jax.device_get(policy)))
    tmp.replace(path)


def load_policy(run_dir: str | Path, overrides: list[str] | None = None):
    """``(config, algorithm, policy)`` of a finished run directory. ``overrides`` (``--set``)
    may change the evaluation environment, e.g. ``env.obs_noise=0.1``; shapes must match."""
    from cognet_jax.config import apply_overrides

    run_dir = Path(run_dir)
    results_path = run_dir / "results.json"
    if not results_path.exists():
        raise FileNotFoundError(f"{results_path} not found: is {run_dir} a training output folder?")
    results = json.loads(results_path.read_text())
    config = config_from_dict(apply_overrides(results["config"], overrides or []))
    algorithm = build_algorithm(config)
    template = algorithm.best_policy(algorithm.init(jax.random.key(0)))
    policy = serialization.from_bytes(template, (run_dir / "policy.msgpack").read_bytes())
    policy = jax.tree.map(jnp.asarray, policy)
    return config, algorithm, policy


def _json_ready(x):
    arr = np.asarray(x)
    return arr.tolist()


def run_training(
    config: Config, seed: int, out_dir: str | Path, progress: bool | None = None, log=print
) -> dict:
    """Run the search of ``config`` with ``seed``; write outputs to ``out_dir``; return results."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    progress = config.run.progress if progress is None else progress
    iterations = config.algorithm.iterations
    t_start = time.perf_counter()

    algorithm, init, step = make_step(config)
    k_init, k_run, k_eval = split_seed_key(seed_key(config, seed))
    state = jax.jit(init)(k_init)
    t0 = time.perf_counter()
    compiled = jax.jit(step, donate_argnums=(1,)).lower(k_run, state).compile()
    compile_s = time.perf_counter() - t0

    history = []
    t_loop = time.perf_counter()
    with _progress_bar(iterations, progress, config.experiment.name) as bar:
        for i in range(iterations):
            state, metrics = compiled(k_run, state)
            history.append(metrics)
            if progress and (i % 10 == 9 or i == iterations - 1):
                m = jax.device_get(metrics)
                bar.set_postfix(value=f"{float(m.value):.2f}", best=f"{float(m.best_value):.2f}")
                bar.update(i + 1 - bar.n)
    history = jax.device_get(jax.tree.map(lambda *xs: jnp.stack(xs), *history))
    loop_s = time.perf_counter() - t_loop

    best = algorithm.best_policy(state)
    final = honest_evaluation(
        algorithm, k_eval, best, config.evaluation.rollouts, config.evaluation.batch
    )
    exact = exact_evaluation(config, best)
    if exact is not None:
        final.update(exact)
    save_policy(out_dir / "policy.msgpack", best)
    wall_s = time.perf_counter() - t_start

    results = {
        "experiment": config.experiment.name,
        "algorithm": config.experiment.algorithm,
        "seed": seed,
        "config": config.to_dict(),
        "final_value": final,
        "in_loop_best": float(history.best_value[-1]),
        "iterations": iterations,
        "wall_s": wall_s,
        "compile_s": compile_s,
        "loop_s": loop_s,
        "values_per_iteration": _json_ready(history.value),
        "best_per_iteration": _json_ready(history.best_value),
        "threshold_per_iteration": _json_ready(history.threshold),
        "kept_per_iteration": _json_ready(history.kept),
        "entropy_injections": int(np.sum(history.injected)),
        "jax_version": jax.__version__,
        "backend": jax.default_backend(),
    }
    (out_dir / "results.json").write_text(json.dumps(results, indent=1))
    if config.run.plots:
        from cognet_jax.reporting import write_plots

        write_plots(config, algorithm, best, results, out_dir)
    exact_text = f" (exact {final['exact']:.6f})" if "exact" in final else ""
    log(
        f"{config.experiment.name} seed {seed}: honest value {final['mean']:.3f} "
        f"+- {final['stderr']:.3f} ({final['rollouts']} rollouts){exact_text}; in-loop best "
        f"{results['in_loop_best']:.3f}; wall {wall_s:.1f} s (compile {compile_s:.1f} s)"
    )
    log(
        f"wrote {out_dir}/results.json, policy.msgpack" + (" and plots" if config.run.plots else "")
    )
    return results
