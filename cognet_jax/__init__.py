"""cognet_jax: JAX-vectorised graph-based cross-entropy policy search for Dec-POMDPs
(G-DICE, COG-DICE, COGNet-DICE).

The public names below are imported on first use (PEP 562), so ``import cognet_jax.io.dpomdp``
(the MADP parser, numpy only) does not load JAX.
"""

from __future__ import annotations

import importlib

_PUBLIC = {
    "Config": "cognet_jax.config",
    "ConfigError": "cognet_jax.config",
    "load_config": "cognet_jax.registry",
    "config_from_dict": "cognet_jax.registry",
    "make_env": "cognet_jax.api",
    "list_envs": "cognet_jax.registry",
    "register_env": "cognet_jax.registry",
    "make_algorithm": "cognet_jax.api",
    "list_algorithms": "cognet_jax.registry",
    "register_algorithm": "cognet_jax.registry",
    "SearchParams": "cognet_jax.api",
    "build": "cognet_jax.api",
    "Built": "cognet_jax.api",
    "build_algorithm": "cognet_jax.api",
    "build_env": "cognet_jax.api",
    "make_step": "cognet_jax.api",
    "make_train": "cognet_jax.api",
    "make_evaluate": "cognet_jax.api",
    "seed_key": "cognet_jax.api",
    "streams": "cognet_jax.algorithms.engine",
    "controller_step": "cognet_jax.controllers.step",
    "register_policy_type": "cognet_jax.controllers.step",
    "portable_policy": "cognet_jax.controllers.encoded",
    "EncodedPolicy": "cognet_jax.controllers.encoded",
    "train": "cognet_jax.driver",
    "evaluate_run": "cognet_jax.saved_runs",
    "run_sweep": "cognet_jax.sweep",
}
__all__ = sorted(_PUBLIC)
__version__ = "0.1.0"


def __getattr__(name: str):
    if name in _PUBLIC:
        value = getattr(importlib.import_module(_PUBLIC[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'cognet_jax' has no attribute {name!r}")


def __dir__():
    return sorted([*globals(), *_PUBLIC])
