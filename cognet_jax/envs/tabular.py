"""Pure-JAX simulator of a tabular Dec-POMDP (a parsed ``.dpomdp`` file, SPEC section 7.3).

The static :class:`TabularEnv` holds only shapes and the horizon (it is hashable and can be
closed over by jitted code); the model arrays live in the :class:`TabularParams` pytree, so
one compiled rollout serves every model of the same shape. One step (SPEC section 1):

1. ``ja = sum_i a_i prod_{j>i} |A_j|`` (last agent fastest; an action beyond an agent's count
   is clipped to its last action);
2. reward ``R[s, ja]`` on the pre-step state;
3. ``s' ~ T[s, ja, :]``;
4. ``jo ~ O[ja, s', :]``, split into per-agent observations (last agent fastest).

The state is the int32 state index; observations are ``[agents]`` int32.

Randomness follows ``envs.base``: ``reset(u, params)`` takes ``u [reset_noise=1]`` and
``step(u, state, actions, params)`` takes ``u [step_noise=2]`` uniform(0, 1) numbers, used by
inverse-CDF draws (first for ``s'``, then for ``jo``). For convenience both also accept a JAX
PRNG key in place of ``u`` (the uniforms are then drawn from it).
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from cognet_jax.config import (
    FLOAT32_MAX,
    ConfigError,
    ProblemSection,
    require,
    require_discount,
    require_positive,
)
from cognet_jax.envs.base import (
    UNROLLED_CATEGORIES,
    categorical_from_columns,
    categorical_from_uniform,
)
from cognet_jax.io.dpomdp import TabularModel, parse_dpomdp
from cognet_jax.registry import register_env

__all__ = ["TabularEnv", "TabularParams", "load_problem", "make_tabular"]


@struct.dataclass
class TabularParams:
    """Model arrays (float32): ``transition [S, JA, S']``, ``observation [JA, S', JO]``,
    ``reward [S, JA]``, ``initial_belief [S]``, and the ``discount`` (a scalar).

    For a sparse transition model (every row has at most half of S' non-zeros) also the rows
    as lists: ``successors [S, JA, K]`` int32 (the non-zero columns in increasing order, padded
    with the last one) and ``successor_probs [S, JA, K]`` (0 in the padding); the exact
    evaluator then costs ``S * K`` instead of ``S * S'`` per joint node and step. ``None`` for a
    dense model. A sparse model keeps the rows only (``transition`` is ``None``): rollouts, the
    exact evaluator and the best responses all read the rows.

    Likewise ``obs_outcomes [JA, S', Ko]`` and ``obs_outcome_probs`` list the non-zero entries
    of every observation row when they are sparse (``None`` otherwise); rollouts draw from them
    (the same draws as from the full rows: box pushing, Mars rovers and the grids observe
    deterministically, one entry of 25 to 81), the exact evaluator reads ``observation``."""

    transition: jax.Array | None
    observation: jax.Array
    reward: jax.Array
    initial_belief: jax.Array
    discount: jax.Array | float = 1.0
    successors: jax.Array | None = None
    successor_probs: jax.Array | None = None
    obs_outcomes: jax.Array | None = None
    obs_outcome_probs: jax.Array | None = None


def _strides(counts: tuple[int, ...]) -> tuple[int, ...]:
    """Mixed-radix strides with the last agent fastest."""
    out, acc = [], 1
    for c in reversed(counts):
        out.append(acc)
        acc *= c
    return tuple(reversed(out))


@dataclasses.dataclass(frozen=True)
class TabularEnv:
    """Static description of a tabular Dec-POMDP (see module docstring)."""

    num_agents: int
    num_states: int
    action_counts: tuple[int, ...]
    obs_counts: tuple[int, ...]
    horizon: int
    obs_shape: tuple[int, ...] = ()
    obs_range: tuple[float, float] | None = None

    #: actions and observations per agent (the most of any agent), and joint ones
    num_actions = property(lambda self: max(self.action_counts))
    num_obs = property(lambda self: max(self.obs_counts))
    num_joint_actions = property(lambda self: math.prod(self.action_counts))
    num_joint_obs = property(lambda self: math.prod(self.obs_counts))

    def default_params(self) -> TabularParams:
        raise NotImplementedError(
            "a TabularEnv has no default model: build env and params with make_tabular(model, "
            "horizon)"
        )

    def joint_action(self, actions: jax.Array) -> jax.Array:
        """Joint action index of ``actions [agents]`` (clipped to each agent's range)."""
        counts = jnp.asarray(self.action_counts, jnp.int32)
        a = jnp.clip(actions.astype(jnp.int32), 0, counts - 1)
        return jnp.sum(a * jnp.asarray(_strides(self.action_counts), jnp.int32))

    def split_joint_obs(self, jo: jax.Array) -> jax.Array:
        """Per-agent observations ``[agents]`` int32 of joint observation ``jo``."""
        strides = jnp.asarray(_strides(self.obs_counts), jnp.int32)
        counts = jnp.asarray(self.obs_counts, jnp.int32)
        return (jo // strides) % counts

    @property
    def reset_noise(self) -> int:
        return 1

    @property
    def step_noise(self) -> int:
        return 2

    def reset(self, u: jax.Array, params: TabularParams) -> jax.Array:
        """``s_0 ~ b0`` (int32) from ``u [1]`` uniform numbers (or a PRNG key)."""
        u = _uniforms(u, self.reset_noise)
        return categorical_from_uniform(u[0], params.initial_belief)

    def step(
        self, u: jax.Array, state: jax.Array, actions: jax.Array, params: TabularParams
    ) -> tuple[jax.Array, jax.Array, jax.Array]:
        """One step from ``u [2]`` uniform numbers (or a PRNG key); returns
        ``(next_state int32, obs [agents] int32, reward float32)``."""
        u = _uniforms(u, self.step_noise)
        ja = self.joint_action(actions)
        reward = params.reward[state, ja].astype(jnp.float32)
        # sparse rows: an inverse-CDF draw over the K listed entries instead of the whole row
        # (a few listed entries of rows hundreds wide)
        next_state = _draw(
            u[0], params.successors, params.successor_probs, params.transition, (state, ja)
        )
        jo = _draw(
            u[1],
            params.obs_outcomes,
            params.obs_outcome_probs,
            params.observation,
            (ja, next_state),
        )
        return next_state, self.split_joint_obs(jo), reward


#: rows of up to this many listed entries are drawn with written-out running sums
#: (``categorical_from_columns``), wider ones with ``categorical_from_uniform``. **[choice]**
#: The cumsum is a slow reduce-window kernel on CPU (benchmarks/NOTES.md); 32 covers the
#: meeting grid's 25 successors per row, and every other model of experiments/ and ../shared
#: lists at most 16, so its draws are unchanged.
LISTED_UNROLLED = 32


def _draw(u, listed, listed_probs, full, row) -> jax.Array:
    """The column drawn with uniform ``u`` from the row ``row`` (an index tuple) of a table:
    from its listed non-zero entries when the table keeps them (``listed`` not ``None``), else
    from the full row (the same draw either way, up to the last bit of the running sums)."""
    if listed is None:
        return categorical_from_uniform(u, full[row])
    probs = listed_probs[row]
    k = probs.shape[-1]
    if UNROLLED_CATEGORIES < k <= LISTED_UNROLLED:
        return listed[row][categorical_from_columns(u, [probs[..., i] for i in range(k)])]
    return listed[row][categorical_from_uniform(u, probs)]


def _uniforms(u: jax.Array, n: int) -> jax.Array:
    """``u`` itself, or ``n`` uniforms drawn from it when it is a PRNG key."""
    u = jnp.asarray(u)
    is_key = jax.dtypes.issubdtype(u.dtype, jax.dtypes.prng_key) or u.dtype == jnp.uint32
    return jax.random.uniform(u, (n,)) if is_key else u


def make_tabular(
    model: TabularModel, horizon: int, discount: float | None = None
) -> tuple[TabularEnv, TabularParams]:
    """Env and params of a parsed model; ``discount`` overrides the model's."""
    if int(horizon) < 1:
        raise ValueError(f"horizon must be a positive integer, got {horizon!r}")
    env = TabularEnv(
        num_agents=model.num_agents,
        num_states=model.num_states,
        action_counts=tuple(model.action_counts),
        obs_counts=tuple(model.obs_counts),
        horizon=int(horizon),
    )
    gamma = model.discount if discount is None else float(discount)
    successors, successor_probs = sparse_rows(model.transition)
    obs_outcomes, obs_outcome_probs = sparse_rows(model.observation)
    params = TabularParams(
        transition=jnp.asarray(model.transition, jnp.float32) if successors is None else None,
        observation=jnp.asarray(model.observation, jnp.float32),
        reward=jnp.asarray(model.reward, jnp.float32),
        initial_belief=jnp.asarray(model.initial_belief, jnp.float32),
        discount=jnp.asarray(gamma, jnp.float32),
        successors=successors,
        successor_probs=successor_probs,
        obs_outcomes=obs_outcomes,
        obs_outcome_probs=obs_outcome_probs,
    )
    return env, params


def sparse_rows(transition: np.ndarray):
    """``(successors [S, JA, K] int32, probs [S, JA, K] float32)`` of the non-zero entries of
    every row of ``transition [S, JA, S']`` (or of any table of rows, e.g. the observations
    ``[JA, S', JO]``) (K = the most non-zeros of any row), or
    ``(None, None)`` when K > S' / 2 (dense enough that the full rows are as cheap). One joint
    action at a time, so the temporaries stay ``[S, S']`` (a 2025-state model's whole table
    would take 0.5 GB of sort indices)."""
    counts = np.stack(
        [np.count_nonzero(transition[:, ja] > 0, axis=-1) for ja in range(transition.shape[1])], 1
    )
    k = max(int(counts.max()), 1)
    if 2 * k > transition.shape[-1]:
        return None, None
    successors = np.empty(transition.shape[:2] + (k,), np.int32)
    probs = np.empty(transition.shape[:2] + (k,), np.float32)
    pad = np.arange(k) >= counts[..., None]  # [S, JA, K]
    for ja in range(transition.shape[1]):
        rows = transition[:, ja]  # [S, S']
        # column indices of the non-zeros first (stable: increasing s'), then the zeros
        order = np.argsort(~(rows > 0), axis=-1, kind="stable")[:, :k]
        p = np.take_along_axis(rows, order, -1)
        # padding entries (probability 0) point at the row's last non-zero column
        last = np.take_along_axis(order, np.maximum(counts[:, ja, None] - 1, 0), -1)
        successors[:, ja] = np.where(pad[:, ja], last, order)
        probs[:, ja] = np.where(pad[:, ja], 0.0, p)
    return jnp.asarray(successors), jnp.asarray(probs)


# ---------------------------------------------------------------------------------------------
# configuration: the [env] section and the registration (cognet_jax.registry)
# ---------------------------------------------------------------------------------------------
@dataclasses.dataclass
class DpomdpSection:
    """``[env]`` of a tabular problem read from the MADP file named in ``[problem]`` (``path``,
    ``horizon``, ``discount``)."""

    name: str = "dpomdp"

    def check(self, config) -> None:
        problem = config.problem
        require(
            bool(problem.path),
            "problem.path",
            "is required for a .dpomdp problem: --set problem.path=FILE.dpomdp",
        )
        require_positive(problem, "problem", "horizon")
        require_discount(problem.discount, "problem.discount")


#: the last parsed model, keyed by (resolved path, mtime, size, discount): a run builds the
#: env, the exact evaluation and the plots' names from one parse
_PARSED: dict = {}
#: files larger than this get a "parsing ..." line on stderr
PARSE_PROGRESS_BYTES = 1_000_000


def load_problem(problem: ProblemSection) -> TabularModel:
    """The parsed model of ``problem.path`` (``ConfigError`` if unreadable); parsed once per
    file version and discount, then reused."""
    path = Path(problem.path).expanduser()
    if not path.exists():
        raise ConfigError("problem.path", f"no such file: {problem.path}")
    if not path.is_file():
        raise ConfigError("problem.path", f"{problem.path}: not a regular file (a .dpomdp model)")
    st = path.stat()
    key = (str(path.resolve()), st.st_mtime_ns, st.st_size, problem.discount)
    if key not in _PARSED:
        _PARSED.clear()
        large = st.st_size > PARSE_PROGRESS_BYTES
        if large:
            print(f"parsing {path} ({st.st_size / 1e6:.1f} MB) ...", file=sys.stderr, flush=True)
        t0 = time.perf_counter()
        _PARSED[key] = parse_dpomdp(str(path), discount=problem.discount)
        if large:
            print(f"parsed {path} in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    return _PARSED[key]


def build_from_section(section: DpomdpSection, config) -> tuple[TabularEnv, TabularParams]:
    """The parsed model of ``problem.path`` (parsed once per file version, ``load_problem``);
    ``ConfigError`` when its rewards over the horizon overflow float32."""
    problem = config.problem
    model = load_problem(problem)
    top = float(np.abs(model.reward).max()) if model.reward.size else 0.0
    if top * problem.horizon > FLOAT32_MAX:
        raise ConfigError(
            "problem.path",
            f"{problem.path}: rewards up to {top:.3g} over horizon {problem.horizon} overflow "
            f"float32 (|return| <= {FLOAT32_MAX:.3g})",
        )
    if problem.discount is None and not model.discount > 0.0:
        # the format allows 0 (only the first reward counts); every return here is a
        # discounted sum, which the simulators' discount check refuses at 0
        raise ConfigError(
            "problem.path",
            f"{problem.path}: its discount line gives {model.discount:g}; cognet-jax needs a "
            "discount in (0, 1]: set problem.discount to override the file's",
        )
    return make_tabular(model, problem.horizon, problem.discount)


register_env("dpomdp", DpomdpSection, build_from_section, reads=("problem",), overwrite=False)
