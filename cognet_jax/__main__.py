from cognet_jax.cli import run

run()
