"""The one driver: runs searches from the command line -- compile once, iterate with a progress
bar, checkpoint, stop cleanly on signals, polish, evaluate the best policy honestly, write each
run's folder.

A *group* is a list of runs (``Run``: config, seed, folder) that share one compiled program:
``cognet-jax train`` is a group of one run, a sweep (``cognet_jax.sweep``) runs one group per
set of settings that differ only in dynamic fields. A group of one runs the search as it is;
a larger group ``vmap``s it over a leading ``[runs]`` axis, sharded over the local devices
(``shard_map``, no collectives). Run r of a group uses exactly the keys of ``train --seed s``
(``api.split_seed_key``, iteration i with ``fold_in(run_key, i)``). The params of a group of
one are constants of the program, as in ``api.make_train(config)`` called without params; in a
larger group the hyper-parameters are data (stacked over ``[runs]``), and so are the env params
when the runs differ in them.

Every run ends with the one honest evaluation (``api.honest_returns``: ``evaluation.rollouts``
fresh rollouts of its best policy from the seed's evaluation key), compiled with the run's
params as constants -- the function ``cognet-jax evaluate DIR`` runs to reproduce it.

Files of a run folder (``write_run``): ``results.json`` (``RESULTS_SCHEMA``: experiment,
algorithm, seed, setting and grid of a sweep, full config, ``final_value`` {mean, stderr,
rollouts, exact values of tabular controllers}, ``in_loop_best`` (the search's own, optimistic
estimate), per-iteration values, polish record, timings); ``policy.msgpack`` (the best policy,
``checkpoint.policy_bytes``); ``vae.msgpack`` when the observation pipeline has a VAE; PNG plots
(a group of one run with ``run.plots``).

Signals (``cognet_jax.signals``): SIGINT, SIGTERM and SIGHUP during the iterations stop the
group after the current iteration (``signals.deferred_stop``); its checkpoint and every run's
best policy so far are written and ``Interrupted`` is raised (the CLI exits with ``128 +
signal``). Checkpoints are written every ``run.checkpoint_every`` iterations and every
``run.checkpoint_seconds`` seconds of search (atomic, ``checkpoint.save_checkpoint``);
``resume`` continues from one bit for bit.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import hashlib
import json
import math
import signal
import sys
import time
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec
from tqdm.auto import tqdm

from cognet_jax.algorithms.engine import SearchParams
from cognet_jax.api import (
    FASTEST_RATE,
    LONG_SECONDS,
    build_algorithm,
    build_env,
    check_budget,
    honest_returns,
    iteration_step,
    params_of,
    seed_key,
    split_seed_key,
)
from cognet_jax.checkpoint import (
    CHECKPOINT_NAME,
    atomic_write_bytes,
    atomic_write_text,
    policy_bytes,
    read_checkpoint,
    read_policy,
    restore_history,
    restore_key,
    restore_state,
    save_checkpoint,
    stack_history,
)
from cognet_jax.config import Config, ConfigError, apply_overrides, parse_override
from cognet_jax.envs.tabular import load_problem
from cognet_jax.errors import CorruptFileError, InputError, MismatchError, read_json
from cognet_jax.exact import exact_value
from cognet_jax.memory import budget_bytes, peak_rss_bytes, trace_checked
from cognet_jax.observations import VAE_FILE
from cognet_jax.registry import (
    algorithm_entry,
    config_from_dict,
    env_entry,
    foreign_code,
    is_builtin,
)
from cognet_jax.reporting import write_plots
from cognet_jax.signals import Stopped, deferred_stop, in_background, wait_for
from cognet_jax.traced import compile_kept, program_key
from cognet_jax.vae import save_vae

#: version of results.json (2: one schema for train and sweep runs; see ``run_record``)
RESULTS_SCHEMA = 2


@dataclasses.dataclass(frozen=True)
class Run:
    """One search of a group: its config, seed and training folder (``None``: no files);
    ``setting`` and ``grid`` say which setting of a sweep it is."""

    config: Config
    seed: int
    folder: Path | None = None
    setting: int = 0
    grid: dict = dataclasses.field(default_factory=dict)


class Interrupted(Exception):
    """A group stopped by a signal after writing its checkpoint and every run's best policy;
    ``signum`` is the signal (the CLI exits with ``128 + signum``)."""

    def __init__(self, out_dir: Path, iteration: int, iterations: int, signum: int = 2):
        self.out_dir, self.iteration, self.signum = Path(out_dir), iteration, int(signum)
        name = signal.Signals(self.signum).name
        super().__init__(
            f"interrupted at iteration {iteration}/{iterations} ({name}): best policy and "
            f"checkpoint written to {out_dir}; continue with --resume {out_dir}"
        )


# ---------------------------------------------------------------------------------------------
# the compiled program of a group
# ---------------------------------------------------------------------------------------------
def _same_tree(a, b) -> bool:
    """Whether two pytrees of arrays have the same structure and values."""
    leaves_a, leaves_b = jax.tree.leaves(a), jax.tree.leaves(b)
    return jax.tree.structure(a) == jax.tree.structure(b) and all(
        np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(leaves_a, leaves_b)
    )


def _stack(trees):
    return jax.tree.map(lambda *xs: jnp.stack([jnp.asarray(x) for x in xs]), *trees)


def take(tree, r: int):
    """Run ``r`` of a pytree with a leading ``[runs]`` axis."""
    return jax.tree.map(lambda x: x[r], tree)


#: arrays of a single run's params larger than this are arguments of its compiled programs,
#: not constants: each program holds its own copy of a constant (a 2025-state model's 262 MB
#: transition table, once in the step, once in the polish, once in the evaluation)
CONSTANT_BYTES = 16 * 2**20


def hoist_large(params):
    """``(held, rebuild)``: the array leaves of ``params`` larger than ``CONSTANT_BYTES`` and
    ``rebuild(held) -> params`` with them put back (traced arguments inside a program); the
    other leaves stay constants."""
    leaves, treedef = jax.tree.flatten(params)
    where = [i for i, x in enumerate(leaves) if _held(x)]

    def rebuild(held):
        out = list(leaves)
        for i, x in zip(where, held, strict=True):
            out[i] = x
        return jax.tree.unflatten(treedef, out)

    return tuple(leaves[i] for i in where), rebuild


def _held(x) -> bool:
    return getattr(x, "nbytes", 0) > CONSTANT_BYTES


def baked_constants(params) -> list:
    """The array leaves of ``params`` that ``hoist_large`` leaves as constants."""
    return [x for x in jax.tree.leaves(params) if not _held(x)]


def per_run(fn, sharding, num_args: int):
    """``vmap(fn)`` over the leading ``[runs]`` axis of every argument and output, each device
    running ``vmap(fn)`` on its own block of runs (``shard_map``): runs never talk to each
    other, so the program holds no collective. (Not jitted: ``Program.compiled`` is.)"""
    spec = sharding.spec
    return jax.shard_map(
        jax.vmap(fn),
        mesh=sharding.mesh,
        in_specs=(spec,) * num_args,
        out_specs=spec,
        check_vma=False,  # carries start as constants; runs are independent anyway
    )


#: ``run`` fields that only drive a run (progress, plots, checkpoints): left out of the keys of
#: its programs, which do not depend on them
DRIVING_FIELDS = ("progress", "plots", "checkpoint_every", "checkpoint_seconds", "probe_seconds")


def program_identity(config: Config, search: bool = False, **extra) -> dict:
    """What a program of ``config`` depends on besides its constants and argument shapes: the
    config without its ``DRIVING_FIELDS`` (and without its ``evaluation`` section for the
    ``search``'s own programs, which never read it), the bytes of the files it reads (the
    model, the VAE of ``network.vae_path``: their weights may be baked in), its memory budget
    in bytes, and ``extra``."""
    sections = config.to_dict()
    sections["run"] = {k: v for k, v in sections["run"].items() if k not in DRIVING_FIELDS}
    if search:
        del sections["evaluation"]
    files = [config.problem.path, config.network.vae_path]
    digests = [_file_digest(Path(f).expanduser()) for f in files if f]
    memory = budget_bytes(config.run.memory_gb)
    return {"config": sections, "files": digests, "memory": memory, **extra}


def _file_digest(path: Path) -> str:
    """SHA-256 of a file's bytes (computed once per size and modification time); "" for a
    missing file."""
    try:
        path = path.resolve()
        stat = path.stat()
    except OSError:
        return ""
    return _digest_of(path, stat.st_size, stat.st_mtime_ns)


@functools.lru_cache(maxsize=64)
def _digest_of(path: Path, size: int, mtime_ns: int) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def compiled_program(
    config: Config, what: str, fn, args: tuple, constants, identity: dict, before_compile=None
):
    """``fn(*args)`` compiled once (``traced.compile_kept``: kept in this process and, traced,
    between processes, while the compilation cache is on), ``what`` naming it in the memory
    check's refusal (``before_compile()`` is called once the check passed, when it is
    compiled afresh); ``constants`` are the arrays of ``config``'s params baked into it. A
    simulator or algorithm registered from outside the package is compiled afresh each time
    (its source is not in the key)."""
    before_compile = before_compile or (lambda: None)
    builtin = (
        not foreign_code()
        and is_builtin(env_entry(config.env.name))
        and is_builtin(algorithm_entry(config.experiment.algorithm))
    )
    key = program_key(what, identity, constants, args) if builtin else None
    memory = budget_bytes(config.run.memory_gb)

    def check(jitted, leaves):
        trace_checked(jitted, leaves, memory, what)
        before_compile()

    return compile_kept(fn, args, key, check)


class Program:
    """The compiled functions of a group: ``init``, ``step`` (one iteration of every run),
    ``finish`` and each run's honest evaluation. One run: the search itself, params as
    constants. Several: ``vmap`` over ``[runs]`` (padded to a multiple of the local devices by
    repeating the last run), hyper-parameters as data, env params as data only when the runs
    differ in them (a zero noise level can then not skip its draws, ``envs.base.scaled_normal``)."""

    def __init__(self, runs: list[Run]):
        self.runs = runs
        config = runs[0].config
        self.config = config
        self.batched = len(runs) > 1
        mesh = Mesh(np.array(jax.local_devices()), ("runs",)) if self.batched else None
        self.sharding = NamedSharding(mesh, PartitionSpec("runs")) if mesh else None
        padded = runs + [runs[-1]] * (-len(runs) % (mesh.size if mesh else 1))
        self.lanes = len(padded)
        self.algorithm, self.params = build_algorithm(config, lanes=self.lanes)
        # one run: its params are constants of its programs, except the largest arrays
        self.held, self._rebuild = hoist_large(self.params)
        self.run_params = [params_of(r.config) for r in runs]
        self.seed_keys = [seed_key(r.config, r.seed) for r in runs]
        # the first run's init and run keys (what a single-run program uses)
        self.k_init, self.k_run, _ = split_seed_key(self.seed_keys[0])
        self._step = iteration_step(self.algorithm)
        self._evaluations: list = []  # (env params, compiled honest evaluation)
        if self.batched:
            padded_params = self.run_params + [self.run_params[-1]] * (len(padded) - len(runs))
            self.shared_env = all(_same_tree(p.env, self.params.env) for p in self.run_params)
            keys = jnp.stack([seed_key(r.config, r.seed) for r in padded])
            hyper = _stack([p.hyper for p in padded_params])
            env = _stack([p.env for p in padded_params])
            self.data = jax.device_put((keys, hyper, env), self.sharding)

    # -- per-run pieces, written once for both layouts --------------------------------------
    def _params(self, hyper, env_params) -> SearchParams:
        env = self.params.env if self.shared_env else env_params
        return SearchParams(env=env, hyper=hyper)

    def _init_one(self, key, hyper, env_params):
        k_init, _, _ = split_seed_key(key)
        return self.algorithm.init(k_init, self._params(hyper, env_params))

    def _step_one(self, key, state, hyper, env_params):
        _, k_run, _ = split_seed_key(key)
        return self._step(k_run, state, self._params(hyper, env_params))

    def _finish_start_one(self, state, hyper, env_params):
        return self.algorithm.finish_start(state, self._params(hyper, env_params))

    def _finish_advance_one(self, work, hyper, env_params):
        return self.algorithm.finish_advance(work, self._params(hyper, env_params))

    # -- the programs --------------------------------------------------------------------
    def compiled(self, what: str, fn, args: tuple, before_compile=None):
        """``fn(*args)`` compiled once (``compiled_program``). One run: the params are
        constants of the program, except the held arrays (``hoist_large``), which a ``fn``
        that needs them takes as its last argument (``_one``). Several runs: ``fn`` is mapped
        over them (``per_run``), the first run's env params constants when all runs share
        them."""
        if not self.batched:
            constants = baked_constants(self.params)
            identity = program_identity(self.config, search=True)
        else:
            constants = self.params.env if self.shared_env else []
            fn = per_run(fn, self.sharding, len(args))
            devices = [d.id for d in self.sharding.mesh.devices.flat]
            identity = program_identity(
                self.config, search=True, devices=devices, shared=self.shared_env
            )
        return compiled_program(self.config, what, fn, args, constants, identity, before_compile)

    def _one(self, method):
        """``method(*args, params)`` as a function of a single run's arguments and the held
        arrays (last)."""
        return lambda *args: method(*args[:-1], self._rebuild(args[-1]))

    def init(self):
        """The initial state (every run's, stacked when batched)."""
        if not self.batched:
            init = self._one(self.algorithm.init)
            return self.compiled("the initial state", init, (self.k_init, self.held))(
                self.k_init, self.held
            )
        return self.compiled("the initial states", self._init_one, self.data)(*self.data)

    def compile_step(self, state, before_compile=lambda: None):
        """``(step(state) -> (state, metrics), compile seconds)``: one iteration of every run,
        checked against the memory budget (``before_compile()`` is called once that passed)
        and compiled ahead of time; ``step.metrics_shapes``: one iteration's metrics, as
        shapes (to restore a checkpoint's history)."""
        t0 = time.perf_counter()
        if not self.batched:
            args = (self.k_run, state, self.held)
            fn = lambda k, s, h: self._step(k, s, self._rebuild(h))  # noqa: E731
            compiled = self.compiled("one iteration", fn, args, before_compile)
            step = lambda s: compiled(args[0], s, self.held)  # noqa: E731
        else:
            keys, hyper, env = self.data
            what = f"one iteration of {len(keys)} runs"
            args = (keys, state, hyper, env)
            compiled = self.compiled(what, self._step_one, args, before_compile)
            step = lambda s: compiled(keys, s, hyper, env)  # noqa: E731
        step.metrics_shapes = compiled.out_shapes[1]
        return step, time.perf_counter() - t0

    def finish(self, state, report=lambda work: None):
        """``(state, info)``: the algorithm's ``finish`` of every run (``info`` stacked), run
        as its steps (``finish_start``, ``finish_advance`` until ``finish_done``,
        ``finish_end``; the same steps ``make_train`` runs in one ``while_loop``), with
        ``report(work)`` after each step. Runs that are done stay as they are while the
        others advance."""
        alg = self.algorithm
        if not self.batched:
            args = (self.held,)
            start_fn, advance_fn = self._one(alg.finish_start), self._one(alg.finish_advance)
        else:
            _, hyper, env = self.data
            args = (hyper, env)
            start_fn, advance_fn = self._finish_start_one, self._finish_advance_one
        start = self.compiled("the polish", start_fn, (state, *args))
        if start.out_shapes is None:  # nothing to do (no polish)
            return state, None
        work = start(state, *args)
        advance = self.compiled("a polish step", advance_fn, (work, *args))
        done = self.compiled("the polish's end", alg.finish_done, (work,))
        while not np.all(np.asarray(done(work))):
            work = advance(work, *args)
            report(work)
        return self.compiled("the polished state", alg.finish_end, (state, work))(state, work)

    def best_policies(self, state) -> list:
        """Every run's best policy, on the host."""
        if not self.batched:
            return [jax.device_get(self.algorithm.best_policy(state))]
        best = jax.device_get(jax.vmap(self.algorithm.best_policy)(state))
        return [take(best, r) for r in range(len(self.runs))]

    def evaluate(self, r: int, policy) -> dict:
        """Run ``r``'s honest value (``honest_summary``), compiled once per env params."""
        params = self.run_params[r]
        found = [fn for env, fn in self._evaluations if _same_tree(env, params.env)]
        if not found:
            config = self.runs[r].config
            found = [honest_evaluation(self.algorithm, config, params, self.lanes)]
            self._evaluations.append((params.env, found[0]))
        return found[0](self.seed_keys[r], policy)


def honest_evaluation(algorithm, config: Config, params: SearchParams, lanes: int = 1):
    """``evaluate(seed_key, policy) -> {"mean", "stderr", "rollouts"}``: the one honest
    evaluation (``api.honest_returns`` with ``config.evaluation``), ``params`` constants of
    the compiled program (``compiled_program``: checked against ``run.memory_gb`` when first
    traced, kept by ``traced.compile_kept``), the mean and standard error summed in float64 on
    the host. ``lanes``: the searches ``algorithm`` was built to run side by side."""
    held, rebuild = hoist_large(params)
    run = honest_returns(algorithm, config.evaluation)
    returns = lambda k, p, h: run(k, p, rebuild(h))  # noqa: E731
    constants = baked_constants(params)
    identity = program_identity(config, lanes=lanes)
    compiled: dict = {}  # by the policy's shapes and types

    def evaluate(key, policy):
        args = (key, jax.tree.map(jnp.asarray, policy), held)
        shapes = str(jax.tree.map(lambda x: (x.shape, x.dtype), args[1]))
        if shapes not in compiled:
            compiled[shapes] = compiled_program(
                config, "the honest evaluation", returns, args, constants, identity
            )
        return return_summary(compiled[shapes](*args))

    return evaluate


def return_summary(returns) -> dict:
    """``{"mean", "stderr", "rollouts"}`` of a 1-D array of returns (in float64); an
    ``InputError`` when a return is not finite (float32 overflowed: rewards too large for the
    horizon)."""
    returns = np.asarray(returns, dtype=np.float64)
    if np.isnan(returns).any():
        raise InputError(
            "the returns are NaN: the simulator's rewards are NaN on some states (or an "
            "infinite reward met its negative)"
        )
    if not np.isfinite(returns).all():
        raise InputError(
            "the returns are not finite: the rewards overflow float32 over this horizon "
            "(lower the rewards or the horizon)"
        )
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
    model = load_problem(config.problem)
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


# ---------------------------------------------------------------------------------------------
# the loop
# ---------------------------------------------------------------------------------------------
@dataclasses.dataclass
class Checkpointing:
    """When a group saves its state: ``path`` of the checkpoint file (``None``: never),
    every ``every`` iterations and every ``seconds`` seconds of search (0: not by that)."""

    path: Path | None
    every: int = 0
    seconds: float = 0.0

    def due(self, iteration: int, since_last: float) -> bool:
        """Whether a checkpoint is due after ``iteration``, ``since_last`` seconds after the
        last one."""
        if self.path is None:
            return False
        by_count = self.every > 0 and iteration % self.every == 0
        return by_count or (self.seconds > 0 and since_last >= self.seconds)


#: seconds a stopped loop waits for the iteration in flight before it keeps the last finished one
STOP_GRACE_S = 5.0
#: the loop dispatches iterations ahead of the one it waits for, about this many seconds of
#: them (at least 2; at most ``AHEAD_MAX`` and ``AHEAD_BYTES`` of search states)
AHEAD_S = 0.1
AHEAD_MAX = 256
AHEAD_BYTES = 256 * 2**20


def wait_ready(tree, flag=None, timeout: float | None = None) -> bool:
    """Wait until every array of ``tree`` is computed; ``False`` when ``flag["signum"]`` is
    set (a stop signal) or ``timeout`` seconds pass first. The blocking wait runs in a waiter
    thread (``signals.wait_for``), so the main thread stays free for signal handlers."""
    leaves = [x for x in jax.tree.leaves(tree) if isinstance(x, jax.Array)]
    pause = 1e-4
    while pause < 0.01:  # a short wait polls (cheaper than waking a thread)
        if all(x.is_ready() for x in leaves):
            return True
        time.sleep(pause)
        pause *= 2
    return wait_for(jax.block_until_ready, leaves, flag, timeout)


class Ahead:
    """How many iterations the loop keeps dispatched: about ``AHEAD_S`` seconds of them, from
    the mean time between finished iterations, so short iterations queue up (the dispatch
    overhead hides behind the computation) while long ones stay two deep; bounded by
    ``AHEAD_MAX`` and by ``AHEAD_BYTES`` of search states in flight."""

    def __init__(self, state):
        size = sum(x.nbytes for x in jax.tree.leaves(state) if hasattr(x, "nbytes"))
        self.cap = int(max(2, min(AHEAD_MAX, AHEAD_BYTES // max(size, 1))))
        self.depth, self.count, self.t0 = 2, 0, time.perf_counter()

    def finished(self) -> None:
        self.count += 1
        mean = (time.perf_counter() - self.t0) / self.count
        self.depth = int(max(2, min(self.cap, AHEAD_S / max(mean, 1e-6))))


def iterate(
    step, state, *, start, iterations, history, checkpointing, save, progress, desc, probe=None
):
    """``state, metrics = step(state)`` from iteration ``start`` to ``iterations``, each
    finished iteration's metrics appended to ``history``; returns ``(state, signum)``: the state
    after the last finished iteration (``len(history)``) and the stop signal that came during
    the loop (``None`` when none did).

    Iterations are dispatched ahead of the one waited for (``Ahead``: about 0.1 s of them, at
    least 2); the loop waits on an event (``wait_ready``), so a stop signal is seen at once.
    It then waits at most ``STOP_GRACE_S`` for the oldest iteration in flight and keeps the
    last finished state.
    ``save(i, state, history)`` writes a checkpoint (``checkpointing``); ``probe(i, state)``
    is called after every finished iteration (``Probes``)."""
    last_save = time.perf_counter()
    bar = tqdm(total=iterations, disable=not progress, desc=desc, unit="it", dynamic_ncols=True)
    done, flight = state, []  # the last finished state; (state, metrics) dispatched, oldest first
    ahead = Ahead(state)
    with deferred_stop() as flag, bar:
        bar.update(start)
        while len(history) < iterations:
            while len(flight) < ahead.depth and len(history) + len(flight) < iterations:
                if flag["signum"] is not None:
                    break
                flight.append(step(flight[-1][0] if flight else done))
            if not flight:
                break
            state, metrics = flight.pop(0)
            if not wait_ready(metrics, flag) and not wait_ready(metrics, timeout=STOP_GRACE_S):
                break
            ahead.finished()
            done = state
            history.append(metrics)
            i = len(history)
            if flag["signum"] is not None:
                break
            if probe is not None:
                probe(i, done)
            if i < iterations and checkpointing.due(i, time.perf_counter() - last_save):
                save(i, done, history)
                last_save = time.perf_counter()
            if progress and (i % 10 == 0 or i == iterations):
                bar.set_postfix(**_postfix(jax.device_get(metrics)))
                bar.update(i - bar.n)
    return done, flag["signum"]


def _postfix(metrics) -> dict:
    value, best = np.asarray(metrics.value), np.asarray(metrics.best_value)
    return {"value": f"{float(value.mean()):.2f}", "best": f"{float(best.max()):.2f}"}


# ---------------------------------------------------------------------------------------------
# a group, from start or checkpoint to its run folders
# ---------------------------------------------------------------------------------------------
def rollout_mesh(config: Config):
    """The context a run's iterations are compiled in: with ``run.shard_rollouts`` a 1-D mesh
    ``("rollouts",)`` over the local devices is set (``jax.set_mesh``), and the rollout
    engine lays every batch of rollouts (and so the candidates' evaluations) over it
    (``rollout.shard_rollouts``); otherwise nothing changes."""
    if not config.run.shard_rollouts:
        return contextlib.nullcontext()
    return jax.set_mesh(Mesh(np.array(jax.local_devices()), ("rollouts",)))


def _meta(runs: list[Run]) -> dict:
    """What a checkpoint was written by (compared on resume, ``run`` sections aside)."""
    return {
        "kind": "runs",
        "runs": [[r.setting, r.seed] for r in runs],
        "configs": [r.config.to_dict() for r in runs],
    }


def _without_run_section(meta: dict) -> dict:
    meta = json.loads(json.dumps(meta))
    for config in meta.get("configs", []):
        config.pop("run", None)
    return meta


def _run_keys(program: Program):
    keys = [split_seed_key(k)[1] for k in program.seed_keys]
    return keys[0] if not program.batched else jnp.stack(keys)


def _save(program: Program, path: Path, iteration: int, state, history) -> None:
    save_checkpoint(
        path,
        state=state,
        keys={"run": _run_keys(program)},
        iteration=iteration,
        history=stack_history(history),
        meta=_meta(program.runs),
    )


def _current_meta(meta: dict, path) -> dict:
    """``meta`` of a checkpoint in today's form: a ``train`` checkpoint of the earlier runner is
    the group of its one run; an earlier sweep's cannot be read (it kept no run keys)."""
    kind = meta.get("kind")
    if kind == "train" and "config" in meta and "seed" in meta:
        return {"kind": "runs", "runs": [[0, meta["seed"]]], "configs": [meta["config"]]}
    if kind != "runs":
        raise MismatchError(
            f"{path} holds a {kind!r} checkpoint of an earlier cognet-jax; resume it with that "
            "version, or start again"
        )
    return meta


def _restore(program: Program, state, path: Path):
    """``(state, raw, iteration)`` from the checkpoint at ``path`` (``raw``: what
    ``read_checkpoint`` read, whose history ``restore_history`` restores); ``MismatchError``
    when another group (configs, seeds or generator) wrote it."""
    raw = read_checkpoint(path)
    raw["meta"] = _current_meta(raw["meta"], path)
    if _without_run_section(raw["meta"]) != _without_run_section(_meta(program.runs)):
        raise MismatchError(f"{path} was written by another config or seed")
    stored = restore_key(raw, "run", program.config.run.prng_impl)
    expected = jax.random.key_data(_run_keys(program))
    if not np.array_equal(np.asarray(jax.random.key_data(stored)), np.asarray(expected)):
        raise MismatchError(f"{path}: stored run keys do not match the seeds")
    restored = restore_state(jax.device_get(state), raw)
    # laid out as the initial state (its programs are compiled for that layout)
    state = jax.tree.map(lambda x, like: jax.device_put(x, like.sharding), restored, state)
    return state, raw, int(raw["iteration"])


def _history(step, raw: dict, path: Path) -> list:
    """The checkpoint's per-iteration metrics, shaped as ``step``'s (after it is compiled: its
    output shapes are the template); ``CorruptFileError`` when they do not fit."""
    try:
        return restore_history(step.metrics_shapes, raw)
    except (ValueError, KeyError, TypeError, IndexError, AttributeError) as err:
        raise CorruptFileError(path, f"history does not fit: {err}") from None


def _polish_records(info, runs: int, seconds: float) -> list:
    """Each run's polish record for results.json (``None`` without a polish)."""
    if info is None:
        return [None] * runs
    info = jax.device_get(info)
    pick = (lambda x, r: x[r]) if np.ndim(info.before) else (lambda x, r: x)
    return [
        {
            "value_before": float(pick(info.before, r)),
            "value_after": float(pick(info.after, r)),
            "moves_applied": int(pick(info.moves_applied, r)),
            "moves_per_sweep": int(info.moves_per_sweep),
            "best_responses_applied": int(pick(info.responses_applied, r)),
            "exact_evaluations": int(pick(info.evaluations, r)),
            "budget": int(info.budget),
            "seconds": seconds,
        }
        for r in range(runs)
    ]


def _settings_dict(algorithm) -> dict:
    """The algorithm's settings as built (e.g. the evaluator "auto" chose)."""
    settings = getattr(algorithm, "settings", None)
    if not dataclasses.is_dataclass(settings):
        return {}
    out = dataclasses.asdict(settings)
    searches = getattr(algorithm, "searches", None)
    if searches is not None:  # a G-DICE portfolio: its member searches
        out["searches"] = searches
    return json.loads(json.dumps(out, default=str))


def run_record(run: Run, program: Program, **fields) -> dict:
    """The results.json of ``run`` (``RESULTS_SCHEMA``), from ``fields``: ``status``,
    ``iteration``, ``final_value`` and, for a finished run, its history and timings."""
    config = run.config
    record = {
        "schema": RESULTS_SCHEMA,
        "experiment": config.experiment.name,
        "algorithm": config.experiment.algorithm,
        "seed": run.seed,
        "setting": run.setting,
        "grid": run.grid,
        "config": config.to_dict(),
        "resolved": _settings_dict(program.algorithm),
        "iterations": config.algorithm.iterations,
        "runs_in_program": len(program.runs),
        "jax_version": jax.__version__,
        "backend": jax.default_backend(),
    }
    record.update(fields)
    return record


def _history_fields(history, r: int | None, iterations: int, algorithm) -> dict:
    """The per-iteration fields of run ``r`` (``None``: an unbatched history)."""
    h = history if r is None else jax.tree.map(lambda x: x[:, r], history)
    env = algorithm.env
    return {
        "in_loop_best": float(h.best_value[-1]),
        # the search's budget: agent-steps simulated by all its iterations
        "simulated_agent_steps": iterations
        * algorithm.rollouts_per_iteration
        * env.horizon
        * env.num_agents,
        "values_per_iteration": np.asarray(h.value).tolist(),
        "best_per_iteration": np.asarray(h.best_value).tolist(),
        "threshold_per_iteration": np.asarray(h.threshold).tolist(),
        "kept_per_iteration": np.asarray(h.kept).tolist(),
        "entropy_injections": int(np.sum(h.injected)),
    }


def fingerprint(config: Config, written: dict | None = None) -> dict:
    """What shapes a policy, hashed: ``config`` without its ``run`` and ``evaluation`` sections
    (as ``written`` to results.json when given: a newer version of the library may add
    settings with defaults, which must not make an old run's policy a stranger), the model
    file it reads (a simulator that reads ``[problem]``) and the numeric settings. Stored in
    the policy file; ``load_run`` refuses a policy whose results.json or model changed since."""
    written = config.to_dict() if written is None else written
    shaping = {k: v for k, v in written.items() if k not in ("run", "evaluation")}
    text = json.dumps(shaping, sort_keys=True, default=str).encode()
    out = {"config": hashlib.sha256(text).hexdigest(), "numerics": numeric_settings()}
    path = Path(config.problem.path).expanduser() if config.problem.path else None
    if path is not None and "problem" in env_entry(config.env.name).reads and path.is_file():
        out["model"] = _file_digest(path)
    return out


def numeric_settings() -> dict:
    """What besides the config changes a policy's numbers: JAX's 64-bit mode and default PRNG,
    and the modules imported from outside the package (``--import``) with their digests."""
    return {
        "x64": bool(jax.config.jax_enable_x64),
        "prng": str(jax.config.jax_default_prng_impl),
        "imported": foreign_code(),
    }


def write_run(run: Run, record: dict, policy, algorithm, plots: bool = False) -> None:
    """A run's training folder: ``policy.msgpack`` (with its ``fingerprint``),
    ``results.json``, the pipeline's VAE and, with ``plots``, the figures
    (``reporting.write_plots``)."""
    if run.folder is None:
        return
    run.folder.mkdir(parents=True, exist_ok=True)
    policy_file = policy_bytes(policy, fingerprint(run.config))
    atomic_write_bytes(run.folder / "policy.msgpack", policy_file)
    vae = getattr(getattr(algorithm, "pipeline", None), "vae", None)
    if vae is not None:
        save_vae(run.folder / VAE_FILE, vae)
    atomic_write_text(run.folder / "results.json", json.dumps(record, indent=1))
    if plots and record.get("status") == "complete":
        write_plots(run.config, algorithm, policy, record, run.folder)


@dataclasses.dataclass
class GroupOptions:
    """How ``run_group`` drives a group: ``checkpoint`` file (``None``: none), ``resume`` from
    it, ``progress`` bar (``None``: ``run.progress``), ``log`` for lines a person reads, ``desc``
    of the bar, ``resume_dir`` named by ``Interrupted``, and ``announce``: a run of its own
    (``train``), which logs its result and draws its plots (``run.plots``); a sweep's runs do
    neither (the sweep writes its tables)."""

    checkpoint: Path | None = None
    resume: bool = False
    progress: bool | None = None
    log: Any = print
    desc: str | None = None
    resume_dir: Path | None = None
    announce: bool = False


def _stop(program: Program, state, iteration: int, opts: GroupOptions, signum):
    """Keep what a stopped group has (checkpoint, every run's best policy) and raise
    ``Interrupted``."""
    with deferred_stop():  # what was found is written even if the signal comes again
        best = program.best_policies(state)
        for r, run in enumerate(program.runs):
            record = run_record(run, program, status="interrupted", iteration=iteration)
            write_run(run, dict(record, final_value=None), best[r], program.algorithm)
    out = opts.resume_dir or (opts.checkpoint.parent if opts.checkpoint else Path("."))
    raise Interrupted(out, iteration, program.config.algorithm.iterations, signum)


def run_group(runs: list[Run], opts: GroupOptions | None = None) -> tuple[list[dict], dict]:
    """Run every run of ``runs`` (one compiled program; see the module docstring) and write
    their folders; returns ``(records, timing)``, one results.json record per run.

    ``opts.checkpoint`` is written every ``run.checkpoint_every`` iterations, every
    ``run.checkpoint_seconds`` seconds, at the end of the search and on a stop signal (then
    ``Interrupted`` is raised, naming ``opts.resume_dir``); ``opts.resume`` continues from it
    bit for bit."""
    opts = opts or GroupOptions()
    config = runs[0].config
    if opts.progress is None:
        opts = dataclasses.replace(opts, progress=config.run.progress)
    with rollout_mesh(config):
        return _run(runs, opts, time.perf_counter())


@dataclasses.dataclass
class _Searched:
    """A group's search, done: its final state, per-iteration metrics, the iteration it
    started from, and timings (seconds; ``t_start``, ``t_loop`` and ``t_searched``, the end of
    the loop before its checkpoint is written: ``time.perf_counter``)."""

    state: Any
    history: list
    start: int
    compile_s: float
    t_start: float
    t_loop: float
    t_searched: float
    probes: Any = None


def _prepare(runs: list[Run], opts: GroupOptions):
    """``(program, state, history, start, step, compile_s)``: the group's program built, its
    state initialised or restored from ``opts.checkpoint``, one iteration compiled;
    ``compile_s``: the initial state's and the iteration's programs, compiled or loaded. Run in a
    worker thread (``signals.in_background``): a stop signal ends the command at once, leaving
    the folder as it was (no iteration has finished)."""
    config = runs[0].config
    seconds = sum(check_budget(r.config, build_env(r.config)[0]) for r in runs)
    if seconds > LONG_SECONDS:
        print(
            f"warning: {config.experiment.name}: {len(runs)} run(s) of at least "
            f"{seconds / 3600:.1f} h of simulation (agent-steps at {FASTEST_RATE:.0e}/s, the "
            "fastest rate measured; the progress bar shows this machine's)",
            file=sys.stderr,
        )

    what = f"{config.experiment.name}" + (f" ({len(runs)} runs)" if len(runs) > 1 else "")

    def announce():  # once the iteration passed the memory check: a refusal is the only line
        print(f"compiling {what} ...", file=sys.stderr, flush=True)

    def prepare():
        with rollout_mesh(config):
            program = Program(runs)
            t0 = time.perf_counter()
            state, raw, start = program.init(), None, 0
            init_s = time.perf_counter() - t0  # its compilation (the run is dispatched)
            if opts.resume and opts.checkpoint is not None and opts.checkpoint.exists():
                state, raw, start = _restore(program, state, opts.checkpoint)
                total = config.algorithm.iterations
                opts.log(f"resuming {config.experiment.name} at iteration {start}/{total}")
            step, step_s = program.compile_step(state, announce)
            compile_s = init_s + step_s
            print(f"compiled {what} in {compile_s:.1f} s", file=sys.stderr, flush=True)
            history = [] if raw is None else _history(step, raw, opts.checkpoint)
        return program, state, history, start, step, compile_s

    return in_background(prepare)


def _search(runs, opts: GroupOptions, t_start: float):
    """``(program, _Searched)``: every iteration of the group, from its start or its
    checkpoint; on a stop signal (also one during the last iteration) the checkpoint and the
    best policies so far are written and ``Interrupted`` is raised."""
    program, state, history, start, step, compile_s = _prepare(runs, opts)
    config = program.config
    run = config.run
    checkpointing = Checkpointing(opts.checkpoint, run.checkpoint_every, run.checkpoint_seconds)

    def save(i, state, history):
        _save(program, opts.checkpoint, i, state, history)

    t_loop = time.perf_counter()
    probes = Probes(program, run.probe_seconds, t_start)
    state, signum = iterate(
        step,
        state,
        start=start,
        iterations=config.algorithm.iterations,
        history=history,
        checkpointing=checkpointing,
        save=save,
        progress=opts.progress,
        desc=opts.desc or config.experiment.name,
        probe=probes if run.probe_seconds > 0 else None,
    )
    t_searched = time.perf_counter()
    if opts.checkpoint is not None:
        with deferred_stop():  # a signal now stops the group once this is written
            save(len(history), state, history)
    if signum is not None:
        _stop(program, state, len(history), opts, signum)
    searched = _Searched(state, history, start, compile_s, t_start, t_loop, t_searched, probes)
    return program, searched


class Probes:
    """Snapshots of every run's anytime best, looked at each ``seconds`` of the run (from its
    start, compile included) and kept when it changed: ``(iteration, wall seconds, best
    policies)``. ``evaluated`` gives each
    its honest evaluation once the search is over (the search's time is not spent on them)."""

    def __init__(self, program: Program, seconds: float, t_start: float):
        self.program, self.seconds, self.t_start = program, seconds, t_start
        self.kept: list = []
        self.last = -math.inf

    def __call__(self, iteration: int, state) -> None:
        now = time.perf_counter()
        if now - self.last >= self.seconds:
            self.last = now
            best = jax.device_get(self.program.best_policies(state))
            if not self.kept or not _same_tree(best, self.kept[-1][2]):  # a new best only
                self.kept.append((iteration, now - self.t_start, best))

    def evaluated(self, r: int) -> list[dict]:
        """Run ``r``'s probes with their honest values."""
        out = []
        for iteration, wall, best in self.kept:
            value = self.program.evaluate(r, best[r])
            out.append({"iteration": iteration, "wall_s": wall, "value": value["mean"]})
        return out


def _finish_and_evaluate(program: Program, state, progress: bool, probes=None):
    """``(state, polish records, final values, best policies, probe records)``: the
    algorithm's ``finish`` (G-DICE's polish, with a progress line when ``progress``), every
    run's honest evaluation and that of its probes (``Probes``), in a worker thread
    (``signals.in_background``), so a stop signal is obeyed at once."""

    line = _FinishLine(progress)

    def work():
        t_polish = time.perf_counter()
        try:
            finished, info = jax.block_until_ready(program.finish(state, line.report))
        finally:
            line.close()
        polish = _polish_records(info, len(program.runs), time.perf_counter() - t_polish)
        best = program.best_policies(finished)
        finals = []
        for r, run in enumerate(program.runs):
            final = program.evaluate(r, best[r])
            final.update(exact_evaluation(run.config, best[r]) or {})
            finals.append(final)
        probing = probes is not None and probes.seconds > 0
        kept = [probes.evaluated(r) if probing else None for r in range(len(program.runs))]
        return finished, polish, finals, best, kept

    with rollout_mesh(program.config):
        try:
            return in_background(work)
        except Stopped:
            line.close()  # the stop's line starts on a line of its own
            raise


class _FinishLine:
    """The progress line of ``finish`` (shown with ``progress``, from its first step): for a
    polish, the moves applied, the best exact value and the exact evaluations spent so far
    (the largest over runs and candidates), and the time."""

    def __init__(self, progress: bool):
        self.progress, self.bar = progress, None

    def report(self, work) -> None:
        if not self.progress:
            return
        if self.bar is None:
            self.bar = tqdm(desc="polish", unit="step", dynamic_ncols=True)
        self.bar.update(1)
        fields = ("moves_applied", "value", "spent")
        if all(hasattr(work, f) for f in fields):
            moves, value, spent = (np.max(np.asarray(getattr(work, f))) for f in fields)
            self.bar.set_postfix(
                moves=int(moves), value=f"{float(value):.6g}", evaluations=int(spent)
            )

    def close(self) -> None:
        bar, self.progress = self.bar, False  # no new bar after this (the worker may go on)
        if bar is not None:
            bar.close()


def _run(runs, opts: GroupOptions, t_start: float):
    """``(records, timing)`` of the group: search, finish (polish), the honest evaluation of
    every run's best policy, its folder. A stop signal after the search keeps the search's best
    policies (``_stop``); one while the folders are written lets them be finished first."""
    program, done = _search(runs, opts, t_start)
    iterations = program.config.algorithm.iterations
    stacked = stack_history(done.history)  # on the host: a jnp.stack of 500 arrays compiles
    t_end = time.perf_counter()
    try:
        _, polish, finals, best, probed = _finish_and_evaluate(
            program, done.state, opts.progress, done.probes
        )
    except Stopped as stop:
        _stop(program, done.state, iterations, opts, stop.signum)
    polish_s = (polish[0] or {}).get("seconds", 0.0)
    timing = {
        "compile_s": done.compile_s,
        "loop_s": done.t_searched - done.t_loop + polish_s,
        "eval_s": time.perf_counter() - t_end - polish_s,
        "runs": len(runs),
        "resumed_from_iteration": done.start or None,
    }
    with deferred_stop() as flag:
        records = _write_runs(program, done, stacked, opts, timing, polish, finals, best, probed)
    if opts.announce:
        _log_run(records[0], runs[0], opts.log)
    if flag["signum"] is not None:
        raise Stopped(flag["signum"])
    return records, timing


def _write_runs(program, done, stacked, opts, timing, polish, finals, best, probed) -> list:
    """Every run's record (results.json) written with its folder (plots: ``opts.announce``
    and ``run.plots``)."""
    iterations = program.config.algorithm.iterations
    records = []
    for r, run in enumerate(program.runs):
        history = _history_fields(
            stacked, r if program.batched else None, iterations, program.algorithm
        )
        record = run_record(
            run,
            program,
            status="complete",
            iteration=iterations,
            resumed_from_iteration=done.start if opts.resume else None,
            final_value=finals[r],
            polish=polish[r],
            wall_s=time.perf_counter() - done.t_start,
            **{k: timing[k] for k in ("compile_s", "loop_s", "eval_s")},
            peak_rss_bytes=peak_rss_bytes(),
            **history,
        )
        if probed[r] is not None:
            record["probes"] = probed[r]
        plots = opts.announce and run.config.run.plots
        write_run(run, record, best[r], program.algorithm, plots=plots)
        records.append(record)
    return records


def _log_run(record: dict, run: Run, log) -> None:
    polish, final = record["polish"], record["final_value"]
    if polish is not None:
        log(
            f"polish: exact {polish['value_before']:.6f} -> {polish['value_after']:.6f} "
            f"({polish['moves_applied']} moves of {polish['moves_per_sweep']} tried per sweep, "
            f"{polish['best_responses_applied']} best responses, {polish['seconds']:.1f} s)"
        )
    exact = f" (exact {final['exact']:.6f})" if "exact" in final else ""
    log(
        f"{record['experiment']} seed {record['seed']}: honest value {final['mean']:.3f} "
        f"+- {final['stderr']:.3f} ({final['rollouts']} rollouts){exact}; in-loop best "
        f"{record['in_loop_best']:.3f}; wall {record['wall_s']:.1f} s (compile "
        f"{record['compile_s']:.1f} s)"
    )
    if run.folder is not None:
        plots = " and plots" if run.config.run.plots else ""
        log(f"wrote {run.folder}/results.json, policy.msgpack{plots}")


# ---------------------------------------------------------------------------------------------
# one run: train, resume, load, evaluate
# ---------------------------------------------------------------------------------------------
def train(config: Config, seed: int, out_dir, progress=None, log=print, resume=False) -> dict:
    """Run the search of ``config`` with ``seed`` and write its folder ``out_dir``: the group
    of one run (``run_group``), checkpointed to ``out_dir/checkpoint.msgpack``; ``resume``
    continues from that checkpoint. Returns the run's results.json record."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    opts = GroupOptions(out / CHECKPOINT_NAME, resume, progress, log, resume_dir=out, announce=True)
    records, _ = run_group([Run(config, seed, out)], opts)
    return records[0]


def resume_target(run_dir, overrides: list[str] | None = None) -> tuple[Config, int]:
    """``(config, seed)`` stored in the checkpoint of the run folder ``run_dir``.
    ``overrides`` may only touch the ``run`` section (progress, plots, checkpoints)."""
    for text in overrides or []:
        (section, _), _ = parse_override(text)
        if section != "run":
            raise ConfigError(text.split("=")[0], "cannot be changed when resuming")
    path = Path(run_dir) / CHECKPOINT_NAME
    meta = _current_meta(read_checkpoint(path)["meta"], path)
    if len(meta.get("runs", [])) != 1:
        raise ConfigError("", f"{run_dir} holds no checkpoint of a single train run")
    config = config_from_dict(apply_overrides(meta["configs"][0], overrides or []))
    return config, int(meta["runs"][0][1])


@dataclasses.dataclass
class LoadedRun:
    """A finished (or stopped) run folder: its config (with overrides), the search and params
    built from it, its best policy and its results.json."""

    config: Config
    algorithm: Any
    params: SearchParams
    policy: Any
    results: dict


def load_run(run_dir, overrides: list[str] | None = None) -> LoadedRun:
    """The run in ``run_dir``. ``overrides`` (``--set``) may change the evaluation setting,
    e.g. ``env.obs_noise=0.1``; shapes must match. The run's own ``vae.msgpack`` (if any) is
    used unless ``network.vae_path`` is overridden."""
    run_dir = Path(run_dir)
    results_path = run_dir / "results.json"
    if not results_path.is_file():
        raise FileNotFoundError(f"{results_path} not found: is {run_dir} a training output folder?")
    results = read_json(results_path, ("config",))
    if not isinstance(results["config"], dict):
        raise CorruptFileError(results_path, "its config is not a table of sections")
    trained = fingerprint(config_from_dict(results["config"]), results["config"])
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
    algorithm, params = build_algorithm(config)
    # the policy's structure and shapes, traced (running ``init`` op by op took seconds)
    template = jax.eval_shape(
        lambda k: algorithm.best_policy(algorithm.init(k, params)), jax.random.key(0)
    )
    saved = read_policy(run_dir / "policy.msgpack", template, fingerprint=trained)
    policy = jax.tree.map(jnp.asarray, saved)
    return LoadedRun(config, algorithm, params, policy, results)


def evaluate_run(run_dir, rollouts: int | None = None, seed: int | None = None, overrides=()):
    """The honest value of the best policy in ``run_dir``: by default the run's own
    evaluation (its seed's evaluation key, ``evaluation.rollouts``), which reproduces its
    results.json ``final_value``; ``seed`` draws from that seed's evaluation key instead,
    ``rollouts`` changes the number, ``overrides`` the setting. Returns the summary with
    ``seed``, ``overrides`` and ``wall_s``."""
    t0 = time.perf_counter()
    run = load_run(run_dir, list(overrides))
    config = run.config
    if rollouts is not None:
        evaluation = dataclasses.replace(config.evaluation, rollouts=rollouts)
        config = dataclasses.replace(config, evaluation=evaluation)
        check_budget(config, run.algorithm.env)  # the time and memory they take
    stored = run.results.get("seed", 0)
    if seed is None and (not isinstance(stored, int) or isinstance(stored, bool) or stored < 0):
        raise CorruptFileError(Path(run_dir) / "results.json", f"seed {stored!r} is no seed")
    seed = stored if seed is None else seed
    evaluate = honest_evaluation(run.algorithm, config, run.params)
    value = evaluate(seed_key(config, seed), run.policy)
    value.update(seed=seed, overrides=list(overrides), wall_s=time.perf_counter() - t0)
    return value
