"""Pieces both vectorised torch references share (torch only, no cognet_jax import): the
inverse-CDF draw and ``torch.compile`` of a time step."""

from __future__ import annotations

import torch

#: compiled graphs a time step may keep: one per (batch size, nodes, first step or later: the
#: first step's evader is a strided view); torch's default of 8 is used up by the benchmark's
#: 3-node sizes, after which dynamo silently runs the rest eagerly
RECOMPILE_LIMIT = 64


def sample_categorical(u: torch.Tensor, probs: torch.Tensor) -> torch.Tensor:
    """Inverse-CDF draw: ``u [...]`` uniform, ``probs [..., K]`` (unnormalised) -> int64
    ``[...]``."""
    cdf = probs.cumsum(-1)
    idx = (cdf <= u[..., None] * cdf[..., -1:]).sum(-1)
    return idx.clamp_max(probs.shape[-1] - 1)


def compile_step(fn):
    """``torch.compile(fn)`` (inductor, static shapes) with dynamo's recompile limit raised to
    ``RECOMPILE_LIMIT``."""
    import torch._dynamo.config as dynamo_config

    for name in ("recompile_limit", "cache_size_limit"):
        if getattr(dynamo_config, name, 0) < RECOMPILE_LIMIT:
            setattr(dynamo_config, name, RECOMPILE_LIMIT)
    return torch.compile(fn, dynamic=False)
