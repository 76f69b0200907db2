"""The honest value of a run: its best policy's mean return over ``evaluation.rollouts`` fresh
rollouts from the seed's evaluation key (``api.final_returns``), compiled with the run's params
as constants (``final_value``), summed in float64 on the host (``final_value_of``): results.json's
``final_value``, what ``cognet-jax evaluate DIR`` reproduces."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from cognet_jax.algorithms.engine import SearchParams
from cognet_jax.api import final_returns
from cognet_jax.compiled import baked_constants, compiled_program, hoist_large, program_identity
from cognet_jax.config import Config
from cognet_jax.errors import InputError


def final_value(algorithm, config: Config, params: SearchParams, lanes: int = 1):
    """``evaluate(seed_key, policy) -> {"mean", "stderr", "rollouts"}``: the one honest
    evaluation (``api.final_returns`` with ``config.evaluation``), ``params`` constants of
    the compiled program (``compiled_program``: checked against ``run.memory_gb`` when first
    traced, kept by ``traced.compile_kept``), the mean and standard error summed in float64 on
    the host. ``lanes``: the searches ``algorithm`` was built to run side by side."""
    held, rebuild = hoist_large(params)
    run = final_returns(algorithm, config.evaluation)
    returns = lambda k, p, h: run(k, p, rebuild(h))  # noqa: E731
    constants = baked_constants(params)
    identity = program_identity(config, lanes=lanes)
    compiled: dict = {}  # by the policy's shapes and types

    def evaluate(key, policy):
        _refuse_nan_policy(policy)
        args = (key, jax.tree.map(jnp.asarray, policy), held)
        shapes = str(jax.tree.map(lambda x: (x.shape, x.dtype), args[1]))
        if shapes not in compiled:
            compiled[shapes] = compiled_program(
                config, "the honest evaluation", returns, args, constants, identity
            )
        return final_value_of(compiled[shapes](*args))

    return evaluate


def _refuse_nan_policy(policy) -> None:
    """An ``InputError`` for a policy with a NaN parameter: a search that diverged (node
    networks trained with a learning rate far too large) or a damaged file; its rollouts
    still give finite returns (a NaN distribution samples some action), so its value would
    be a number that means nothing."""
    for leaf in jax.tree.leaves(policy):
        x = np.asarray(leaf) if not isinstance(leaf, jax.Array) else leaf
        if jnp.issubdtype(x.dtype, jnp.floating) and bool(jnp.isnan(x).any()):
            raise InputError(
                "the policy holds NaN parameters: it has no honest value (the search "
                "diverged -- node networks trained with too large a network.learning_rate -- "
                "or its checkpoint or policy file was damaged or edited)"
            )


def final_value_of(returns) -> dict:
    """The honest value (results.json's ``final_value``: ``{"mean", "stderr", "rollouts"}``)
    of a 1-D array of returns (in float64); an ``InputError`` when a return is NaN or not
    finite (float32 overflowed: rewards too large for the horizon)."""
    returns = np.asarray(returns, dtype=np.float64)
    if np.isnan(returns).any():
        raise InputError(
            "the returns are NaN: the simulator's rewards or observations are NaN on some "
            "states (or an infinite reward met its negative), a discrete observation was "
            "outside 0 .. num_obs - 1, or the policy chose an action its agent lacks or a "
            "node its controller lacks"
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
