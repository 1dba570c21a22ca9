"""``python -m emgail_jax.train``: an alias of ``python -m emgail_jax.run``."""

import sys

from emgail_jax.run import main

if __name__ == "__main__":
    sys.exit(main())
