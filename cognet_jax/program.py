"""The compiled program of a group of runs (``Program``): the search's initial state, one
iteration of every run, the algorithm's ``finish`` and each run's honest evaluation, compiled
once and kept (``traced.compile_kept``) under a key of what they depend on
(``program_identity``).

A *group* is a list of runs (``Run``: config, seed, folder) that share one compiled program:
``cognet-jax train`` is a group of one run, a sweep (``cognet_jax.sweep``) runs one group per
set of settings that differ only in dynamic fields. A group of one runs the search as it is,
its params constants of the programs (as in ``api.make_train(config)`` called without
params); a larger group ``vmap``s it over a leading ``[runs]`` axis, sharded over the local
devices (``shard_map``, no collectives), the hyper-parameters data (stacked over ``[runs]``)
and the env params too when the runs differ in them. Run r of a group uses exactly the keys of
``train --seed s`` (``api.split_seed_key``, iteration i with ``fold_in(run_key, i)``).

Every run ends with the one honest evaluation (``final_value``: ``api.final_returns``,
``evaluation.rollouts`` fresh rollouts of its best policy from the seed's evaluation key),
compiled with the run's params as constants -- the function ``cognet-jax evaluate DIR`` runs to
reproduce it.
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from cognet_jax import status
from cognet_jax.algorithms.engine import SearchParams
from cognet_jax.api import (
    Built,
    build,
    iteration_step,
    params_of,
    seed_keys,
    split_seed_key,
)
from cognet_jax.compiled import (
    baked_constants,
    compiled_program,
    hoist_large,
    program_identity,
)
from cognet_jax.config import Config
from cognet_jax.errors import UsageError
from cognet_jax.honest_value import final_value
from cognet_jax.memory import budget_bytes, trace_checked
from cognet_jax.registry import (
    env_entry,
)


@dataclasses.dataclass(frozen=True)
class Run:
    """One search of a group: its config, seed and training folder (``None``: no files);
    ``setting`` and ``grid`` say which setting of a sweep it is."""

    config: Config
    seed: int
    folder: Path | None = None
    setting: int = 0
    grid: dict = dataclasses.field(default_factory=dict)


def same_tree(a, b) -> bool:
    """Whether two pytrees of arrays have the same structure and values."""
    leaves_a, leaves_b = jax.tree.leaves(a), jax.tree.leaves(b)
    return jax.tree.structure(a) == jax.tree.structure(b) and all(
        np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(leaves_a, leaves_b)
    )


#: ``_stack`` stacks at most this many arrays in one operation
STACK_CHUNK = 64


def _stack(trees):
    """The leaves of ``trees`` stacked along a new leading axis (``_stacked``)."""
    return jax.tree.map(lambda *xs: _stacked(xs), *trees)


def shape_of(x) -> jax.ShapeDtypeStruct:
    """``x``'s shape, dtype, sharding and weak type: what a program compiled for it reads."""
    weak = bool(getattr(x, "weak_type", False))
    return jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=x.sharding, weak_type=weak)


def _stack_shared(trees):
    """``_stack(trees)`` where many of ``trees`` are the same object (a sweep's seeds of one
    setting share their params): the distinct ones stacked once, then gathered per run, so
    100,000 runs of one setting stack one tree, not 100,000. The same arrays."""
    first: dict[int, int] = {}
    index = [first.setdefault(id(t), len(first)) for t in trees]
    distinct = list({id(t): t for t in trees}.values())
    stacked = _stack(distinct)
    where = jnp.asarray(index, jnp.int32)
    return jax.tree.map(lambda x: jnp.take(x, where, axis=0), stacked)


def _stacked(xs) -> jax.Array:
    """``jnp.stack(xs)``, at most ``STACK_CHUNK`` arrays at a time: one stack of thousands
    of arrays compiles a program that grows with them (seconds per thousand runs of a
    sweep), while a chunk's program is compiled once and reused. The same array."""
    parts = [
        jnp.stack([jnp.asarray(x) for x in xs[i : i + STACK_CHUNK]])
        for i in range(0, len(xs), STACK_CHUNK)
    ]
    while len(parts) > 1:
        parts = [
            jnp.concatenate(parts[i : i + STACK_CHUNK]) for i in range(0, len(parts), STACK_CHUNK)
        ]
    return parts[0]


def take(tree, r: int):
    """Run ``r`` of a pytree with a leading ``[runs]`` axis."""
    return jax.tree.map(lambda x: x[r], tree)


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


#: program identities whose memory ``Program.check_memory`` found within the budget
_MEMORY_CHECKED: set = set()


class Program:
    """The compiled functions of a group: ``init``, ``step`` (one iteration of every run),
    ``finish`` and each run's honest evaluation. One run: the search itself, params as constants.
    Several: ``vmap`` over ``[runs]`` (padded to ``lanes`` runs at least and to a multiple of the
    local devices by repeating the last run), hyper-parameters as data, env params as data only when
    the runs differ in them (a zero noise level can then not skip its draws,
    ``envs.base.scaled_normal``)."""

    def __init__(self, runs: list[Run], built: Built | None = None, lanes: int = 0):
        self.runs = runs
        # the programs' config: the build's, which a sweep's batches share (``batches``)
        config = runs[0].config if built is None else built.config
        self.config = config
        self.batched = len(runs) > 1 or lanes > 1
        mesh = Mesh(np.array(jax.local_devices()), ("runs",)) if self.batched else None
        self.sharding = NamedSharding(mesh, PartitionSpec("runs")) if mesh else None
        padded = runs + [runs[-1]] * max(0, lanes - len(runs))  # a sweep's last batch
        padded += [runs[-1]] * (-len(padded) % (mesh.size if mesh else 1))
        self.lanes = len(padded)
        self.built = built or build(config, lanes=self.lanes)
        self.algorithm, self.params = self.built.algorithm, self.built.params
        # one run: its params are constants of its programs, except the largest arrays
        self.held, self._rebuild = hoist_large(self.params)
        # every run's params (envs: ``build_env``'s); the first run's are the build's
        # (built once per config object: a sweep's seeds of one setting share theirs)
        made = {id(config): self.params}
        for r in runs[1:]:
            if id(r.config) not in made:
                made[id(r.config)] = params_of(r.config)
        self.run_params = [made[id(r.config)] for r in runs]
        #: ``[runs]`` every run's seed key (``api.seed_keys``: one call, not one per run)
        self.seed_keys = seed_keys([r.config for r in runs], [r.seed for r in runs])
        # the first run's init and run keys (what a single-run program uses)
        self.k_init, self.k_run, _ = split_seed_key(self.seed_keys[0])
        self._step = iteration_step(self.algorithm)
        self._evaluations: list = []  # (env params, compiled honest evaluation)
        self._finish_programs = None  # ``compile_finish``'s
        if self.batched:
            padded_params = self.run_params + [self.run_params[-1]] * (len(padded) - len(runs))
            self.shared_env = all(same_tree(p.env, self.params.env) for p in self.run_params)
            pad = len(padded) - len(runs)
            keys = jnp.concatenate([self.seed_keys, jnp.repeat(self.seed_keys[-1:], pad, 0)])
            hyper = _stack_shared([p.hyper for p in padded_params])
            env = _stack_shared([p.env for p in padded_params])
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
    def compiled(self, what: str, fn, args: tuple, before_compile=None, mapped: bool = True):
        """``fn(*args)`` compiled once (``compiled_program``). One run: the params are
        constants of the program, except the held arrays (``hoist_large``), which a ``fn``
        that needs them takes as its last argument (``_one``). Several runs: ``fn`` is mapped
        over them (``per_run``), the first run's env params constants when all runs share
        them; with ``mapped`` false it is compiled as it is, for one run of the group at a
        time (its hyper-parameters and env params arguments, ``finish_per_run``)."""
        if not self.batched:
            constants = baked_constants(self.params)
            identity = program_identity(self.config, search=True)
        elif not mapped:  # one run of a group, its hyper-parameters and env params as data
            constants = self.params.env if self.shared_env else []
            identity = program_identity(
                self.config, search=True, one_run_of_group=True, shared=self.shared_env
            )
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

    def check_memory(self) -> None:
        """What ``init`` and ``compile_step`` check (``cognet-jax check``), and nothing more:
        the initial state's and one iteration's programs compiled as a run compiles them (and
        kept for it, ``compiled``), each held to ``run.memory_gb`` before compiling
        (``memory.trace_checked``) and after (``memory.check_compiled``); nothing runs. One
        run only."""
        identity = json.dumps(
            program_identity(self.config, search=True), sort_keys=True, default=str
        )
        builders = (env_entry(self.config.env.name).build, type(self.algorithm))
        key = (identity, *builders)
        if key in _MEMORY_CHECKED:  # the same programs passed already (in this process)
            return
        init = self._one(self.algorithm.init)
        args = (self.k_init, self.held)
        told = []

        step = lambda k, s, h: self._step(k, s, self._rebuild(h))  # noqa: E731

        def announce(step_checked: bool = False):
            """Once, when a program is compiled afresh (seconds): a line first. The iteration's
            trace is checked before that line, so that a refusal is the only line printed."""
            if told:
                return
            told.append(True)
            if not step_checked:
                shapes = jax.eval_shape(init, *args)
                memory = budget_bytes(self.config.run.memory_gb)
                trace_checked(jax.jit(step), (self.k_run, shapes, self.held), memory)
            status.say(f"compiling {self.config.experiment.name} to check it ...")

        state = self.compiled("the initial state", init, args, announce).out_shapes
        self.compiled("one iteration", step, (self.k_run, state, self.held), lambda: announce(True))
        _MEMORY_CHECKED.add(key)

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
        self._check_carried(state, compiled.out_shapes[0])
        if not type(self.algorithm).__module__.startswith("cognet_jax."):
            self._check_policy(state)
        return step, time.perf_counter() - t0

    def _check_carried(self, state, after) -> None:
        """``UsageError`` naming the search's ``step`` when an iteration returns a state of
        another structure, shape or dtype than it was given (the next iteration's program
        was compiled for the first: JAX would refuse the call with its own error)."""
        before = jax.eval_shape(lambda x: x, state)
        same = jax.tree.structure(before) == jax.tree.structure(after) and all(
            (a.shape, a.dtype) == (b.shape, b.dtype)
            for a, b in zip(jax.tree.leaves(before), jax.tree.leaves(after))
        )
        if not same:
            search = type(self.algorithm).__name__
            changed = next(
                (
                    f"{a.dtype}{list(a.shape)} became {b.dtype}{list(b.shape)}"
                    for a, b in zip(jax.tree.leaves(before), jax.tree.leaves(after))
                    if (a.shape, a.dtype) != (b.shape, b.dtype)
                ),
                "its structure changed",
            )
            raise UsageError(
                f"{search}.step / tell (the search's code) returned a state unlike the one it "
                f"was given ({changed}): an iteration must keep every array's shape and dtype"
            )

    def _check_policy(self, state) -> None:
        """``UsageError`` naming a plug-in search's ``best_policy`` when the honest evaluation
        cannot run the policy it gives (traced on shapes, before the search: found after it,
        the search's time would be lost to an internal error)."""
        alg, params = self.algorithm, self.run_params[0]
        one = jax.tree.map(lambda x: x[0], state) if self.batched else state
        search = type(alg).__name__
        try:
            jax.eval_shape(
                lambda k, s: alg.returns(k, alg.best_policy(s), 2, params, 2), self.k_init, one
            )
        except Exception as err:
            text = " ".join(str(err).split())[:300]
            raise UsageError(
                f"{search}.best_policy (the search's code) gives a policy its controller "
                f"cannot evaluate: {type(err).__name__}: {text} (a policy of one run, as "
                "the controller's act and next_node read it)"
            ) from None

    def compile_finish(self, state):
        """``(args, start, advance, done)``: the programs of the algorithm's ``finish``
        (``advance`` and ``done`` None when it has nothing to do), compiled once on the
        shapes of ``state`` -- before the search, so a finish over the memory budget is
        refused (or a sweep's group batched, ``batches``) before the search's time is spent."""
        if self._finish_programs is not None:
            return self._finish_programs
        alg = self.algorithm
        if self._finish_per_run:  # one run's programs, run for each run in turn (``finish``)
            one = jax.tree.map(shape_of, self._run_slice((state, *self.data[1:]), 0))
            args = one[1:]
            start_fn = lambda s, h, e: alg.finish_start(s, self._params(h, e))  # noqa: E731
            advance_fn = lambda w, h, e: alg.finish_advance(w, self._params(h, e))  # noqa: E731
            start = self.compiled("the finish of one run", start_fn, one, mapped=False)
            advance = done = None
            if start.out_shapes is not None:
                work = start.out_shapes
                what = "a finish step of one run"
                advance = self.compiled(what, advance_fn, (work, *args), mapped=False)
                done = self.compiled(
                    "the finish's end of one run", alg.finish_done, (work,), mapped=False
                )
            self._finish_programs = (None, start, advance, done)
            return self._finish_programs
        if not self.batched:
            args = (self.held,)
            start_fn, advance_fn = self._one(alg.finish_start), self._one(alg.finish_advance)
        else:
            _, hyper, env = self.data
            args = (hyper, env)
            start_fn, advance_fn = self._finish_start_one, self._finish_advance_one
        start = self.compiled("the finish", start_fn, (jax.tree.map(shape_of, state), *args))
        advance = done = None
        if start.out_shapes is not None:
            work = start.out_shapes
            advance = self.compiled("a finish step", advance_fn, (work, *args))
            done = self.compiled("the finish's end", alg.finish_done, (work,))
        self._finish_programs = (args, start, advance, done)
        return self._finish_programs

    def finish(self, state, report=lambda work: None):
        """``(state, info)``: the algorithm's ``finish`` of every run (``info`` stacked), run
        as its steps (``finish_start``, ``finish_advance`` until ``finish_done``,
        ``finish_end``; the same steps ``make_train`` runs in one ``while_loop``), with
        ``report(work)`` after each step (programs of ``compile_finish``). Runs that are done
        stay as they are while the others advance."""
        alg = self.algorithm
        args, start, advance, done = self.compile_finish(state)
        if advance is None:  # nothing to do
            return state, None
        if self._finish_per_run:
            work = self._finish_each_run(state, start, advance, done, report)
        else:
            work = start(state, *args)
            while not np.all(np.asarray(done(work))):
                work = advance(work, *args)
                report(work)
        return self.compiled("the finished state", alg.finish_end, (state, work))(state, work)

    @property
    def _finish_per_run(self) -> bool:
        """A group's finish runs one run after another (the algorithm's ``finish_per_run``)."""
        return self.batched and bool(getattr(self.algorithm, "finish_per_run", False))

    def _run_slice(self, tree, r: int):
        """Run ``r``'s leaves of a group's ``tree``, on the first local device."""
        first = jax.sharding.SingleDeviceSharding(jax.local_devices()[0])
        return jax.device_put(jax.tree.map(lambda x: x[r], tree), first)

    def _finish_each_run(self, state, start, advance, done, report):
        """The finish's work of every run, one run after another, stacked over the group's
        lanes (a padded lane repeats the last run's, as its state does)."""
        works = []
        for r in range(len(self.runs)):
            one_state, hyper, env = self._run_slice((state, *self.data[1:]), r)
            work = start(one_state, hyper, env)
            while not bool(np.asarray(done(work))):
                work = advance(work, hyper, env)
                report(work)
            works.append(work)
        works += [works[-1]] * (self.lanes - len(works))
        return jax.device_put(jax.tree.map(lambda *w: jnp.stack(w), *works), self.sharding)

    def best_policies(self, state) -> list:
        """Every run's best policy, on the host."""
        if not self.batched:
            return [jax.device_get(self.algorithm.best_policy(state))]
        best = jax.device_get(jax.vmap(self.algorithm.best_policy)(state))
        return [take(best, r) for r in range(len(self.runs))]

    def final_value(self, r: int, policy) -> dict:
        """Run ``r``'s honest value (``final_value``), compiled once per env params."""
        params = self.run_params[r]
        found = [fn for env, fn in self._evaluations if same_tree(env, params.env)]
        if not found:
            config = self.runs[r].config
            found = [final_value(self.algorithm, config, params, self.lanes)]
            self._evaluations.append((params.env, found[0]))
        return found[0](self.seed_keys[r], policy)
