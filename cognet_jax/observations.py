"""Observation pipelines of COGNet-DICE: what the node networks read, and how training pairs are
made from what the rollouts saw (SPEC section 6).

Rollouts always see the simulator's raw observation (e.g. a heatmap patch ``[16]``). One function,
``ObservationPipeline.features``, maps it to the node networks' input; it is applied in exactly
two places, both inside the compiled iteration: where the controller consumes an observation
(``NeuralController.next_node``) and where training pairs are built
(``ObservationPipeline.training_pairs``).

* ``"raw"``: the identity; networks read the flattened patch ``[16]`` (2D COGNet-DICE, hidden
  160 in the thesis experiments).
* ``"encoded"``: the VAE's encoder mean ``mu [latent]`` (encoded COGNet-DICE, hidden 10): the
  heatmap's patch VAE, or on any other simulator whose observation holds several numbers one
  trained on its own observations (``simulator_vae``).

**Augmentation** (thesis Fig. 4.1; ``augment_samples = m > 0``): every training pair
``(z, q')`` gets ``m`` extra pairs with the same target: the observation's latent sample
``l ~ N(mu(z), sigma(z))`` itself (encoded) or its decoding ``decode(l) [16]`` (raw). The extra
pairs count like real ones in the cross-entropy (each pair has weight one).

The VAE (``resolve_vae``) **[choice]**: ``network.vae_path`` names a file written by
``cognet-jax vae train``; left empty, the VAE is trained on demand, deterministically from
``network.vae_seed`` with ``network.vae_epochs`` epochs, ``network.vae_latent`` latent
dimensions and KL weight ``network.vae_kl_weight`` (clean + noisy patches, the defaults of
``cognet_jax.vae``; a few seconds on CPU), cached for the process. A training run writes the
VAE it used to ``RUN_DIR/vae.msgpack`` and ``cognet-jax evaluate RUN_DIR`` reads that file, so a
policy is always evaluated with its own encoder.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from cognet_jax.config import ConfigError, require, require_positive
from cognet_jax.controllers.neural import NeuralController
from cognet_jax.memory import check_made_fits, trace_checked
from cognet_jax.rollout import rollouts
from cognet_jax.vae import (
    PATCH_FEATURES,
    VAE_MAX_EPOCHS,
    TrainedVAE,
    load_vae,
    train_vae,
    vae_bytes,
)

KINDS = ("raw", "encoded")
#: File name of the VAE a run used, inside its output folder.
VAE_FILE = "vae.msgpack"


def pipeline_run_files(pipeline) -> dict:
    """The run files (``engine.Search.run_files``) of a search that reads its observations
    through ``pipeline``: its VAE, which ``network.vae_path`` then names, if it has one."""
    if pipeline is None or pipeline.vae is None:
        return {}
    return {VAE_FILE: ("network.vae_path", vae_bytes(pipeline.vae))}


def legacy_run_files(results: dict, run_dir: Path) -> dict:
    """``run_files`` of a results.json written before that field: its VAE file with the
    ``vae_sha256`` it recorded (``None`` before that field too)."""
    if not (Path(run_dir) / VAE_FILE).is_file():
        return {}
    return {VAE_FILE: {"field": "network.vae_path", "sha256": results.get("vae_sha256")}}


@dataclasses.dataclass(frozen=True, eq=False)
class ObservationPipeline:
    """Maps raw observations ``[..., *raw_shape]`` to network features ``[..., *feature_shape]``.

    ``vae`` is required for ``kind="encoded"`` and for augmentation; its parameters are closed
    over as constants of the compiled iteration.
    """

    kind: str = "raw"
    raw_shape: tuple[int, ...] = ()
    vae: TrainedVAE | None = None
    augment_samples: int = 0

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"unknown observation kind {self.kind!r}; choose from {KINDS}")
        if (self.kind == "encoded" or self.augment_samples > 0) and self.vae is None:
            raise ValueError("the encoded pipeline and augmentation need a VAE")

    @property
    def feature_shape(self) -> tuple[int, ...]:
        return (self.vae.latent,) if self.kind == "encoded" else self.raw_shape

    @property
    def is_identity(self) -> bool:
        return self.kind == "raw"

    def features(self, obs: jax.Array) -> jax.Array:
        """``obs [..., *raw_shape]`` -> ``[..., *feature_shape]`` (identity or encoder mean)."""
        if self.kind == "raw":
            return obs
        return self.vae.encode(self._flat(obs))[0]

    def _flat(self, obs: jax.Array) -> jax.Array:
        """``obs [..., *raw_shape]`` as the VAE reads it: ``[..., F]`` float32."""
        lead = obs.shape[: obs.ndim - len(self.raw_shape)]
        return obs.reshape(lead + (-1,)).astype(jnp.float32)

    def training_pairs(self, key: jax.Array, obs, src, tgt, valid):
        """Network inputs of the training pairs, with ``augment_samples`` extra pairs per pair.

        Args:
          key: drives the latent samples (unused without augmentation).
          obs: raw observations ``[agents, P, *raw_shape]``; ``src, tgt, valid [agents, P]``.

        Returns:
          ``(features [agents, P * (1 + m), *feature_shape], src, tgt, valid)`` with the
          ``[agents, P * (1 + m)]`` bookkeeping repeated for the extra pairs.
        """
        feats = self.features(obs)
        m = self.augment_samples
        if m == 0:
            return feats, src, tgt, valid
        mu, logvar = self.vae.encode(self._flat(obs))  # [agents, P, latent]
        eps = jax.random.normal(key, (m,) + mu.shape)
        latent = mu[None] + jnp.exp(0.5 * logvar)[None] * eps  # [m, agents, P, latent]
        extra = latent
        if self.kind != "encoded":  # decoded: raw observations again
            decoded = self.vae.decode(latent)
            extra = decoded.reshape(decoded.shape[:-1] + tuple(self.raw_shape))
        extra = jnp.moveaxis(extra, 0, 1)  # [agents, m, P, F]
        agents, p = src.shape
        extra = extra.reshape((agents, m * p) + extra.shape[3:]).astype(feats.dtype)

        def repeat(x):  # [agents, P] -> [agents, P * (1 + m)]
            return jnp.concatenate([x, jnp.tile(x, (1, m))], axis=1)

        return (
            jnp.concatenate([feats, extra], axis=1),
            repeat(src),
            repeat(tgt),
            repeat(valid),
        )


def neural_controller(env, nodes: int, hidden: int, pipeline: ObservationPipeline | None = None):
    """``(pipeline, NeuralController)`` of a COGNet-DICE search on ``env``: the networks read
    the pipeline's features (``pipeline=None``: the raw observation)."""
    if pipeline is None:
        pipeline = ObservationPipeline("raw", env.obs_shape)
    controller = NeuralController(
        num_agents=env.num_agents,
        num_nodes=nodes,
        num_actions=env.num_actions,
        obs_shape=pipeline.feature_shape,
        hidden=hidden,
        action_counts=env.action_counts,
        features=None if pipeline.is_identity else pipeline.features,
    )
    return pipeline, controller


@functools.lru_cache(maxsize=4)
def trained_vae(seed: int, epochs: int, latent: int = 1, kl_weight: float = 1.0) -> TrainedVAE:
    """The on-demand VAE: ``train_vae`` on clean + noisy patches, cached."""
    return train_vae(seed=seed, epochs=epochs, latent=latent, kl_weight=kl_weight)[0]


def resolve_vae(
    vae_path: str, seed: int, epochs: int, latent: int = 1, kl_weight: float = 1.0
) -> TrainedVAE:
    """The VAE in ``vae_path`` or, when it is empty, the on-demand one (see module docstring).
    A missing, foreign or damaged file raises ``ConfigError`` naming ``network.vae_path``, a
    file of another latent size one naming ``network.vae_latent``."""
    if vae_path:
        path = Path(vae_path).expanduser()
        if not path.is_file():
            what = "not a regular file" if path.exists() else "no such file"
            raise ConfigError("network.vae_path", f"{what}: {vae_path}")
        try:
            vae = load_vae(path)
        except Exception as err:  # msgpack's and the blob's errors: not a VAE file, or torn
            raise ConfigError(
                "network.vae_path",
                f"{vae_path}: not a VAE file of `cognet-jax vae train`, or damaged "
                f"({type(err).__name__}: {err})",
            ) from None
        if vae.model.latent != latent:
            raise ConfigError(
                "network.vae_latent",
                f"is {latent}, but the VAE in {vae_path} has {vae.model.latent} latent "
                f"dimensions: set network.vae_latent = {vae.model.latent}",
            )
        return vae
    return trained_vae(seed, epochs, latent, kl_weight)


def check_network(config, training: bool) -> None:
    """``ConfigError`` naming the field for a bad ``[network]`` of a COGNet-DICE search;
    ``training``: the optimiser settings are checked too (the thesis algorithm trains its
    networks; the weight-space search samples them)."""
    net = config.network
    require_positive(net, "network", "hidden")
    if training:
        require_positive(net, "network", "train_steps")
        require(net.learning_rate > 0, "network.learning_rate", "must be > 0")
        require(0 <= net.momentum < 1, "network.momentum", "must be in [0, 1)")
    require_positive(net, "network", "vae_epochs", "augment_samples", "vae_latent")
    require(  # as ``cognet-jax vae train`` bounds them: a VAE file holds no more
        net.vae_latent <= PATCH_FEATURES,
        "network.vae_latent",
        f"at most {PATCH_FEATURES} (a code no wider than the 4 x 4 patch), got {net.vae_latent}",
    )
    require(
        net.vae_epochs <= VAE_MAX_EPOCHS,
        "network.vae_epochs",
        f"at most {VAE_MAX_EPOCHS} (an epoch is one pass over the patches), got {net.vae_epochs}",
    )
    require(net.vae_kl_weight > 0, "network.vae_kl_weight", f"must be > 0, got {net.vae_kl_weight}")
    require(net.vae_seed >= 0, "network.vae_seed", f"must be >= 0, got {net.vae_seed}")


def build_pipeline(config, env, env_params=None) -> ObservationPipeline:
    """The observation pipeline of ``config.network`` (trains or loads the VAE only when the
    encoded pipeline or augmentation needs it): the heatmap's patch VAE (``resolve_vae``), or
    for any other simulator one trained on its own observations under ``env_params``
    (``simulator_vae``; ``None``: the config's)."""
    net = config.network
    vae = None
    if net.observation == "encoded" or net.augment:
        features = math.prod(env.obs_shape)
        if env.num_obs is not None or features < 2:
            raise ConfigError(
                "network.observation" if net.observation == "encoded" else "network.augment",
                "a VAE encodes continuous observations; this simulator observes "
                + ("discrete ones" if env.num_obs is not None else "a single number"),
            )
        if config.env.name == "heatmap" or net.vae_path:
            vae = resolve_vae(
                net.vae_path, net.vae_seed, net.vae_epochs, net.vae_latent, net.vae_kl_weight
            )
        else:
            if env_params is None:
                from cognet_jax.registry import build_env

                env_params = build_env(config)[1]
            vae = simulator_vae(env, env_params, net)
        if vae.model.features != features:
            raise ConfigError(
                "network.vae_path",
                f"the VAE reads {vae.model.features} numbers per observation; this simulator "
                f"observes {features} (shape {tuple(env.obs_shape)})",
            )
    return ObservationPipeline(
        kind=net.observation,
        raw_shape=env.obs_shape,
        vae=vae,
        augment_samples=net.augment_samples if net.augment else 0,
    )


#: Rollouts of the uniformly random controller that give the input statistics.
STATS_ROLLOUTS = 4096
#: Observations a simulator's own VAE trains on (``simulator_vae``)
VAE_OBSERVATIONS = 8192
#: the VAEs trained on simulators' observations in this process: key -> (env, params, vae)
_SIMULATOR_VAES: dict = {}


def simulator_vae(env, env_params, net) -> TrainedVAE:
    """The VAE of a simulator other than the heatmap: ``train_vae`` on ``VAE_OBSERVATIONS``
    of the observations of rollouts of the uniformly random controller (enough for 4 times as many,
    at most ``STATS_ROLLOUTS``; key ``network.vae_seed``), every agent's and step's alike,
    flattened; ``network``'s ``vae_epochs``, ``vae_latent``, ``vae_kl_weight``; cached in the
    process per simulator, params and settings. **[choice]** The random controller's observations:
    what a search sees first, with no policy to prefer; the run keeps its VAE (``vae.msgpack``), so
    its policy is evaluated with the encoder it was searched with."""
    settings = (net.vae_seed, net.vae_epochs, net.vae_latent, net.vae_kl_weight)
    leaves = tuple(np.asarray(x).tobytes() for x in jax.tree.leaves(env_params))
    key = (env, leaves, settings)
    try:
        hash(key)
    except TypeError:  # an unhashable simulator object: one cache entry per object
        key = (id(env), leaves, settings)
    if key not in _SIMULATOR_VAES:
        controller = neural_controller(env, 2, 1)[1]
        uniform = uniform_policy(controller)
        seed = jax.random.key(net.vae_seed)
        k_roll, k_pick = jax.random.split(seed)
        per_rollout = env.horizon * env.num_agents  # 4 x the observations kept, at most
        count = int(np.clip(-(-4 * VAE_OBSERVATIONS // per_rollout), 16, STATS_ROLLOUTS))
        traj = jax.jit(
            lambda k: rollouts(env, controller, k, count, env_params, uniform, record=True)
        )(k_roll)
        obs = np.asarray(traj.obs, np.float32)
        obs = obs.reshape(-1, math.prod(env.obs_shape))
        pick = np.asarray(jax.random.permutation(k_pick, obs.shape[0]))[:VAE_OBSERVATIONS]
        vae = train_vae(
            seed=net.vae_seed,
            epochs=net.vae_epochs,
            latent=net.vae_latent,
            kl_weight=net.vae_kl_weight,
            observations=obs[pick],
        )[0]
        _SIMULATOR_VAES[key] = (env, env_params, vae)
    return _SIMULATOR_VAES[key][2]


#: statistics of raw observations computed in this process: ``(id(env), id(env_params),
#: controller shape) -> (env, env_params, stats)`` (the objects held, so the ids stay theirs);
#: a config's load decides ``standardize_inputs = "auto"`` with them, then its noise pilot and
#: its build need them again
_RAW_STATS: dict = {}


def uniform_policy(controller):
    """The uniformly random policy of a neural ``controller``: its initial policy's uniform
    actions, zero networks (uniform next nodes)."""
    template = controller.init(jax.random.key(0))
    return template.replace(net_params=jax.tree.map(jnp.zeros_like, template.net_params))


def input_statistics(env, controller, pipeline, env_params, memory=None):
    """``(mean, scale) [agents, F]`` of the networks' input features over the observations
    of ``STATS_ROLLOUTS`` rollouts of the uniformly random controller (key 0) under
    ``env_params``; a feature that never varies gets scale 1. Their trajectories must fit
    ``memory`` bytes (``memory.trace_checked``). Raw observations' statistics are computed
    once per simulator, params and controller shape in a process (``_RAW_STATS``)."""
    return _measured(env, controller, pipeline, env_params, memory)[:2]


def input_covariance(env, controller, pipeline, env_params, memory=None):
    """``[agents, F, F]``: the covariance of the networks' input features over the rollouts
    of ``input_statistics`` (the same measurement)."""
    return _measured(env, controller, pipeline, env_params, memory)[2]


def _measured(env, controller, pipeline, env_params, memory):
    """``_statistics`` of the rollouts of ``input_statistics``, cached for raw observations."""
    check_made_fits(controller.init, (jax.random.key(0),), memory, "one joint policy's arrays")
    uniform = uniform_policy(controller)
    record = jax.jit(
        lambda k: rollouts(env, controller, k, STATS_ROLLOUTS, env_params, uniform, record=True)
    )
    what = f"the input statistics ({STATS_ROLLOUTS} recorded rollouts)"
    trace_checked(record, (jax.random.key(0),), memory, what)  # traced only: no rollout
    if pipeline.kind != "raw":
        return _statistics(record, pipeline)
    shape = (controller.num_agents, controller.num_nodes, controller.num_actions)
    key = (id(env), id(env_params), shape, controller.hidden)
    if key not in _RAW_STATS:
        _RAW_STATS[key] = (env, env_params, _statistics(record, pipeline))
    return _RAW_STATS[key][2]


def _statistics(record, pipeline):
    """``(mean, scale, covariance)`` of the trajectories ``record(key)`` records: the first two
    are ``input_statistics``, the last ``input_covariance``."""
    traj = record(jax.random.key(0))
    feats = pipeline.features(traj.obs)  # [R, H, agents, *feature_shape]
    feats = feats.reshape(feats.shape[:3] + (-1,))
    mean, std = feats.mean((0, 1)), feats.std((0, 1))
    centred = feats - mean
    covariance = jnp.einsum("rhaf,rhag->afg", centred, centred) / (feats.shape[0] * feats.shape[1])
    return mean, jnp.where(std > 1e-6, std, 1.0), covariance
