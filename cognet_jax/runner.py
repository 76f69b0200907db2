"""Drives a search from the command line: compile once, iterate with a progress bar, evaluate
the best policy honestly, write ``results.json``, the policy and plots.

Files written to ``out_dir``:

* ``results.json`` -- experiment, algorithm, seed, full config, ``final_value`` {mean, stderr,
  rollouts} (fresh evaluation of the best policy with the seed's reserved evaluation key),
  ``in_loop_best`` (the search's own, optimistically biased, estimate), iterations, wall and
  compile seconds, per-iteration values;
* ``policy.msgpack`` -- the best policy (versioned and checksummed,
  ``checkpoint.policy_bytes``), loadable with ``load_policy``;
* ``vae.msgpack`` -- the patch VAE the observation pipeline used (encoded or augmented
  COGNet-DICE only); ``load_policy`` reads it back so evaluation uses the same encoder;
* PNG plots (``run.plots``).
"""

from __future__ import annotations

import contextlib
import json
import signal
import threading
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from cognet_jax.api import build_algorithm, make_step, seed_key, split_seed_key
from cognet_jax.config import Config, config_from_dict
from cognet_jax.errors import MismatchError
from cognet_jax.memory import budget_bytes, trace_checked


def _progress_bar(total: int, enabled: bool, desc: str):
    from tqdm.auto import tqdm

    return tqdm(total=total, disable=not enabled, desc=desc, unit="it", dynamic_ncols=True)


def honest_evaluation(algorithm, key, policy, rollouts: int, batch: int) -> dict:
    """Mean and standard error of ``rollouts`` fresh rollouts of ``policy``."""
    fn = jax.jit(algorithm.policy_returns, static_argnums=(2, 3))
    return return_summary(fn(key, policy, rollouts, batch))


def return_summary(returns) -> dict:
    """``{"mean", "stderr", "rollouts"}`` of a 1-D array of returns (in float64)."""
    returns = np.asarray(returns, dtype=np.float64)
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
    if config.env.name != "dpomdp" or not hasattr(policy, "transitions"):
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
    """Write ``policy`` atomically (``checkpoint.policy_bytes``: versioned, checksummed)."""
    from cognet_jax.checkpoint import atomic_write_bytes, policy_bytes

    atomic_write_bytes(path, policy_bytes(policy))


def load_policy(run_dir: str | Path, overrides: list[str] | None = None):
    """``(config, algorithm, policy)`` of a finished run directory. ``overrides`` (``--set``)
    may change the evaluation environment, e.g. ``env.obs_noise=0.1``; shapes must match.
    The run's own ``vae.msgpack`` (if any) is used unless ``network.vae_path`` is overridden."""
    from cognet_jax.checkpoint import read_policy
    from cognet_jax.config import apply_overrides, parse_override
    from cognet_jax.errors import read_json
    from cognet_jax.observations import VAE_FILE

    run_dir = Path(run_dir)
    results_path = run_dir / "results.json"
    if not results_path.is_file():
        raise FileNotFoundError(f"{results_path} not found: is {run_dir} a training output folder?")
    results = read_json(results_path, ("config",))
    overrides = list(overrides or [])
    named = {tuple(parse_override(o)[0]) for o in overrides}
    if ("problem", "path") in named:
        raise MismatchError(
            f"--set problem.path: the policy in {run_dir} was trained on "
            f"{results['config'].get('problem', {}).get('path')!r}; a policy is evaluated on "
            "its own model (other fields, e.g. problem.horizon or env noise, may change)"
        )
    if (run_dir / VAE_FILE).is_file() and ("network", "vae_path") not in named:
        overrides.insert(0, f"network.vae_path={json.dumps(str(run_dir / VAE_FILE))}")
    config = config_from_dict(apply_overrides(results["config"], overrides))
    algorithm = build_algorithm(config)
    template = algorithm.best_policy(algorithm.init(jax.random.key(0)))
    policy = read_policy(run_dir / "policy.msgpack", template)
    policy = jax.tree.map(jnp.asarray, policy)
    return config, algorithm, policy


def save_vae_of(algorithm, out_dir: Path) -> Path | None:
    """Write the VAE of ``algorithm``'s observation pipeline (if it has one) to the run folder."""
    from cognet_jax.observations import VAE_FILE
    from cognet_jax.vae import save_vae

    vae = getattr(getattr(algorithm, "pipeline", None), "vae", None)
    if vae is None:
        return None
    save_vae(out_dir / VAE_FILE, vae)
    return out_dir / VAE_FILE


def _settings_dict(algorithm) -> dict:
    import dataclasses

    settings = getattr(algorithm, "settings", None)
    if not dataclasses.is_dataclass(settings):
        return {}
    out = dataclasses.asdict(settings)
    if hasattr(algorithm, "restarts"):  # a G-DICE portfolio: searches per member
        out["searches"] = [
            {"shared_controller": m.settings.shared_controller, "restarts": r, "entropy_rate": e}
            for m, r, e in zip(algorithm.members, algorithm.restarts, algorithm.rates)
        ]
    return json.loads(json.dumps(out, default=str))


def finish_search(algorithm, state, log=print) -> tuple[object, dict | None]:
    """The algorithm's ``finish`` after the last iteration (G-DICE: exact polish of the best
    policy), compiled and timed; ``(state, record for results.json or None)``. The record
    holds the exact values before and after, the moves applied and the seconds it took."""
    if not getattr(algorithm, "polishes", False):
        return state, None
    t0 = time.perf_counter()
    state, info = jax.jit(algorithm.finish)(state)
    info = jax.device_get(info)
    record = {
        "value_before": float(info.before),
        "value_after": float(info.after),
        "moves_applied": int(info.moves_applied),
        "moves_per_sweep": int(info.moves_per_sweep),
        "best_responses_applied": int(info.responses_applied),
        "seconds": time.perf_counter() - t0,
    }
    log(
        f"polish: exact {record['value_before']:.6f} -> {record['value_after']:.6f} "
        f"({record['moves_applied']} moves of {record['moves_per_sweep']} tried per sweep, "
        f"{record['best_responses_applied']} best responses, "
        f"{record['seconds']:.1f} s)"
    )
    return state, record


def _json_ready(x):
    arr = np.asarray(x)
    return arr.tolist()


class Interrupted(Exception):
    """A run stopped by SIGINT or SIGTERM after writing its best policy and a checkpoint;
    ``signum`` is the signal (the CLI exits with ``128 + signum``)."""

    def __init__(self, out_dir: Path, iteration: int, iterations: int, signum: int = 2):
        self.out_dir, self.iteration, self.signum = Path(out_dir), iteration, int(signum)
        name = signal.Signals(self.signum).name
        super().__init__(
            f"interrupted at iteration {iteration}/{iterations} ({name}): best policy and "
            f"checkpoint written to {out_dir}; continue with --resume {out_dir}"
        )


#: the signals that stop a search softly: Ctrl-C, and what ``timeout`` and schedulers send
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextlib.contextmanager
def sigint_guard():
    """Inside the block the first SIGINT (Ctrl-C) or SIGTERM only sets ``flag["stop"]`` (and
    ``flag["signum"]``), so the loop can finish the current iteration and write a checkpoint;
    a second one raises ``KeyboardInterrupt`` at once (abandoning the iteration). No-op outside
    the main thread."""
    flag = {"stop": False, "signum": int(signal.SIGINT)}
    if threading.current_thread() is not threading.main_thread():
        yield flag
        return

    def second(signum, frame):
        raise KeyboardInterrupt

    def handler(signum, frame):
        flag["stop"], flag["signum"] = True, int(signum)
        for sig in STOP_SIGNALS:
            signal.signal(sig, second)

    previous = {sig: signal.signal(sig, handler) for sig in STOP_SIGNALS}
    try:
        yield flag
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)


def iterate(
    step,
    state,
    *,
    start: int,
    iterations: int,
    history: list,
    checkpoint_every: int,
    save,
    on_interrupt,
    progress: bool,
    desc: str,
    postfix=None,
):
    """The training loop of ``train`` and ``sweep``: ``state, metrics = step(state)`` from
    iteration ``start`` to ``iterations``, each iteration's metrics appended to ``history``.

    ``save(i, state, history)`` writes a checkpoint every ``checkpoint_every`` iterations (0:
    never) and when a SIGINT / SIGTERM stops the loop (``sigint_guard``: the current iteration
    finishes first); then ``on_interrupt(i, state, signum)`` writes what the caller keeps and
    raises. A progress bar every 10 iterations, with ``postfix(metrics) -> dict`` beside it.
    Returns the final state (``history`` is filled in place)."""
    i = start
    with sigint_guard() as sigint, _progress_bar(iterations, progress, desc) as bar:
        bar.update(start)
        while i < iterations and not sigint["stop"]:
            state, metrics = step(state)
            history.append(metrics)
            i += 1
            if checkpoint_every and i % checkpoint_every == 0 and i < iterations:
                save(i, state, history)
            if progress and (i % 10 == 0 or i == iterations):
                if postfix is not None:
                    bar.set_postfix(**postfix(jax.device_get(metrics)))
                bar.update(i - bar.n)
        if i < iterations:
            save(i, state, history)
            on_interrupt(i, state, sigint["signum"])
    return state


def _train_meta(config: Config, seed: int) -> dict:
    return {"kind": "train", "config": config.to_dict(), "seed": seed}


def resume_target(run_dir: str | Path, overrides: list[str] | None = None):
    """``(config, seed)`` stored in the checkpoint of ``run_dir``. ``overrides`` may only
    touch the ``run`` section (progress, plots, checkpoint_every)."""
    from cognet_jax.checkpoint import CHECKPOINT_NAME, read_checkpoint
    from cognet_jax.config import ConfigError, apply_overrides, parse_override

    for text in overrides or []:
        (section, _), _ = parse_override(text)
        if section != "run":
            raise ConfigError(text.split("=")[0], "cannot be changed when resuming")
    raw = read_checkpoint(Path(run_dir) / CHECKPOINT_NAME)
    meta = raw["meta"]
    if meta.get("kind") != "train":
        raise ConfigError("", f"{run_dir} holds a {meta.get('kind')} checkpoint, not a train run")
    return config_from_dict(apply_overrides(meta["config"], overrides or [])), int(meta["seed"])


def rollout_mesh(config: Config):
    """The context a run's iterations are compiled in: with ``run.shard_rollouts`` a 1-D mesh
    ``("rollouts",)`` over the local devices is set (``jax.set_mesh``), and the rollout
    engine lays every batch of rollouts (and so the candidates' evaluations) over it
    (``rollout.shard_rollouts``); otherwise nothing changes."""
    import contextlib

    if not config.run.shard_rollouts:
        return contextlib.nullcontext()
    from jax.sharding import Mesh

    return jax.set_mesh(Mesh(np.array(jax.local_devices()), ("rollouts",)))


def _in_rollout_mesh(fn):
    """Runs ``fn(config, ...)`` inside ``rollout_mesh(config)``."""
    import functools

    @functools.wraps(fn)
    def wrapped(config: Config, *args, **kwargs):
        with rollout_mesh(config):
            return fn(config, *args, **kwargs)

    return wrapped


@_in_rollout_mesh
def run_training(
    config: Config,
    seed: int,
    out_dir: str | Path,
    progress: bool | None = None,
    log=print,
    resume: bool = False,
) -> dict:
    """Run the search of ``config`` with ``seed`` (inside ``rollout_mesh(config)``); write
    outputs to ``out_dir``; return results.

    Every ``run.checkpoint_every`` iterations (0: never), at the end and on SIGINT the full
    search state is written atomically to ``out_dir/checkpoint.msgpack``; on SIGINT the best
    policy so far is written too and ``Interrupted`` is raised. ``resume=True`` continues from
    that checkpoint: the remaining iterations use the same compiled step and the same
    ``fold_in(run_key, iteration)`` keys, so the results are bit-identical to an uninterrupted
    run."""
    from cognet_jax.checkpoint import (
        CHECKPOINT_NAME,
        atomic_write_text,
        read_checkpoint,
        restore_history,
        restore_key,
        restore_state,
        save_checkpoint,
        stack_history,
    )

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    progress = config.run.progress if progress is None else progress
    iterations = config.algorithm.iterations
    every = config.run.checkpoint_every
    ckpt_path = out_dir / CHECKPOINT_NAME
    t_start = time.perf_counter()

    algorithm, init, step = make_step(config)
    save_vae_of(algorithm, out_dir)
    k_init, k_run, k_eval = split_seed_key(seed_key(config, seed))
    trace_checked(jax.jit(init), (k_init,), budget_bytes(config.run.memory_gb), "the initial state")
    state = jax.jit(init)(k_init)
    history = []
    start = 0
    if resume:
        raw = read_checkpoint(ckpt_path)
        stored_config = dict(raw["meta"].get("config", {}), run=None)
        if raw["meta"].get("seed") != seed or stored_config != dict(config.to_dict(), run=None):
            raise MismatchError(f"{ckpt_path} was written by another config or seed")
        stored = restore_key(raw, "run", config.run.prng_impl)
        if not np.array_equal(jax.random.key_data(stored), jax.random.key_data(k_run)):
            raise MismatchError(f"{ckpt_path}: stored run key does not match seed {seed}")
        state = jax.tree.map(jnp.asarray, restore_state(state, raw))
        history = restore_history(jax.eval_shape(step, k_run, state)[1], raw)
        start = int(raw["iteration"])
        log(f"resuming {config.experiment.name} seed {seed} at iteration {start}/{iterations}")
    t0 = time.perf_counter()
    traced = trace_checked(
        jax.jit(step, donate_argnums=(1,)), (k_run, state), budget_bytes(config.run.memory_gb)
    )
    compiled = traced.lower().compile()
    compile_s = time.perf_counter() - t0

    def checkpoint(i, state, history):
        save_checkpoint(
            ckpt_path,
            state=state,
            keys={"init": k_init, "run": k_run, "eval": k_eval},
            iteration=i,
            history=stack_history(history),
            meta=_train_meta(config, seed),
        )

    def interrupted(i, state, signum):  # keep what we have
        save_policy(out_dir / "policy.msgpack", algorithm.best_policy(state))
        atomic_write_text(
            out_dir / "results.json",
            json.dumps(
                {
                    "experiment": config.experiment.name,
                    "algorithm": config.experiment.algorithm,
                    "seed": seed,
                    "config": config.to_dict(),
                    "status": "interrupted",
                    "iteration": i,
                    "final_value": None,
                },
                indent=1,
            ),
        )
        raise Interrupted(out_dir, i, iterations, signum)

    t_loop = time.perf_counter()
    state = iterate(
        lambda s: compiled(k_run, s),
        state,
        start=start,
        iterations=iterations,
        history=history,
        checkpoint_every=every,
        save=checkpoint,
        on_interrupt=interrupted,
        progress=progress,
        desc=config.experiment.name,
        postfix=lambda m: dict(value=f"{float(m.value):.2f}", best=f"{float(m.best_value):.2f}"),
    )
    checkpoint(iterations, state, history)
    state, polish_info = finish_search(algorithm, state, log)
    history = stack_history(history)  # on the host: jnp.stack of 500 arrays compiles
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
        # the algorithm's settings as built (e.g. the evaluator "auto" chose)
        "resolved": _settings_dict(algorithm),
        "status": "complete",
        "resumed_from_iteration": start if resume else None,
        "final_value": final,
        "in_loop_best": float(history.best_value[-1]),
        "iterations": iterations,
        # the search's budget: agent-steps simulated by all its iterations
        "simulated_agent_steps": iterations
        * algorithm.rollouts_per_iteration
        * algorithm.env.horizon
        * algorithm.env.num_agents,
        "wall_s": wall_s,
        "compile_s": compile_s,
        "loop_s": loop_s,
        "values_per_iteration": _json_ready(history.value),
        "best_per_iteration": _json_ready(history.best_value),
        "threshold_per_iteration": _json_ready(history.threshold),
        "kept_per_iteration": _json_ready(history.kept),
        "entropy_injections": int(np.sum(history.injected)),
        "polish": polish_info,
        "jax_version": jax.__version__,
        "backend": jax.default_backend(),
    }
    atomic_write_text(out_dir / "results.json", json.dumps(results, indent=1))
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
