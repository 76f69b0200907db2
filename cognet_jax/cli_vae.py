"""``cognet-jax vae train``: the VAE of Encoded COGNet-DICE trained on heatmap patches
(``cognet_jax.vae``), its arguments checked in one line each, written to ``--out``
(vae.msgpack, vae.json, vae_mu.png)."""

from __future__ import annotations

import time
from pathlib import Path

from tqdm.auto import tqdm

from cognet_jax.atomic_files import atomic_write_json
from cognet_jax.errors import UsageError
from cognet_jax.run_folder import check_out, claim, held_run

#: ``vae train``'s largest ``--kl-weight``: beyond it the KL term alone drives the code (and
#: past float32, NaN); its largest ``--epochs`` is ``vae.VAE_MAX_EPOCHS``
VAE_MAX_KL_WEIGHT = 1e6
#: ... and ``--latent``: a code no wider than the 4 x 4 patch it encodes
VAE_MAX_LATENT = 16


def vae_command(args) -> int:
    """``vae train`` with the parsed ``args``; exit status 0."""
    from cognet_jax.vae import VAE_MAX_EPOCHS

    if not 1 <= args.epochs <= VAE_MAX_EPOCHS:
        raise UsageError(f"--epochs must be in 1 .. {VAE_MAX_EPOCHS}, got {args.epochs}")
    if not 0 <= args.seed < 2**31:
        raise UsageError(f"--seed must be in 0 .. 2147483647, got {args.seed}")
    if not 1 <= args.latent <= VAE_MAX_LATENT:
        raise UsageError(
            f"--latent must be in 1 .. {VAE_MAX_LATENT} (a patch has 16 pixels), got {args.latent}"
        )
    if not 0 < args.kl_weight <= VAE_MAX_KL_WEIGHT:
        raise UsageError(f"--kl-weight must be in (0, {VAE_MAX_KL_WEIGHT:g}], got {args.kl_weight}")
    check_out(args.out)
    out = Path(args.out)
    held = held_run(out) if out.is_dir() else None
    if held:
        raise UsageError(
            f"{out} holds a run ({held}); its vae.msgpack belongs to that run: give another --out"
        )
    if (out / "vae.msgpack").exists() and not args.overwrite:
        raise UsageError(f"{out} already holds a VAE (vae.msgpack); replace it with --overwrite")
    with claim(out, resume=True):  # the lock and the write check; no run to refuse here
        return _train_vae(args, out)


def _train_vae(args, out: Path) -> int:
    import jax
    import numpy as np

    from cognet_jax.controllers.figures import plot_vae_mu
    from cognet_jax.vae import diagnostics, save_vae, train_vae

    t0 = time.perf_counter()
    with tqdm(total=args.epochs, disable=args.no_progress, desc="vae", unit="epoch") as bar:

        def progress(epoch, loss):
            bar.set_postfix(loss=f"{loss:.3f}")
            bar.update(1)

        vae, losses = train_vae(
            seed=args.seed,
            epochs=args.epochs,
            noisy=not args.no_noise,
            progress=progress,
            latent=args.latent,
            kl_weight=args.kl_weight,
        )
    if not np.isfinite(losses).all() or not all(
        bool(np.isfinite(np.asarray(x)).all()) for x in jax.tree.leaves(vae.params)
    ):
        raise UsageError(
            f"the VAE's training diverged (loss {losses[-1]:.3g}; --kl-weight "
            f"{args.kl_weight:g}): nothing written; lower --kl-weight"
        )
    info = diagnostics(vae)
    info.update(
        seed=args.seed,
        epochs=args.epochs,
        latent=args.latent,
        kl_weight=args.kl_weight,
        noisy=not args.no_noise,
        losses=losses.tolist(),
        wall_s=time.perf_counter() - t0,
    )
    save_vae(out / "vae.msgpack", vae)
    atomic_write_json(out / "vae.json", info)
    plot_vae_mu(vae, out / "vae_mu.png")
    print(
        f"vae: final loss {losses[-1]:.3f}; Spearman(mu, distance) "
        f"{info['spearman_mu_distance']:.4f}; mu {info['mu_source_corner']:.2f} at (2, 2) .. "
        f"{info['mu_far_corner']:.2f} at (13, 13); reconstruction MAE {info['recon_mae']:.4f}"
    )
    print(f"wrote {out}/vae.msgpack, vae.json, vae_mu.png")
    return 0
