"""A COGNet-DICE policy that carries its observation encoder (encoded COGNet-DICE, SPEC
section 6), so it runs on raw observations outside the search.

An encoded search's ``NeuralPolicy`` reads the patch VAE's encoder mean ``mu [latent]``, not the
raw patch ``[16]``: inside the search the encoder is part of the controller kind
(``NeuralController.features``). ``EncodedPolicy`` bundles the two as one pytree -- the neural
policy and the VAE's parameters (sizes static) -- so ``controller_step`` needs nothing else.
``portable_policy(algorithm, policy)`` makes one from a search's policy.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from cognet_jax.controllers.neural import NeuralPolicy
from cognet_jax.vae import PatchVAE


@struct.dataclass
class EncodedPolicy:
    """``policy``: the ``NeuralPolicy`` over the latent, ``action_probs [agents, nodes,
    actions]``, networks reading ``[latent]``. ``vae_params``: the ``PatchVAE`` parameters whose
    encoder maps a raw observation ``[raw_features]`` to ``mu [latent]``."""

    policy: NeuralPolicy
    vae_params: Any
    latent: int = struct.field(pytree_node=False)
    vae_hidden: int = struct.field(pytree_node=False)
    raw_features: int = struct.field(pytree_node=False)

    @classmethod
    def of(cls, policy: NeuralPolicy, vae) -> EncodedPolicy:
        """From a neural policy and the ``TrainedVAE`` its search encoded with."""
        model = vae.model
        return cls(
            policy=policy,
            vae_params=vae.params,
            latent=model.latent,
            vae_hidden=model.hidden,
            raw_features=model.features,
        )

    def features(self, obs: jax.Array) -> jax.Array:
        """``obs [..., raw_features]`` -> encoder mean ``[..., latent]``; the function the
        search's rollouts apply (``ObservationPipeline.features``)."""
        model = PatchVAE(latent=self.latent, hidden=self.vae_hidden, features=self.raw_features)
        return model.apply(self.vae_params, obs.astype(jnp.float32), method=PatchVAE.encode)[0]


def portable_policy(algorithm, policy):
    """``policy`` of ``algorithm`` in a form that runs on the simulator's raw observations:
    an ``EncodedPolicy`` when the search's networks read a VAE encoding, else ``policy``."""
    pipeline = getattr(algorithm, "pipeline", None)
    if pipeline is None or pipeline.is_identity:
        return policy
    return EncodedPolicy.of(policy, pipeline.vae)
