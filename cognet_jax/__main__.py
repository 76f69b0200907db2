import sys

from cognet_jax.cli import main

sys.exit(main())
