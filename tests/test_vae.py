"""Patch VAE: mu monotonic in the distance from the source, reconstructions, save/load, CLI."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cognet_jax.vae import (
    diagnostics,
    load_vae,
    reachable_patches,
    reachable_positions,
    save_vae,
    spearman,
    train_vae,
    training_patches,
)


@pytest.fixture(scope="module")
def vae():
    return train_vae(seed=0, epochs=60)[0]


def test_training_data_sizes():
    x, t = training_patches(noisy=True)
    assert x.shape == (144 * 13, 16) and t.min() >= 0 and t.max() <= 1
    assert training_patches(noisy=False)[0].shape == (144, 16)


def test_spearman_helper():
    assert spearman([1, 2, 3, 4], [10, 20, 30, 40]) == pytest.approx(1.0)
    assert spearman([1, 2, 3, 4], [4, 3, 2, 1]) == pytest.approx(-1.0)


def test_mu_monotonic_in_distance_and_reconstruction(vae):
    info = diagnostics(vae)
    # mu increases with the distance from the source over the 144 reachable positions
    assert info["spearman_mu_distance"] >= 0.95, info
    assert info["mu_source_corner"] < info["mu_far_corner"]
    # stated bound: mean absolute pixel error of the reconstruction from mu < 0.05, worst < 0.25
    assert info["recon_mae"] < 0.05, info
    assert info["recon_max_abs"] < 0.25, info
    mu = np.asarray(vae.encode(jnp.asarray(reachable_patches()))[0])[:, 0]
    assert mu.shape == (144,)
    assert reachable_positions().shape == (144, 2)


def test_save_load_roundtrip_and_sample(vae, tmp_path):
    save_vae(tmp_path / "v.msgpack", vae)
    again = load_vae(tmp_path / "v.msgpack")
    x = jnp.asarray(reachable_patches()[:5])
    for a, b in zip(vae.encode(x), again.encode(x)):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-6)
    samples = again.sample(jax.random.key(0), 7)
    assert samples.shape == (7, 16) and float(samples.min()) > 0 and float(samples.max()) < 1
    z = again.sample_latent(jax.random.key(1), x)
    assert z.shape == (5, 1)


def test_vae_training_is_deterministic():
    a, la = train_vae(seed=3, epochs=2)
    b, lb = train_vae(seed=3, epochs=2)
    np.testing.assert_array_equal(la, lb)
    x = jnp.asarray(reachable_patches())
    np.testing.assert_array_equal(np.asarray(a.encode(x)[0]), np.asarray(b.encode(x)[0]))


def test_low_kl_weight_2d_latent_keeps_the_orientation_of_the_patch():
    """The encoded default experiments' VAE (2-D latent, KL weight 0.01, 200 epochs) tells the
    mirror positions (2, 7) and (7, 2) apart, which a distance-only latent cannot; with the
    thesis's KL weight 1 the second dimension collapses to the prior."""
    pos = reachable_positions()
    a, b = (int(np.where((pos == p).all(1))[0][0]) for p in ((2, 7), (7, 2)))
    x = jnp.asarray(reachable_patches())
    low = np.asarray(train_vae(seed=0, epochs=200, latent=2, kl_weight=0.01)[0].encode(x)[0])
    assert np.abs(low[a] - low[b]).max() > 1.0
    assert (low.std(0) > 0.3).all()
    plain = np.asarray(train_vae(seed=0, epochs=60, latent=2)[0].encode(x)[0])
    assert np.sort(plain.std(0))[0] < 0.1


def test_a_vae_file_with_other_shapes_or_non_finite_weights_is_refused(tmp_path):
    """``load_vae`` checks the parameters against the sizes its header gives and refuses
    non-finite ones (a diverged training encodes every patch as NaN)."""
    import jax
    from flax import serialization

    from cognet_jax.vae import load_vae, save_vae

    vae, _ = train_vae(seed=0, epochs=1)
    good = tmp_path / "good.msgpack"
    save_vae(good, vae)
    load_vae(good)
    blob = serialization.msgpack_restore(good.read_bytes())
    for name, edit, says in (
        ("hidden", lambda b: b.update(hidden=7), "do not fit latent 1 and hidden 7"),
        (
            "nan",
            lambda b: b.update(params=jax.tree.map(lambda x: x * np.nan, b["params"])),
            "not finite",
        ),
    ):
        damaged = dict(blob)
        edit(damaged)
        path = tmp_path / f"{name}.msgpack"
        path.write_bytes(serialization.msgpack_serialize(damaged))
        with pytest.raises(ValueError, match=says):
            load_vae(path)
