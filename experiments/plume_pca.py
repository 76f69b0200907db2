"""A probe (2026-12-02): the plume with its 3 x 3 patch PCA-whitened inside the simulator, to
load with ``--import``. The whitening is computed from every (agent cell, source cell) pair of
the default grid plus the pixel noise; on that exactly symmetric covariance ``numpy.linalg.eigh``
returns the two gradient directions rotated 45 degrees from the grid's axes, so each
neighbour's "brightest" test is two sign tests on single features. The library's
``whiten_inputs`` (statistics of random-controller rollouts) whitens the same covariance in a
different basis and did not gain (experiments/NOTES.md, "Whitened inputs").

    cognet-jax --import experiments/plume_pca.py sweep experiments/plume-pca-n5.toml --seeds 8
"""

import dataclasses

import jax.numpy as jnp
import numpy as np

import cognet_jax
from cognet_jax.envs.plume import PATCH_OFFSETS, Plume, PlumeParams


def whitening(env: Plume, params: PlumeParams) -> tuple[np.ndarray, np.ndarray]:
    """``(mean [9], transform [9, 9])``: ``(patch - mean) @ transform`` has covariance the
    identity over every agent cell and source cell of ``env``'s grid, noise included."""
    n = env.size
    cells = np.stack(np.meshgrid(np.arange(n), np.arange(n), indexing="ij"), -1).reshape(-1, 2)
    agent, source = np.repeat(cells, len(cells), 0), np.tile(cells, (len(cells), 1))
    patch_cells = agent[:, None, :] + PATCH_OFFSETS
    inside = np.all((patch_cells >= 0) & (patch_cells < n), -1)
    d2 = ((patch_cells - source[:, None, :]) ** 2).sum(-1)
    patches = np.where(inside, np.exp(-d2 / (2 * params.spread**2)), 0.0)
    covariance = np.cov(patches.T) + params.obs_noise**2 * np.eye(9)
    values, vectors = np.linalg.eigh(covariance)
    return patches.mean(0).astype(np.float32), (vectors / np.sqrt(values)).astype(np.float32)


@dataclasses.dataclass(frozen=True)
class PlumeWhitened(Plume):
    """The plume observing ``(patch - mean) @ transform`` (``whitening``)."""

    mean: tuple = ()
    transform: tuple = ()

    def step(self, u, state, actions, params):
        state, obs, reward = super().step(u, state, actions, params)
        transform = jnp.asarray(np.array(self.transform, np.float32))
        return state, (obs - jnp.asarray(np.array(self.mean, np.float32))) @ transform, reward


@dataclasses.dataclass
class PlumePcaSection:  # the [env] config section: the plume's defaults
    name: str = "plume-pca"


def make(section, config):
    params = PlumeParams()
    mean, transform = whitening(Plume(), params)
    env = PlumeWhitened(mean=tuple(mean.tolist()), transform=tuple(map(tuple, transform.tolist())))
    return env, params


cognet_jax.register_env("plume-pca", PlumePcaSection, make)
