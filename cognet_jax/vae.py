"""Patch VAE (SPEC section 6): compresses a 4 x 4 heatmap patch ``[16]`` into a latent ``[latent]``;
the same model compresses any simulator's observations of ``F`` numbers (``train_vae`` with
``observations``: each feature's range, ``observation_range``, mapped to [0, 1] first).

Model: encoder ``16 -> hidden (ReLU) -> (mu [latent], logvar [latent])``; decoder
``latent -> hidden (ReLU) -> 16 (sigmoid)``. Loss per patch (minimised): summed binary
cross-entropy of the reconstruction + ``kl_weight`` * KL(N(mu, sigma) || N(0, 1)); weight 1 (the
thesis's plain VAE) by default. **[choice]** A 2-D latent trained with weight 1 keeps only the
distance to the source (the second mean collapses to the prior); with a smaller weight (a
beta-VAE with beta < 1) both dimensions stay informative, so the orientation of the patch --
*which* coordinate is still far from the source -- survives the encoding. The encoded default
experiments use ``latent=2, kl_weight=0.01`` and 200 epochs (experiments/README.md has the
measurements).

Training data (``training_patches``): the 144 clean 4 x 4 stride-1 windows of the scene that
an agent can see (positions in [2, 13]^2: the 13 x 13 windows minus the never-observed last row
and column) plus, when ``noisy``, the windows of 12 noisy scenes,
``scene + amplitude * N(mean, std)`` per pixel with mean in {-0.001, 0.001}, std in
{0.001, 0.01}, amplitude in {0.9, 1.0, 1.1} (1728 patches).
**[choice]** The noisy patch is the encoder input; its BCE target is the same patch clipped to
[0, 1] (BCE needs targets in [0, 1]).

Optimiser **[choice]**: Adam, lr 3e-3, minibatches of 16, 60 epochs, shuffled per epoch by a
fixed key (the thesis: Adam lr 1e-3, batch 1, 100 epochs; ours reaches the same loss in far
fewer steps). **[choice]** Canonical sign: the latent of a 1-D VAE is only defined up to a sign
(the prior is symmetric); after training, the sign is flipped if needed so that mu *increases*
with the distance from the source, as in thesis Fig. 5.10 -- an exact symmetry of the model
(encoder mean and decoder input weights are negated together).

Files: ``save_vae(path, vae)`` / ``load_vae(path)`` write/read one msgpack file (Flax
serialization) holding the sizes and the parameters.
"""

from __future__ import annotations

import dataclasses
import itertools
from pathlib import Path
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import serialization

from cognet_jax.atomic_files import atomic_write_bytes
from cognet_jax.envs.heatmap import HIGH, LOW, PATCH, all_patches, scene

#: numbers in one observed patch (the VAE's input)
PATCH_FEATURES = PATCH * PATCH
#: the most epochs a VAE trains (``cognet-jax vae train --epochs``, ``network.vae_epochs``): an
#: epoch is one pass over 1,872 patches, milliseconds
VAE_MAX_EPOCHS = 100_000

NOISE_MEANS = (-0.001, 0.001)
NOISE_STDS = (0.001, 0.01)
NOISE_AMPLITUDES = (0.9, 1.0, 1.1)


class PatchVAE(nn.Module):
    """The VAE; ``__call__(x [B, 16], eps [B, latent])`` returns ``(recon [B, 16], mu, logvar)``."""

    latent: int = 1
    hidden: int = 8
    features: int = PATCH_FEATURES

    def setup(self):
        self.enc_hidden = nn.Dense(self.hidden)
        self.enc_mu = nn.Dense(self.latent)
        self.enc_logvar = nn.Dense(self.latent)
        self.dec_hidden = nn.Dense(self.hidden)
        self.dec_out = nn.Dense(self.features)

    def encode(self, x):
        h = nn.relu(self.enc_hidden(x))
        return self.enc_mu(h), self.enc_logvar(h)

    def decode_logits(self, z):
        return self.dec_out(nn.relu(self.dec_hidden(z)))

    def decode(self, z):
        return nn.sigmoid(self.decode_logits(z))

    def __call__(self, x, eps):
        mu, logvar = self.encode(x)
        z = mu + jnp.exp(0.5 * logvar) * eps
        return self.decode_logits(z), mu, logvar


@dataclasses.dataclass(frozen=True, eq=False)
class TrainedVAE:
    """A trained VAE: the module and its parameters, with pure helper functions.

    All helpers take a single patch ``[16]`` or a batch ``[..., 16]``.
    """

    model: PatchVAE
    params: Any
    #: ``[F]`` each input feature's range ``(low, high)``: the encoder reads ``(x - low) /
    #: (high - low)`` and the decoder's (0, 1) output is mapped back; None: the heatmap's
    #: patches, read as they are
    low: Any = None
    high: Any = None

    @property
    def latent(self) -> int:
        return self.model.latent

    def _unit(self, x):
        if self.low is None:
            return x
        return (x - self.low) / (self.high - self.low)

    def encode(self, x):
        """``x [..., F]`` -> ``(mu [..., latent], logvar [..., latent])``."""
        return self.model.apply(self.params, self._unit(x), method=PatchVAE.encode)

    def decode(self, z):
        """``z [..., latent]`` -> reconstruction ``[..., F]`` (in (0, 1) for the heatmap's
        patches; in the features' range otherwise)."""
        out = self.model.apply(self.params, z, method=PatchVAE.decode)
        return out if self.low is None else self.low + out * (self.high - self.low)

    def sample_latent(self, key, x):
        """One draw ``z ~ N(mu(x), sigma(x))``, ``[..., latent]``."""
        mu, logvar = self.encode(x)
        return mu + jnp.exp(0.5 * logvar) * jax.random.normal(key, mu.shape)

    def sample(self, key, num: int):
        """``num`` patches decoded from the prior ``z ~ N(0, 1)``: ``[num, 16]``."""
        return self.decode(jax.random.normal(key, (num, self.latent)))


def training_patches(noisy: bool = True, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``(inputs [N, 16], targets [N, 16])``: 144 clean patches, plus 1728 noisy ones when
    ``noisy`` (see module docstring); targets are the inputs clipped to [0, 1]."""
    clean = scene()
    images = [clean]
    if noisy:
        rng = np.random.default_rng(seed)
        for mean, std, amp in itertools.product(NOISE_MEANS, NOISE_STDS, NOISE_AMPLITUDES):
            images.append(clean + amp * rng.normal(mean, std, clean.shape).astype(np.float32))
    x = np.concatenate([reachable_patches(img) for img in images]).astype(np.float32)
    return x, np.clip(x, 0.0, 1.0)


def loss_fn(model: PatchVAE, params, x, target, eps, kl_weight: float = 1.0):
    """Mean over the batch of (summed BCE + kl_weight * KL); ``x, target [B, 16]``,
    ``eps [B, latent]``."""
    logits, mu, logvar = model.apply(params, x, eps)
    bce = optax.sigmoid_binary_cross_entropy(logits, target).sum(-1)
    kl = -0.5 * jnp.sum(1.0 + logvar - mu**2 - jnp.exp(logvar), axis=-1)
    return jnp.mean(bce + kl_weight * kl)


def reachable_positions() -> np.ndarray:
    """Every position an agent can observe from, ``[144, 2]`` (x, y in [2, 13], row-major)."""
    r = np.arange(LOW, HIGH + 1)
    return np.stack(np.meshgrid(r, r, indexing="ij"), -1).reshape(-1, 2)


def reachable_patches(image: np.ndarray | None = None) -> np.ndarray:
    """Patches ``[144, 16]`` of ``image`` (default: the clean scene) seen from
    ``reachable_positions()`` (same order): the windows with top-left corner in [0, 11]^2."""
    windows = all_patches(image)  # [13 * 13, 16], corners row-major
    corners = reachable_positions() - 2
    return windows[corners[:, 0] * 13 + corners[:, 1]]


def _canonical_sign(vae: TrainedVAE) -> TrainedVAE:
    """Flip the first latent dimension's sign if its mean decreases with the distance from the
    source (the other dimensions are left as trained)."""
    mu = np.asarray(vae.encode(jnp.asarray(reachable_patches()))[0])[:, 0]
    dist = np.linalg.norm(reachable_positions(), axis=-1)
    if np.corrcoef(mu, dist)[0, 1] >= 0:
        return vae
    p = jax.tree.map(lambda a: a, vae.params)  # copy the nesting
    inner = dict(p["params"])
    flip = jnp.ones(vae.latent).at[0].set(-1.0)
    inner["enc_mu"] = jax.tree.map(lambda a: a * flip, inner["enc_mu"])
    dec = dict(inner["dec_hidden"])
    dec["kernel"] = dec["kernel"] * flip[:, None]
    inner["dec_hidden"] = dec
    return TrainedVAE(vae.model, {"params": inner})


def train_vae(
    seed: int = 0,
    epochs: int = 60,
    batch: int = 16,
    learning_rate: float = 3e-3,
    latent: int = 1,
    hidden: int = 8,
    noisy: bool = True,
    progress=None,
    kl_weight: float = 1.0,
    observations: np.ndarray | None = None,
) -> tuple[TrainedVAE, np.ndarray]:
    """Train the patch VAE deterministically from ``seed``: on the heatmap's patches
    (``training_patches``), or on ``observations [N, F]`` of any simulator
    (``observation_range`` maps them to [0, 1]).

    Returns ``(vae, losses [epochs])`` (mean training loss per epoch). ``progress`` is called
    with ``(epoch, loss)`` after each epoch (e.g. to drive a progress bar).
    """
    low = high = None
    if observations is None:
        x_np, t_np = training_patches(noisy, seed)
    else:
        low, high = observation_range(observations)
        x_np = ((observations - low) / (high - low)).astype(np.float32)
        t_np = np.clip(x_np, 0.0, 1.0)
    n = x_np.shape[0] - x_np.shape[0] % batch
    model = PatchVAE(latent=latent, hidden=hidden, features=x_np.shape[-1])
    key = jax.random.key(seed)
    k_init, k_train = jax.random.split(key)
    params = model.init(k_init, jnp.zeros((1, x_np.shape[-1])), jnp.zeros((1, latent)))
    opt = optax.adam(learning_rate)
    opt_state = opt.init(params)
    x_all, t_all = jnp.asarray(x_np), jnp.asarray(t_np)
    grad = jax.value_and_grad(lambda p, x, t, e: loss_fn(model, p, x, t, e, kl_weight))

    @jax.jit
    def epoch(params, opt_state, k):
        k_perm, k_eps = jax.random.split(k)
        perm = jax.random.permutation(k_perm, x_all.shape[0])[:n].reshape(-1, batch)
        eps = jax.random.normal(k_eps, (perm.shape[0], batch, latent))

        def one(carry, inp):
            params, opt_state = carry
            idx, e = inp
            loss, g = grad(params, x_all[idx], t_all[idx], e)
            updates, opt_state = opt.update(g, opt_state, params)
            return (optax.apply_updates(params, updates), opt_state), loss

        (params, opt_state), losses = jax.lax.scan(one, (params, opt_state), (perm, eps))
        return params, opt_state, losses.mean()

    losses = []
    for i in range(epochs):
        params, opt_state, loss = epoch(params, opt_state, jax.random.fold_in(k_train, i))
        losses.append(float(loss))
        if progress is not None:
            progress(i, losses[-1])
    if observations is not None:  # no scene to orient the latent by
        bounds = (jnp.asarray(low, jnp.float32), jnp.asarray(high, jnp.float32))
        return TrainedVAE(model, params, *bounds), np.asarray(losses)
    return _canonical_sign(TrainedVAE(model, params)), np.asarray(losses)


#: quantiles of each feature that ``observation_range`` maps to 0 and 1
RANGE_QUANTILES = (0.01, 0.99)


def observation_range(observations: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(low, high) [F]``: each feature's 1% and 99% quantiles over ``observations [N,
    F]``, the range the VAE maps to [0, 1] (its reconstruction targets are clipped there).
    **[choice]** Quantiles, not the extremes: a rare outlier of Gaussian noise would squeeze
    the rest of a feature into a sliver of the range. A feature that never varies gets a
    range of 1 around its value."""
    low, high = np.quantile(np.asarray(observations, np.float64), RANGE_QUANTILES, axis=0)
    flat = high - low < 1e-6
    low, high = np.where(flat, low - 0.5, low), np.where(flat, high + 0.5, high)
    return low.astype(np.float32), high.astype(np.float32)


def vae_bytes(vae: TrainedVAE) -> bytes:
    """The VAE file's bytes (msgpack: latent and hidden sizes, parameters)."""
    blob = {
        "latent": vae.model.latent,
        "hidden": vae.model.hidden,
        "params": serialization.to_state_dict(jax.device_get(vae.params)),
    }
    if vae.low is not None:  # a simulator's own observations (the heatmap's files: as before)
        blob["features"] = vae.model.features
        blob["low"], blob["high"] = np.asarray(vae.low), np.asarray(vae.high)
    return serialization.msgpack_serialize(blob)


def save_vae(path: str | Path, vae: TrainedVAE) -> None:
    atomic_write_bytes(path, vae_bytes(vae))


#: the largest VAE file read: a patch VAE's parameters take a few KiB
MAX_VAE_BYTES = 2**24


def load_vae(path: str | Path) -> TrainedVAE:
    """The VAE of a ``save_vae`` file; ``ValueError`` for a file too large to be one, sizes
    out of range, parameters of other shapes than its sizes give, or parameters that are not
    finite (a VAE whose training diverged encodes every patch as NaN)."""
    path = Path(path)
    if path.stat().st_size > MAX_VAE_BYTES:
        raise ValueError(f"{path.stat().st_size} bytes, over the {MAX_VAE_BYTES} a VAE file has")
    blob = serialization.msgpack_restore(path.read_bytes())
    latent, hidden = int(blob["latent"]), int(blob["hidden"])
    features = int(blob.get("features", PATCH_FEATURES))
    if not (1 <= features <= 1 << 20 and 1 <= latent <= features and 1 <= hidden <= 4096):
        raise ValueError(f"features {features}, latent {latent} and hidden {hidden} out of range")
    model = PatchVAE(latent=latent, hidden=hidden, features=features)
    params = jax.tree.map(jnp.asarray, blob["params"])
    shapes = jax.eval_shape(
        model.init, jax.random.key(0), jnp.zeros((1, features)), jnp.zeros((1, latent))
    )
    want = jax.tree.map(lambda x: tuple(x.shape), shapes)
    if jax.tree.map(lambda x: tuple(x.shape), params) != want:
        raise ValueError(f"its parameters do not fit latent {latent} and hidden {hidden}")
    low = high = None
    if "low" in blob:
        low, high = (jnp.asarray(blob[k], jnp.float32) for k in ("low", "high"))
        if low.shape != (features,) or high.shape != (features,) or not bool(jnp.all(high > low)):
            raise ValueError(f"its input range is not {features} intervals")
    leaves = jax.tree.leaves(params) + ([low, high] if low is not None else [])
    if not all(bool(jnp.all(jnp.isfinite(x))) for x in leaves):
        raise ValueError("its parameters are not finite (its training diverged)")
    return TrainedVAE(model, params, low, high)


def spearman(a: np.ndarray, b: np.ndarray) -> float:
    """Spearman rank correlation (average ranks for ties)."""

    def ranks(v):
        v = np.asarray(v, np.float64)
        order = np.argsort(v, kind="stable")
        r = np.empty(len(v))
        r[order] = np.arange(len(v), dtype=np.float64)
        for val in np.unique(v):  # average tied ranks
            tie = v == val
            r[tie] = r[tie].mean()
        return r

    return float(np.corrcoef(ranks(a), ranks(b))[0, 1])


def diagnostics(vae: TrainedVAE) -> dict:
    """Quality numbers over the reachable positions: Spearman(mu, distance), mu at the source
    corner (2, 2) and the far corner (13, 13), mean absolute reconstruction error of the clean
    patches (from mu) and its maximum."""
    x = jnp.asarray(reachable_patches())
    mu, logvar = vae.encode(x)
    recon = np.asarray(vae.decode(mu))
    mu = np.asarray(mu)[:, 0]
    pos = reachable_positions()
    dist = np.linalg.norm(pos, axis=-1)
    err = np.abs(recon - np.asarray(x))
    return {
        "spearman_mu_distance": spearman(mu, dist),
        "mu_source_corner": float(mu[0]),
        "mu_far_corner": float(mu[-1]),
        "mean_sigma": float(np.exp(0.5 * np.asarray(logvar)).mean()),
        "recon_mae": float(err.mean()),
        "recon_max_abs": float(err.max()),
    }
