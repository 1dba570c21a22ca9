"""Shared test setup: JAX's persistent compilation cache (MJX compiles are slow on CPU)."""

import pathlib

import jax

_REPO = pathlib.Path(__file__).resolve().parents[1]

jax.config.update("jax_compilation_cache_dir", str(_REPO / ".cache" / "jax"))
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)
