"""cognet_jax: JAX-vectorised graph-based cross-entropy policy search for Dec-POMDPs
(G-DICE, COG-DICE, COGNet-DICE)."""

from cognet_jax.api import build_algorithm, build_env, make_step, make_train
from cognet_jax.config import Config, ConfigError, load_config
from cognet_jax.controllers.step import controller_step

__all__ = [
    "Config",
    "ConfigError",
    "build_algorithm",
    "build_env",
    "controller_step",
    "load_config",
    "make_step",
    "make_train",
]
__version__ = "0.1.0"
