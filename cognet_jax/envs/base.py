"""The simulator interface every Dec-POMDP environment implements.

Conventions (gymnax style, randomness first):

* ``env.reset(u, params) -> state`` draws ``s_0 ~ b0`` from ``u [reset_noise]`` uniform(0, 1)
  numbers. There is no observation before the first action (SPEC section 1).
* ``env.step(u, state, actions, params) -> (next_state, obs, reward)``, ``u [step_noise]``
  uniform(0, 1) numbers, ``actions`` of shape
  ``[agents]`` (int32). ``reward`` is the joint reward ``R(s_t, a_t)`` on the *pre-step* state,
  ``obs`` is ``z_{t+1}`` computed on ``s_{t+1}``: ``[agents, *obs_shape]`` float32 for continuous
  observations, ``[agents]`` int32 for discrete ones.

An environment object is a frozen (hashable) dataclass holding only *static* facts -- shapes,
horizon, number of agents -- so that it can be closed over by jitted code. Every tunable number
(noise levels, rewards, discount) lives in the ``params`` pytree, so sweeping over it needs no
recompilation.

Why uniforms instead of keys: the rollout engine draws the random numbers of every rollout of a
time step in *one* block call (``[rollouts, noise]``), which is much faster on CPU than one
threefry call per rollout, and compiles faster. Normal draws are made from uniforms by the
inverse CDF (``normal_from_uniform``).
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from typing import Any, Protocol

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import ndtri

from cognet_jax.errors import SimulatorError, SimulatorWarning, UsageError, callback_failure

EnvState = Any
EnvParams = Any


class Environment(Protocol):
    """Static description plus pure step functions of a Dec-POMDP simulator."""

    #: Number of agents n.
    num_agents: int
    #: Actions per agent (the maximum over agents when they differ; see ``action_counts``).
    num_actions: int
    #: Per-agent action counts; controllers mask actions ``>= action_counts[i]``.
    action_counts: tuple[int, ...]
    #: Shape of one agent's observation: ``()`` for a scalar, ``(16,)`` for a 4x4 patch.
    obs_shape: tuple[int, ...]
    #: Number of discrete observations per agent (maximum over agents), or ``None`` if continuous.
    num_obs: int | None
    #: Episode length h (static: it is the scan length).
    horizon: int
    #: Range ``(low, high)`` of a scalar continuous observation (for regions and plots).
    obs_range: tuple[float, float] | None

    #: Uniform numbers consumed by one ``reset`` / one ``step``.
    reset_noise: int
    step_noise: int

    def default_params(self) -> EnvParams: ...

    def reset(self, u: jax.Array, params: EnvParams) -> EnvState: ...

    def step(
        self, u: jax.Array, state: EnvState, actions: jax.Array, params: EnvParams
    ) -> tuple[EnvState, jax.Array, jax.Array]: ...


@jax.jit
def normal_from_uniform(u: jax.Array) -> jax.Array:
    """Standard normal draws from uniform(0, 1) numbers (inverse CDF, clipped away from 0/1).

    Jitted so the inverse CDF, a few hundred operations, is traced once per shape and its trace
    reused by every step and program of the process; XLA inlines it, so the numbers are those
    of the plain call (tracing times in benchmarks/NOTES.md)."""
    eps = 1e-7
    return ndtri(jnp.clip(u, eps, 1.0 - eps))


#: Up to this many categories the inverse CDF is written out as K running sums and K
#: comparisons, which XLA fuses into one loop; ``jnp.cumsum`` becomes a reduce-window kernel on
#: CPU and costs more than the whole draw (benchmarks/NOTES.md).
UNROLLED_CATEGORIES = 16


def sum_last(x: jax.Array) -> jax.Array:
    """Sum over the last axis; for up to ``UNROLLED_CATEGORIES`` entries (agents) as a chain of
    adds in index order, which XLA fuses with its neighbours, where a ``reduce`` over an axis of
    2-16 becomes a library kernel of its own on CPU (benchmarks/NOTES.md)."""
    k = x.shape[-1]
    if k > UNROLLED_CATEGORIES:
        return jnp.sum(x, axis=-1)
    total = x[..., 0]
    for i in range(1, k):
        total = total + x[..., i]
    return total


def scaled_normal(scale: jax.Array | float, u: jax.Array) -> jax.Array:
    """``scale * normal_from_uniform(u)``, skipping the inverse CDF when ``scale`` is zero.

    Noise-free settings (the tagging thesis setting, a heatmap without sensor noise) then pay
    nothing for their zero noise: the inverse CDF is a few hundred operations per draw and was the
    largest part of a tagging step. A constant zero ``scale`` (a program's params baked in, as
    ``cognet-jax train`` compiles them) gives zeros without tracing the inverse CDF at all, a
    smaller program that compiles faster (benchmarks/NOTES.md, "Measurements behind code choices").
    Otherwise ``lax.cond`` on the scalar ``scale``: with an unbatched ``scale`` only one branch
    runs; under ``vmap`` over a batched ``scale`` both run and the result is selected. The value is
    the same every way (``0 * x = 0`` for the finite ``x`` this returns)."""
    dtype = jnp.result_type(jnp.float32, u.dtype)  # float32, or float64 uniforms under x64
    if not isinstance(scale, jax.core.Tracer) and not np.any(scale):  # a constant zero
        return jnp.zeros(u.shape, dtype)
    scale = jnp.asarray(scale, jnp.float32)
    return jax.lax.cond(
        scale == 0.0,
        lambda: jnp.zeros(u.shape, dtype),
        lambda: (scale * normal_from_uniform(u)).astype(dtype),
    )


@jax.jit
def categorical_from_uniform(u: jax.Array, probs: jax.Array) -> jax.Array:
    """Index drawn from ``probs [..., K]`` with uniform ``u [...]`` (inverse CDF): the number of
    running sums ``p_0 + ... + p_k`` that are ``<= u * sum(p)``, at most ``K - 1``.

    Jitted like ``normal_from_uniform``: traced once per shape, inlined by XLA into the
    programs that call it (the same numbers), and one small program instead of ``3K + 2``
    single operations where it runs eagerly (sampling a controller outside a program)."""
    k = probs.shape[-1]
    if k > UNROLLED_CATEGORIES:
        cdf = jnp.cumsum(probs, axis=-1)
        idx = jnp.sum(cdf <= u[..., None] * cdf[..., -1:], axis=-1)
        return jnp.minimum(idx, k - 1).astype(jnp.int32)
    return categorical_from_columns(u, [probs[..., i] for i in range(k)])


def categorical_from_columns(u: jax.Array, columns: list[jax.Array]) -> jax.Array:
    """``categorical_from_uniform`` with the K probabilities given as K arrays of ``u``'s shape
    (K written-out running sums and comparisons): the same operations on every element."""
    running = [columns[0]]
    for column in columns[1:]:
        running.append(running[-1] + column)
    threshold = u * running[-1]
    idx = sum((c <= threshold).astype(jnp.int32) for c in running)
    return jnp.minimum(idx, len(columns) - 1).astype(jnp.int32)


#: the five moves of the grid and plane simulators: stay, x+1, x-1, y+1, y-1 (``[5, 2]``)
MOVES5 = np.array([[0, 0], [1, 0], [-1, 0], [0, 1], [0, -1]], dtype=np.float32)
MOVE5_NAMES = ("stay", "x+1", "x-1", "y+1", "y-1")


class ContinuousObservations:
    """Mixin of simulators with continuous observations and the same actions for every agent
    (``num_agents`` and ``num_actions`` given by the class)."""

    num_obs = None

    @property
    def action_counts(self) -> tuple[int, ...]:
        return (self.num_actions,) * self.num_agents


def build_from_fields(env_cls, params_cls, section):
    """``(env, params)`` from an ``[env]`` section whose fields are named as the fields of the
    static ``env_cls`` (shapes: horizon, agents) or of the ``params_cls`` pytree (every tunable
    number); ``name`` and the fields of neither are left out."""
    values = dataclasses.asdict(section)
    static = {f.name for f in dataclasses.fields(env_cls)}
    dynamic = {f.name for f in dataclasses.fields(params_cls)}
    env = env_cls(**{k: v for k, v in values.items() if k in static})
    params = params_cls(**{k: v for k, v in values.items() if k in dynamic})
    return env, params


def dynamic_fields(params_cls) -> tuple[str, ...]:
    """The ``[env]`` fields that only change the params pytree (``register_env``'s
    ``dynamic``): every field of ``params_cls``."""
    return tuple(f.name for f in dataclasses.fields(params_cls))


def check_simulator(env, env_params, name: str, values: bool = True) -> None:
    """Trace ``env.reset`` and ``env.step`` once on abstract values (``jax.eval_shape``: no
    computation) and refuse, with a ``SimulatorError`` naming the simulator, its code and what
    was expected against what it returned: a function that raises, an observation of another
    shape or dtype than ``[agents, *obs_shape]`` (int32 ``[agents]`` for discrete ones), a
    reward that is not one number, a state whose arrays change shape or dtype in a step; with
    ``values``, also NaN or infinite observations and rewards (``_check_values``, computed: a
    second or two of tracing and dispatch, spent on simulators outside the package only)."""
    key = (id(env), id(env_params), values)
    if key in _CHECKED:  # the same objects, checked already (a config's load, then its build)
        return
    owner = f"simulator {name!r} ({type(env).__module__}.{type(env).__name__})"
    _check_sizes(env, owner)
    _check_discount(env_params, owner)
    u_reset = jax.ShapeDtypeStruct((env.reset_noise,), jnp.float32)
    u_step = jax.ShapeDtypeStruct((env.step_noise,), jnp.float32)
    actions = jax.ShapeDtypeStruct((env.num_agents,), jnp.int32)

    def traced(what, fn, *args):
        """``(program, output shapes)`` of ``fn`` traced once on abstract values; a value
        JAX casts unsafely (a float written into an integer state) is the simulator's error,
        a 64-bit dtype JAX truncates (x64 off) one warning line of the simulator's."""
        try:
            with warnings.catch_warnings(record=True) as seen:
                warnings.simplefilter("always")
                warnings.filterwarnings("error", message=".*cannot safely cast")
                out = jax.make_jaxpr(fn, return_shape=True)(*args)
        except Exception as err:  # the simulator's own error
            text = " ".join(str(err).split())[:300]
            raise SimulatorError(f"{owner}: {what} raised {type(err).__name__}: {text}") from err
        truncated = [w for w in seen if TRUNCATED_DTYPE in str(w.message)]
        for w in seen:  # the others as they came
            if w not in truncated:
                warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        if truncated:
            dtype = str(truncated[0].message).split(TRUNCATED_DTYPE, 1)[1].split()[0]
            warnings.warn(
                SimulatorWarning(
                    f"{owner}: {what} asks for {dtype}, which JAX truncates to 32 bits "
                    "(jax_enable_x64 is off): the simulator runs in 32 bits"
                ),
                stacklevel=3,
            )
            # said once: the same truncation, met again as the search traces the step
            warnings.filterwarnings("ignore", message=f"{TRUNCATED_DTYPE}.*")
        return out

    _, state = traced("reset(u, params)", env.reset, u_reset, env_params)
    step_program, out = traced(
        "step(u, state, actions, params)", env.step, u_step, state, actions, env_params
    )
    if not (isinstance(out, tuple) and len(out) == 3):
        raise SimulatorError(f"{owner}: step must return (state, obs, reward)")
    next_state, obs, reward = out
    if jax.tree.structure(next_state) != jax.tree.structure(state):
        raise SimulatorError(
            f"{owner}: step changed the state's structure: reset gave "
            f"{jax.tree.structure(state)}, step returned {jax.tree.structure(next_state)}"
        )
    for what, x in (("observation", obs), ("reward", reward)):
        if not isinstance(x, jax.ShapeDtypeStruct):  # a list, tuple or dict of arrays
            raise SimulatorError(
                f"{owner}: step returned its {what} as a {type(x).__name__} "
                f"({_shapes(x)}), expected one array"
            )
    if any(
        (a.shape, a.dtype) != (b.shape, b.dtype)
        for a, b in zip(jax.tree.leaves(next_state), jax.tree.leaves(state))
    ):
        raise SimulatorError(
            f"{owner}: step changed the state: reset gave {_shapes(state)}, step returned "
            f"{_shapes(next_state)}"
        )
    discrete = env.num_obs is not None
    want = (env.num_agents,) if discrete else (env.num_agents, *env.obs_shape)
    kind = "integer" if discrete else "floating"
    dtype_ok = jnp.issubdtype(obs.dtype, jnp.integer if discrete else jnp.floating)
    if obs.shape != want or not dtype_ok:
        raise SimulatorError(
            f"{owner}: step returned an observation {obs.dtype}{list(obs.shape)}, expected "
            f"{kind} {list(want)} (agents x obs_shape {tuple(env.obs_shape)})"
        )
    if reward.shape != () or not jnp.issubdtype(reward.dtype, jnp.floating):
        raise SimulatorError(
            f"{owner}: step returned a reward {reward.dtype}{list(reward.shape)}, expected one "
            "float (the joint reward, a shape () array)"
        )
    callbacks = _host_callbacks(step_program.jaxpr)
    debug = [c for c in callbacks if c in _DEBUG_PRIMITIVES]
    if debug:  # output only: nothing a search needs, and it stalls compiling for minutes
        raise SimulatorError(
            f"{owner}: step calls jax.debug.print or jax.debug.callback ({', '.join(debug)}): "
            "every step of every rollout would call back into Python, millions of calls per "
            "iteration; remove it (call the step directly to debug it)"
        )
    if callbacks:
        warnings.warn(
            SimulatorWarning(
                f"{owner}: step calls back into Python ({', '.join(callbacks)}): every step "
                "of every rollout makes that call, millions per iteration, so the search "
                "will be slow"
            ),
            stacklevel=2,
        )
    if values:
        _check_values(env, env_params, owner)
    _CHECKED[key] = (env, env_params)  # held, so the ids stay theirs


def _check_discount(env_params, owner: str) -> None:
    """The params' ``discount`` (every return is summed with it) a number in (0, 1], as the
    built-in simulators' ``discount`` fields are: a NaN one makes every return NaN, which
    would be blamed on the rewards, and one above 1 grows the returns without bound."""
    discount = getattr(env_params, "discount", None)
    try:
        value = float(np.asarray(discount))
    except (TypeError, ValueError):
        raise SimulatorError(
            f"{owner}: its params' discount is {discount!r}, expected a number in (0, 1]"
        ) from None
    if not (math.isfinite(value) and 0.0 < value <= 1.0):
        raise SimulatorError(f"{owner}: its params' discount is {value}, expected one in (0, 1]")


@dataclasses.dataclass(frozen=True)
class GuardedSteps:
    """The honest evaluation's simulator: ``env`` whose step adds NaN to its reward when an
    observation is not finite or an action is outside its agent's ``action_counts`` (a search
    of one's own drew it; JAX would clamp it silently), and 0 otherwise. Such an episode's
    return is NaN, which the honest evaluation refuses (``honest_value.final_value_of``) as it
    refuses NaN rewards; every other return is the same to the bit (``x + 0.0 == x``)."""

    env: Any

    def __getattr__(self, name):
        if name == "env" or name.startswith("__"):  # (copy and pickle before ``env`` is set)
            raise AttributeError(name)
        return getattr(self.env, name)

    def reset(self, u, params):
        return self.env.reset(u, params)

    def step(self, u, state, actions, params):
        dtype = jnp.asarray(actions).dtype
        if not jnp.issubdtype(dtype, jnp.integer):  # seen while tracing
            raise UsageError(
                f"the controller's actions are {dtype}, expected integers "
                "(the act() of the search's controller: a simulator indexes with them)"
            )
        state, obs, reward = self.env.step(u, state, actions, params)
        # a Python or numpy number is a reward too (as the search's rollouts take it)
        reward = jnp.asarray(reward)
        counts = jnp.asarray(self.env.action_counts)
        bad = jnp.any((actions < 0) | (actions >= counts)) | ~jnp.all(jnp.isfinite(obs))
        bad = bad | jnp.any(outside_observations(self.env, obs))
        return state, obs, reward + jnp.where(bad, jnp.nan, 0.0).astype(reward.dtype)


def outside_observations(env, obs) -> jax.Array:
    """``[agents]`` bool: a discrete observation outside ``0 .. num_obs - 1`` (a controller's
    table has no row for it: JAX would clamp the index silently); all False for continuous
    observations."""
    if env.num_obs is None:
        return jnp.zeros(jnp.shape(obs)[:1], bool)
    obs = jnp.asarray(obs)
    return (obs < 0) | (obs >= env.num_obs)


#: how JAX's warning about a 64-bit dtype it truncates (x64 off) begins
TRUNCATED_DTYPE = "Explicitly requested dtype "
#: simulators ``check_simulator`` passed: ``(id(env), id(params), values) -> (env, params)``
_CHECKED: dict = {}
#: the longest horizon a simulator may declare: beyond it one rollout is already millions of
#: steps, and the search's first measurement (``noise_pilot``) alone would run for hours
MAX_HORIZON = 1_000_000


#: the static members every simulator declares (``Environment``)
REQUIRED_MEMBERS = (
    "num_agents",
    "num_actions",
    "action_counts",
    "obs_shape",
    "num_obs",
    "horizon",
    "obs_range",
    "reset_noise",
    "step_noise",
)


def _check_sizes(env, owner: str) -> None:
    """Refuse declared sizes no search can run with: a horizon that is not an integer in
    ``1 .. MAX_HORIZON``, action counts that are not one positive integer per agent, or a
    ``num_actions`` other than the largest of them (the policies' action tables are that wide:
    a larger count would never be drawn); a missing member of ``Environment``, and an
    ``obs_range`` that is not two finite numbers, low below high."""
    missing = [m for m in REQUIRED_MEMBERS if not hasattr(env, m)]
    missing += [m for m in ("reset", "step") if not callable(getattr(env, m, None))]
    if missing:
        raise SimulatorError(
            f"{owner}: missing {', '.join(missing)} (a simulator has the members of "
            "cognet_jax.envs.base.Environment)"
        )
    agents = env.num_agents
    if isinstance(agents, bool) or not isinstance(agents, (int, np.integer)) or agents < 1:
        raise SimulatorError(f"{owner}: num_agents must be an integer >= 1, got {agents!r}")
    num_obs = env.num_obs
    if num_obs is not None and (
        isinstance(num_obs, bool) or not isinstance(num_obs, (int, np.integer)) or num_obs < 1
    ):
        raise SimulatorError(
            f"{owner}: num_obs must be None (continuous observations) or the count of discrete "
            f"observations, an integer >= 1, got {num_obs!r}"
        )
    obs_range = env.obs_range
    if obs_range is not None:
        try:
            low, high = (float(v) for v in obs_range)
        except (TypeError, ValueError):
            low = high = math.nan
        if not (math.isfinite(low) and math.isfinite(high) and low < high):
            raise SimulatorError(
                f"{owner}: obs_range must be None or (low, high), two finite numbers with "
                f"low < high, got {obs_range!r}"
            )
    horizon = env.horizon
    if isinstance(horizon, bool) or not isinstance(horizon, (int, np.integer)):
        raise SimulatorError(f"{owner}: horizon must be an integer, got {horizon!r}")
    if not 1 <= horizon <= MAX_HORIZON:
        raise SimulatorError(f"{owner}: horizon must be in 1 .. {MAX_HORIZON}, got {horizon}")
    shape = tuple(env.obs_shape) if env.num_obs is None else ()
    if any(not isinstance(d, int | np.integer) or d < 1 for d in shape):
        raise SimulatorError(
            f"{owner}: obs_shape {shape} must be sizes of at least 1 (an observation of no "
            "features tells a controller nothing); () is one number"
        )
    for name in ("reset_noise", "step_noise"):  # uniforms per reset / step: a count
        value = getattr(env, name)
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
            raise SimulatorError(
                f"{owner}: {name} (uniforms it draws per call) must be an integer >= 0, got "
                f"{value!r}"
            )
    counts = tuple(env.action_counts)
    if len(counts) != env.num_agents or any(int(c) < 1 for c in counts):
        raise SimulatorError(
            f"{owner}: action_counts {counts} must give a positive count for each of the "
            f"{env.num_agents} agents"
        )
    if env.num_actions != max(counts):
        raise SimulatorError(
            f"{owner}: num_actions is {env.num_actions} but action_counts {counts} allow up to "
            f"{max(counts)}; num_actions must be the largest action count"
        )


#: primitives that call Python from inside a compiled program; the first two only for output
_DEBUG_PRIMITIVES = ("debug_callback", "debug_print")
_CALLBACK_PRIMITIVES = (*_DEBUG_PRIMITIVES, "io_callback", "pure_callback")


def _host_callbacks(jaxpr) -> list[str]:
    """Names of the host-callback primitives in the program ``jaxpr`` (nested ones included)."""
    found: set[str] = set()

    def walk(jaxpr):
        for eqn in jaxpr.eqns:
            if eqn.primitive.name in _CALLBACK_PRIMITIVES:
                found.add(eqn.primitive.name)
            for value in eqn.params.values():
                for inner in value if isinstance(value, (tuple, list)) else (value,):
                    inner = getattr(inner, "jaxpr", inner)
                    if hasattr(inner, "eqns"):
                        walk(inner)

    walk(jaxpr)
    return sorted(found)


#: episodes of random actions ``_check_values`` runs, and the longest it runs
CHECK_EPISODES = 512
CHECK_STEPS = 200


def _check_values(env, env_params, owner: str) -> None:
    """On fixed uniforms: one reset, then one step for each action ``a`` with every agent
    taking ``a``; then ``CHECK_EPISODES`` episodes of random actions over the first
    ``CHECK_STEPS`` steps of the horizon, keeping per step only whether the observations were
    finite (so a simulator whose observations are NaN once in ten thousand steps is still
    caught, at the cost of one small program). A NaN or infinite observation or reward is
    refused here, naming the step, rather than turned into a search over NaN."""
    rng = np.random.default_rng(0)
    u = jnp.asarray(rng.uniform(size=env.reset_noise + env.step_noise), jnp.float32)
    state = env.reset(u[: env.reset_noise], env_params)
    actions = jnp.arange(min(env.action_counts), dtype=jnp.int32)[:, None]
    actions = jnp.broadcast_to(actions, (actions.shape[0], env.num_agents))
    step = jax.vmap(lambda a: env.step(u[env.reset_noise :], state, a, env_params)[1:])
    steps = min(env.horizon, CHECK_STEPS)
    counts = jnp.asarray(env.action_counts)

    def episode(key):
        k_reset, k_steps = jax.random.split(key)

        def body(s, k):
            k_u, k_a = jax.random.split(k)
            u_step = jax.random.uniform(k_u, (env.step_noise,))
            acts = jnp.floor(jax.random.uniform(k_a, counts.shape) * counts).astype(jnp.int32)
            s, obs, reward = env.step(u_step, s, acts, env_params)
            outside = jnp.any(outside_observations(env, obs))
            obs = jnp.asarray(obs, jnp.float32)
            status = jnp.where(
                jnp.any(jnp.isnan(obs)), 1, jnp.where(jnp.all(jnp.isfinite(obs)), 0, 2)
            )
            status = jnp.where(outside, 3, status)
            return s, (status.astype(jnp.int8), reward)

        s0 = env.reset(jax.random.uniform(k_reset, (env.reset_noise,)), env_params)
        return jax.lax.scan(body, s0, jax.random.split(k_steps, steps))[1]

    try:  # under vmap, as every search runs it
        first = step(actions)
        keys = jax.random.split(jax.random.key(0), CHECK_EPISODES)
        status, rewards = jax.jit(jax.vmap(episode))(keys)
    except Exception as err:  # the simulator's own error
        failed = callback_failure(err)
        what = (
            f"ran a Python callback that raised at {failed}"
            if failed
            else f"raised {type(err).__name__}: {err}"
        )
        message = f"{owner}: step(u, state, actions, params) under jax.vmap {what}"
        raise SimulatorError(message) from err
    status = np.asarray(status)
    outside = np.asarray(outside_observations(env, first[0]))
    if outside.any() or (status == 3).any():
        seen = f" ({np.asarray(first[0])[outside][:4]} ...)" if outside.any() else ""
        raise SimulatorError(
            f"{owner}: step returned a discrete observation outside 0 .. {env.num_obs - 1} "
            f"(num_obs {env.num_obs}){seen}: a controller has no row for it"
        )
    for what, x in zip(("observation", "reward"), first):
        x = np.asarray(x)
        if jnp.issubdtype(x.dtype, jnp.floating) and not np.isfinite(x).all():
            kind = "a NaN" if np.isnan(x).any() else "an infinite"
            raise SimulatorError(
                f"{owner}: step returned {kind} {what} ({x[~np.isfinite(x)][:4]} ...)"
            )
    rewards = np.asarray(rewards, np.float32)  # [episodes, steps]
    for what, bad, nan in (
        ("observation", status != 0, status == 1),
        ("reward", ~np.isfinite(rewards), np.isnan(rewards)),
    ):
        if bad.any():
            kind = "a NaN" if nan.any() else "an infinite"
            at = int(np.argmax(bad.any(axis=0))) + 1
            raise SimulatorError(
                f"{owner}: step returned {kind} {what} at step {at} of an episode of random "
                f"actions ({int(bad.sum())} of {bad.size} steps of {CHECK_EPISODES} episodes)"
            )
    with np.errstate(all="ignore"):  # the sum a rollout accumulates, in its float32
        returns = rewards.sum(axis=1, dtype=np.float32)
    if not np.isfinite(returns).all():
        raise SimulatorError(
            f"{owner}: the rewards of an episode of random actions sum to an infinite return "
            f"in float32 (rewards up to {np.abs(rewards).max():.3g}): rescale the rewards"
        )


def _shapes(tree) -> str:
    return ", ".join(f"{x.dtype}{list(x.shape)}" for x in jax.tree.leaves(tree))
