"""The ``cognet-jax`` executable (pyproject's console script, and ``python -m cognet_jax``):
stop signals are heeded from its first instant (``signals.heed_while_starting``: the standard
library only), then the command line, whose imports load JAX for seconds (``cli.run``)."""

from __future__ import annotations

from cognet_jax.signals import heed_while_starting


def run() -> None:
    heed_while_starting()
    from cognet_jax.cli import run as run_command_line

    run_command_line()
