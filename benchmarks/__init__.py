"""Speed measurements of cognet_jax against PyTorch references (``python -m benchmarks``)."""
