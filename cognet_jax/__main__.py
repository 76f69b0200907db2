from cognet_jax.entry import run

run()
