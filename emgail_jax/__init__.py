"""EM-GAIL in JAX: model-free IRL from multi-intention, unlabeled, overlapping demonstrations."""

from __future__ import annotations

import os

__version__ = "0.1.0"

# XLA:CPU's concurrency-optimised scheduler deadlocks on the vmapped update step with the
# jaxlib this project pins (every thread idles in BlockUntilReady); the default scheduler does
# not. The flag must be in place before JAX creates its CPU backend, hence at import time.
_XLA_WORKAROUNDS = ("--xla_cpu_enable_concurrency_optimized_scheduler=false",)


def _add_xla_flags(*flags: str) -> None:
    current = os.environ.get("XLA_FLAGS", "")
    missing = [f for f in flags if f.split("=")[0] not in current]
    if missing:
        os.environ["XLA_FLAGS"] = " ".join([current, *missing]).strip()


_add_xla_flags(*_XLA_WORKAROUNDS)


def __getattr__(name: str):
    # Imported on first use, so that `import emgail_jax` stays light and sets the XLA flags
    # above before anything imports JAX.
    if name in ("load_policy", "load_reward", "SavedRun"):
        from emgail_jax import saved_run

        return getattr(saved_run, name)
    raise AttributeError(f"module 'emgail_jax' has no attribute {name!r}")
