"""Process-wide JAX set-up for the command-line tools: host devices and the compilation cache."""

from __future__ import annotations

import os

from emgail_jax import _add_xla_flags

DEFAULT_CACHE = os.path.join(os.path.expanduser("~"), ".cache", "emgail_jax", "xla")


def setup(host_devices: int | None = None, cache_dir: str | None = DEFAULT_CACHE) -> None:
    """Call before the first JAX computation.

    Args:
      host_devices: split the CPU into this many XLA devices (XLA runs one core per device, so
        seeds sharded over two devices use both cores of a 2-core machine). ``None`` uses one
        device per core. Has no effect once JAX's backend exists or on GPU/TPU.
      cache_dir: JAX's persistent compilation cache, which removes repeated compiles across
        processes; ``None`` disables it.
    """
    devices = host_devices or os.cpu_count() or 1
    _add_xla_flags(f"--xla_force_host_platform_device_count={devices}")
    import jax

    # A cache chosen earlier (JAX_COMPILATION_CACHE_DIR, or a caller's config) wins.
    if cache_dir and not jax.config.jax_compilation_cache_dir:
        jax.config.update("jax_compilation_cache_dir", cache_dir)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)
        jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
