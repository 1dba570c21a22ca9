"""Shared test setup: the package's XLA flags first, then JAX's persistent compilation cache."""

import pathlib  # noqa: I001  (emgail_jax must be imported before jax, against isort order)

import emgail_jax  # noqa: F401  (sets XLA_FLAGS before JAX creates its CPU backend)
import jax

_REPO = pathlib.Path(__file__).resolve().parents[1]

jax.config.update("jax_compilation_cache_dir", str(_REPO / ".cache" / "jax"))
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)
