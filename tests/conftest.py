"""Shared test setup: two host devices (so seed sharding is exercised) and JAX's persistent
compilation cache, both before JAX creates its backend."""

import pathlib

from emgail_jax import runtime

_REPO = pathlib.Path(__file__).resolve().parents[1]

runtime.setup(host_devices=2, cache_dir=str(_REPO / ".cache" / "jax"))
