"""Memory planning: how many rollouts may be in flight at once, and refusing a program that
cannot fit before XLA compiles it.

A search holds ``candidates x rollouts`` rollouts in flight in one evaluation (every candidate's
rollouts advance through the same ``lax.scan`` step). ``rollout.evaluate_candidates`` evaluates
the candidates in chunks (``lax.map`` with ``batch_size``) when all of them at once would not fit
the budget; each candidate's value is the same as unchunked, because each candidate already
uses the same key (common random numbers) and its own rollouts are never split.

* :func:`budget_bytes` -- ``run.memory_gb`` in bytes (0: half of this machine's memory).
* :func:`rollout_bytes` -- bytes one in-flight rollout needs, as XLA counts them: a probe of
  ``4 x 256`` rollouts is compiled and its temporary buffer size read
  (``Compiled.memory_analysis``). The probe costs a compile, so it runs only when an
  upper bound says the batch could be too big: every array the evaluation of all candidates
  at once creates, summed (:func:`traced_bytes` of its trace, which
  ``rollout.evaluate_candidates`` then uses as it is), or without such a trace every array
  that the trace of one rollout creates, summed, times the rollouts in flight.
* :func:`candidate_chunk` -- how many candidates to evaluate at once, or ``ResourceError``
  when even one candidate's rollouts exceed the budget.
* :func:`check_traced` -- the largest array of a traced (not yet compiled) program against the
  budget; a program whose single array cannot fit is refused with its shape.

This module is a leaf of the rollout layer: the rollouts it measures come in as a function
``run(key, policy, num, env_params) -> returns [num]`` (``cognet_jax.rollout`` passes its own).

**[choice]** The budget is per search: a portfolio of ``r`` searches or a sweep of ``n`` runs
(both ``vmap``-ed) gives each lane ``budget / lanes``.
"""

from __future__ import annotations

import math
import os
import re
import sys
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from cognet_jax.errors import ResourceError

#: the sizes a refusal asks to lower (``compiled.compiled_program`` names the config's own)
SIZES = "nodes, samples, candidates, rollouts, horizon"
#: the share of physical memory a run may use when ``run.memory_gb`` is 0
DEFAULT_MEMORY_SHARE = 0.5
#: the share of the budget a chunk of candidates' rollouts may take: the rest of the program
#: (its candidates, returns, the search's own arrays) needs room beside it (at the whole budget
#: the paper setting's iteration took 3-12% more than it, and was refused after compiling)
CHUNK_SHARE = 0.75
#: rollouts per candidate and candidates of the probe that measures bytes per rollout
PROBE_ROLLOUTS, PROBE_CANDIDATES = 256, 4


def machine_memory_bytes() -> int:
    """Physical memory of this machine in bytes."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):  # pragma: no cover - not POSIX
        return 8 * 2**30


def budget_bytes(memory_gb: float = 0.0) -> int:
    """The memory budget in bytes: ``memory_gb`` GB, or with 0 ``DEFAULT_MEMORY_SHARE`` of the
    machine's physical memory."""
    if memory_gb > 0:
        return int(memory_gb * 1e9)
    return int(DEFAULT_MEMORY_SHARE * machine_memory_bytes())


def peak_rss_bytes() -> int | None:
    """The peak resident set size of this process so far (``ru_maxrss``; Linux reports KB,
    macOS bytes), or None where ``resource`` is missing. It covers the whole process: parsing,
    compiling, every run it made before."""
    try:
        import resource
    except ImportError:  # pragma: no cover - not POSIX
        return None
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return int(peak if sys.platform == "darwin" else peak * 1024)


def gb(num_bytes: float) -> str:
    """``num_bytes`` as ``"1.23 GB"``."""
    return f"{num_bytes / 1e9:.3g} GB"


def check_made_fits(make, args: tuple, memory: int | None, what: str) -> None:
    """``ResourceError`` when the arrays ``make(*args)`` returns are over ``memory`` bytes
    (``None``: ``budget_bytes()``), found by ``jax.eval_shape`` before anything is made: a
    policy or a batch of candidates built eagerly (outside a compiled program, which
    ``trace_checked`` checks) is refused instead of failing to allocate."""
    size = sum(_aval_bytes(x) for x in jax.tree.leaves(jax.eval_shape(make, *args)))
    limit = budget_bytes() if memory is None else memory
    if size > limit:
        raise ResourceError(
            f"{what} take {gb(size)}, over the memory budget of {gb(limit)}; lower the sizes "
            "in the config (algorithm.nodes, algorithm.candidates, network.hidden) or raise "
            "run.memory_gb"
        )


def _aval_bytes(aval) -> int:
    shape = getattr(aval, "shape", None)
    dtype = getattr(aval, "dtype", None)
    if shape is None or dtype is None:
        return 0
    try:
        itemsize = np.dtype(dtype).itemsize
    except TypeError:  # PRNG key arrays and other extended dtypes
        itemsize = 8
    return math.prod(shape) * itemsize


def _sub_jaxprs(params: dict):
    for p in params.values():
        for s in p if isinstance(p, (list, tuple)) else (p,):
            if hasattr(s, "eqns"):
                yield s
            elif hasattr(getattr(s, "jaxpr", None), "eqns"):
                yield s.jaxpr


def jaxpr_arrays(jaxpr):
    """Every array a jaxpr creates (``(aval, primitive name)``), sub-programs included."""
    for eqn in jaxpr.eqns:
        for v in eqn.outvars:
            yield v.aval, eqn.primitive.name
        for sub in _sub_jaxprs(eqn.params):
            yield from jaxpr_arrays(sub)


def _abstract(tree):
    return jax.tree.map(lambda x: jax.ShapeDtypeStruct(jnp.shape(x), jnp.result_type(x)), tree)


def _is_traced(tree) -> bool:
    return any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves(tree))


def _with_params(env_params):
    """``(args, read)``: concrete env params stay constants of a probe (as in the real program,
    where e.g. a zero noise level skips its draws); traced ones (a sweep) become arguments."""
    if _is_traced(env_params):
        return (_abstract(env_params),), lambda e: e[0]
    return (), lambda e: env_params


def traced_bytes(jaxpr) -> int:
    """Bytes of every array a jaxpr creates, summed, the arrays of a loop body once, not once
    per step (an upper bound on what it keeps alive at once: a ``lax.scan`` body's arrays
    live one step at a time)."""
    return sum(_aval_bytes(a) for a, _ in jaxpr_arrays(jaxpr))


def _step_upper_bound(run, env_params, policy) -> int:
    """Bytes of every array the trace of one rollout creates (its reset, its scan's step once,
    its last step), summed (an upper bound on what a rollout keeps alive; 10-100x what XLA
    needs after fusion)."""
    extra, read = _with_params(env_params)
    jaxpr = jax.make_jaxpr(lambda k, p, *e: run(k, p, 1, read(e)))(
        jax.random.key(0), _abstract(policy), *extra
    )
    return traced_bytes(jaxpr.jaxpr)


_PROBED: dict = {}


def rollout_bytes(run, env_params, policy, cache: tuple = ()) -> float:
    """Bytes one in-flight rollout of ``policy`` needs in a batch of candidates, measured from
    XLA's buffer assignment of a small probe (cached per ``cache`` -- what identifies ``run``
    -- and shapes)."""
    policy = _abstract(policy)
    extra, read = _with_params(env_params)
    cache_key = (*cache, id(env_params), str(jax.tree.structure(policy)))
    cache_key += tuple((x.shape, str(x.dtype)) for x in jax.tree.leaves((policy, extra)))
    if cache_key not in _PROBED:
        stacked = jax.tree.map(
            lambda x: jax.ShapeDtypeStruct((PROBE_CANDIDATES, *x.shape), x.dtype), policy
        )

        def probe(k, ps, *e):
            return jax.vmap(lambda p: run(k, p, PROBE_ROLLOUTS, read(e)).mean())(ps)

        compiled = jax.jit(probe).lower(jax.random.key(0), stacked, *extra).compile()
        temp = compiled.memory_analysis().temp_size_in_bytes
        _PROBED[cache_key] = temp / (PROBE_CANDIDATES * PROBE_ROLLOUTS)
    return _PROBED[cache_key]


def candidate_chunk(
    run,
    env_params,
    policy,
    candidates: int,
    rollouts: int,
    memory: int | None,
    what: str = "algorithm.eval_rollouts",
    cache: tuple = (),
    upper_bound: int | None = None,
) -> int:
    """How many of ``candidates`` candidates (``rollouts`` rollouts each, by ``run``) to evaluate at
    once within ``CHUNK_SHARE`` of ``memory`` bytes (None: :func:`budget_bytes`); ``candidates``
    when all fit. ``policy`` is one candidate (arrays or shapes). Raises ``ResourceError`` naming
    ``what`` when one candidate's rollouts alone exceed the budget.

    ``upper_bound``: bytes that all candidates at once surely fit in (the
    :func:`traced_bytes` of their traced evaluation); None: every array the trace of one
    rollout creates, summed, times ``candidates x rollouts``. Within the budget, all are
    evaluated at once; over it, the bytes per rollout are measured (:func:`rollout_bytes`)."""
    memory = budget_bytes() if memory is None else memory
    if upper_bound is None:
        upper_bound = candidates * rollouts * _step_upper_bound(run, env_params, policy)
    if upper_bound <= memory:
        return candidates
    per_rollout = rollout_bytes(run, env_params, policy, cache)
    per_candidate = rollouts * per_rollout
    if per_candidate > memory:
        raise ResourceError(
            f"{what}: {rollouts} rollouts in flight x {per_rollout:.0f} bytes each needs about "
            f"{gb(per_candidate)}, over the memory budget of {gb(memory)}; lower {what} or "
            "raise run.memory_gb"
        )
    return max(1, min(candidates, int(memory * CHUNK_SHARE // per_candidate)))


def largest_array(jaxpr) -> tuple[int, Any, str]:
    """``(bytes, aval, primitive)`` of the largest array a jaxpr creates."""
    best = (0, None, "")
    for aval, prim in jaxpr_arrays(jaxpr):
        b = _aval_bytes(aval)
        if b > best[0]:
            best = (b, aval, prim)
    return best


def check_traced(traced, memory: int | None, what: str = "one iteration") -> None:
    """Refuse a traced program (``jax.jit(f).trace(...)``) whose largest single array exceeds
    ``memory`` bytes, before XLA compiles it."""
    memory = budget_bytes() if memory is None else memory
    size, aval, _ = largest_array(traced.jaxpr.jaxpr)
    if size > memory:
        shape = "x".join(str(d) for d in aval.shape)
        raise ResourceError(
            f"{what} needs an array of {shape} {aval.dtype}, about {gb(size)}, over "
            f"the memory budget of {gb(memory)}; lower the sizes in the config ({SIZES}) or raise "
            "run.memory_gb"
        )


class MemoryOverBudget(ResourceError):
    """A compiled program's buffers exceed the budget: ``needed`` and ``budget`` in bytes;
    ``before_search``: the program is a group's initial state or iteration (a sweep then runs
    the group's runs in smaller batches, ``batches``)."""

    def __init__(self, message: str, needed: int, budget: int):
        super().__init__(message)
        self.needed, self.budget = needed, budget
        self.before_search = False


def program_devices(compiled) -> int:
    """How many devices a compiled program runs on (the devices of its arguments' and
    outputs' shardings; 1 when it names none)."""
    try:
        shardings = jax.tree.leaves((compiled.input_shardings, compiled.output_shardings))
        devices = {d for s in shardings for d in s.device_set}
    except Exception:  # an object without shardings (a test's stand-in): one device
        return 1
    return max(1, len(devices))


def check_compiled(compiled, memory: int | None, what: str = "one iteration") -> None:
    """Refuse a compiled program whose buffers at once (its arguments, outputs and XLA's
    temporaries, by XLA's memory analysis) exceed ``memory`` bytes. XLA on CPU allocates a
    program's temporaries as one block, which the largest-array check before compiling
    (``check_traced``) does not see: e.g. one iteration of thousands of runs side by side.
    XLA's analysis counts one device's buffers: a program laid over several devices (a
    sweep's runs, ``run.shard_rollouts``) holds that many times as much, all of it in this
    machine's memory on CPU."""
    memory = budget_bytes() if memory is None else memory
    try:
        stats = compiled.memory_analysis()
    except Exception:  # a backend without the analysis: the check before compiling stands
        return
    if stats is None:
        return
    devices = program_devices(compiled)
    temp = int(stats.temp_size_in_bytes) * devices
    total = temp + (int(stats.argument_size_in_bytes) + int(stats.output_size_in_bytes)) * devices
    total -= int(stats.alias_size_in_bytes) * devices
    if total > memory:
        raise MemoryOverBudget(
            f"{what} needs about {gb(total)} at once ({gb(temp)} of them XLA's temporaries), "
            f"over the memory budget of {gb(memory)}; lower the sizes in the config ({SIZES}), "
            "run fewer seeds side by side, or raise run.memory_gb",
            total,
            memory,
        )


def trace_checked(jitted, args: tuple, memory: int | None, what: str = "one iteration"):
    """``jitted.trace(*args)`` (``jitted`` from ``jax.jit``) checked by :func:`check_traced`;
    JAX's own refusal of too-large random draws, and a size past 32-bit integers, become a
    ``ResourceError`` too. Lower the result to compile it."""
    try:
        traced = jitted.trace(*args)
    except OverflowError as err:  # a count past int32, e.g. nodes x layers
        found = re.search(r"(?:value|integer) (-?\d+)", str(err))
        size = f"a size of {found.group(1)}" if found else "a size"
        raise ResourceError(
            f"{what}: {size} does not fit the 32-bit integers arrays are indexed with; lower "
            f"the sizes in the config ({SIZES})"
        ) from None
    except ResourceError as err:  # this library's own draws (``prng``)
        raise ResourceError(f"{what}: {err}") from None
    except ValueError as err:
        if "random draws" in str(err) or "too large" in str(err):
            raise ResourceError(f"{what}: {err}; lower the sizes in the config ({SIZES})") from None
        raise
    check_traced(traced, memory, what)
    return traced
