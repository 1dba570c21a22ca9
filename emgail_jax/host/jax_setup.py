"""Process-wide JAX set-up for the command-line tools: host devices, the compilation cache and,
for a run spread over several processes or hosts, ``jax.distributed``."""

from __future__ import annotations

import dataclasses
import os

DEFAULT_CACHE = os.path.join(os.path.expanduser("~"), ".cache", "emgail_jax", "xla")


# XLA:CPU's concurrency-optimised scheduler deadlocks on the vmapped update step with the
# jaxlib this project pins (every thread idles in BlockUntilReady); the default scheduler does
# not. Set on `import emgail_jax`, before anything imports JAX.
XLA_WORKAROUNDS = ("--xla_cpu_enable_concurrency_optimized_scheduler=false",)


def add_xla_flags(*flags: str) -> None:
    current = os.environ.get("XLA_FLAGS", "")
    missing = [f for f in flags if f.split("=")[0] not in current]
    if missing:
        os.environ["XLA_FLAGS"] = " ".join([current, *missing]).strip()


@dataclasses.dataclass(frozen=True)
class Distributed:
    """Where a process of a multi-process run finds the others (``jax.distributed``)."""

    coordinator: str  # HOST:PORT of process 0
    num_processes: int
    process_id: int

    @classmethod
    def from_options(
        cls, coordinator: str | None, num_processes: int | None, process_id: int | None
    ) -> Distributed | None:
        """From command-line options, else JAX's standard environment variables
        (``JAX_COORDINATOR_ADDRESS``, ``JAX_NUM_PROCESSES``, ``JAX_PROCESS_ID``); ``None`` for a
        single-process run. Raises ``ValueError`` (one line) for an incomplete set."""
        env = os.environ
        coordinator = coordinator or env.get("JAX_COORDINATOR_ADDRESS")
        if num_processes is None and env.get("JAX_NUM_PROCESSES"):
            num_processes = int(env["JAX_NUM_PROCESSES"])
        if process_id is None and env.get("JAX_PROCESS_ID"):
            process_id = int(env["JAX_PROCESS_ID"])
        given = (coordinator, num_processes, process_id)
        if all(value is None for value in given):
            return None
        if any(value is None for value in given):
            raise ValueError(
                "a multi-process run needs --coordinator HOST:PORT, --num-processes N and "
                "--process-id I (or JAX_COORDINATOR_ADDRESS, JAX_NUM_PROCESSES, JAX_PROCESS_ID)"
            )
        if ":" not in coordinator or not 0 <= process_id < num_processes:
            raise ValueError(
                f"--coordinator must be HOST:PORT and 0 <= --process-id < --num-processes; got "
                f"{coordinator}, {process_id}, {num_processes}"
            )
        return cls(coordinator, num_processes, process_id)


def setup(
    host_devices: int | None = None,
    cache_dir: str | None = DEFAULT_CACHE,
    distributed: Distributed | None = None,
) -> None:
    """Call before the first JAX computation.

    Args:
      host_devices: split the CPU into this many XLA devices (XLA runs one core per device, so
        seeds sharded over two devices use both cores of a 2-core machine). ``None`` uses one
        device per core. Has no effect once JAX's backend exists or on GPU/TPU.
      cache_dir: JAX's persistent compilation cache, which removes repeated compiles across
        processes; ``None`` disables it.
      distributed: join a run of several processes (``jax.distributed``): ``jax.devices()``
        then lists every process's devices, and seeds are sharded over all of them.
    """
    devices = host_devices or os.cpu_count() or 1
    add_xla_flags(f"--xla_force_host_platform_device_count={devices}")
    import jax

    if distributed is not None:
        jax.distributed.initialize(
            distributed.coordinator, distributed.num_processes, distributed.process_id
        )
        # The CPU collectives (gloo) set up their connections on first use and give up after
        # 30 s; right after `initialize` every process is here at once, later (after compiles
        # that take each process its own time) not.
        from jax.experimental import multihost_utils

        multihost_utils.sync_global_devices("emgail_jax: processes connected")

    # A cache chosen earlier (JAX_COMPILATION_CACHE_DIR, or a caller's config) wins.
    if cache_dir and not jax.config.jax_compilation_cache_dir:
        jax.config.update("jax_compilation_cache_dir", cache_dir)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)
        jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
