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


def test_a_vae_of_a_simulators_own_observations_reads_their_range(tmp_path):
    """A VAE trained on observations of any scale (``observations``) maps each feature's 1%
    - 99% quantiles to [0, 1]; its file keeps that range, so a loaded copy encodes alike,
    and it decodes back into the observations' range. Its latent orders the observations
    by the factor that made them (here one hidden number behind 6 features)."""
    rng = np.random.default_rng(0)
    factor = rng.uniform(-1.0, 1.0, (4096, 1))
    obs = (300.0 + 50.0 * factor * np.linspace(1.0, 2.0, 6)).astype(np.float32)
    vae, losses = train_vae(seed=0, epochs=30, observations=obs)
    assert losses[-1] < losses[0]
    assert vae.model.features == 6 and np.asarray(vae.low).shape == (6,)
    save_vae(tmp_path / "v.msgpack", vae)
    again = load_vae(tmp_path / "v.msgpack")
    x = jnp.asarray(obs[:64])
    np.testing.assert_array_equal(np.asarray(vae.encode(x)[0]), np.asarray(again.encode(x)[0]))
    decoded = np.asarray(again.decode(again.encode(x)[0]))
    assert decoded.min() >= obs.min() - 1.0 and decoded.max() <= obs.max() + 1.0
    mu = np.asarray(again.encode(jnp.asarray(obs))[0])[:, 0]
    assert abs(spearman(mu, factor[:, 0])) > 0.95


def test_the_encoded_pipeline_runs_on_an_image_patch_simulator(tmp_path):
    """``network.observation = "encoded"`` on the plume (3 x 3 patches, no VAE file): the
    search trains a VAE on the plume's own observations, keeps it in the run folder, and
    ``evaluate`` of the folder reads that file to the same value."""
    import json

    from cognet_jax.cli import main

    out = tmp_path / "run"
    sets = [
        'network.observation="encoded"', "network.vae_latent=2", "network.vae_epochs=3",
        "algorithm.iterations=2", "algorithm.candidates=16", "algorithm.eval_rollouts=8",
        "algorithm.elites=2", "algorithm.polish_share=0", "algorithm.best_pool=0",
        "evaluation.rollouts=200", "run.plots=false",
    ]  # fmt: skip
    argv = ["train", "plume-n5", "--seed", "0", "--out", str(out), "--no-progress"]
    assert main([*argv, *(a for s in sets for a in ("--set", s))]) == 0
    results = json.loads((out / "results.json").read_text())
    assert load_vae(out / "vae.msgpack").model.features == 9
    assert main(["evaluate", str(out)]) == 0
    logged = json.loads((out / "evaluations.jsonl").read_text().splitlines()[-1])
    assert logged["mean"] == pytest.approx(results["final_value"]["mean"], rel=1e-5)
