"""EM-GAIL in JAX: model-free IRL from multi-intention, unlabeled, overlapping demonstrations."""

from __future__ import annotations

__version__ = "0.1.0"

# The XLA flags must be in place before JAX creates its CPU backend, hence at import time.
from emgail_jax.host.jax_setup import XLA_WORKAROUNDS, add_xla_flags

add_xla_flags(*XLA_WORKAROUNDS)


def __getattr__(name: str):
    # Imported on first use, so that `import emgail_jax` stays light and sets the XLA flags
    # above before anything imports JAX.
    if name in ("load_policy", "SavedRun"):
        from emgail_jax.host import saved_run

        return getattr(saved_run, name)
    if name in ("load_reward", "load_absorbing_reward"):
        from emgail_jax.reward import load

        return getattr(load, name)
    raise AttributeError(f"module 'emgail_jax' has no attribute {name!r}")
