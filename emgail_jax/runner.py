"""Runs the update step for many seeds: ``jit(vmap(scan(update)))``, sharded over devices.

Seeds are the leading axis of every leaf of the train state. They are sharded over as many
devices as divide the seed count (XLA:CPU runs one core per device), each device vmapping its
share. Iterations are scanned in chunks of ``chunk_size`` inside one compiled call; the host
only acts between chunks (logs, progress, checkpoints).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from emgail_jax.training import TrainState


@dataclasses.dataclass
class Timings:
    compile_s: float = 0.0
    train_s: float = 0.0
    iterations: int = 0


def chunk_length(iterations: int, chunk_size: int) -> int:
    """The largest chunk <= ``chunk_size`` that divides ``iterations`` (one compile only)."""
    return max(d for d in range(1, min(chunk_size, iterations) + 1) if iterations % d == 0)


def seed_sharding(seeds: int) -> NamedSharding:
    devices = jax.devices()
    count = max(d for d in range(1, len(devices) + 1) if seeds % d == 0)
    return NamedSharding(Mesh(np.asarray(devices[:count]), ("seed",)), PartitionSpec("seed"))


def default_seed_batch() -> int | None:
    """Seeds vmapped together on one device: one on CPU, all of a device's on accelerators.

    XLA:CPU runs a device's program on one core, so vmapping seeds there batches nothing: on
    this 2-core machine, halfcheetah (K = 3) took 1.06 s per seed-iteration with 2 seeds
    vmapped on each core and 0.78-0.87 s with them one after the other; the driver took
    the same.
    """
    return 1 if jax.default_backend() == "cpu" else None


def map_in_batches(f: Callable, batch: int | None) -> Callable:
    """``f`` over the leading axis of a pytree: ``vmap`` over groups of at most ``batch``
    elements (the largest group size that divides the axis), the groups one after the other
    (``lax.map``); ``None`` vmaps all at once."""

    def mapped(tree):
        n = jax.tree.leaves(tree)[0].shape[0]
        if batch is None or batch >= n:
            return jax.vmap(f)(tree)
        size = chunk_length(n, batch)
        # Explicit shapes: some leaves (MJX's) have zero size, where -1 cannot be inferred.
        grouped = jax.tree.map(lambda x: x.reshape(n // size, size, *x.shape[1:]), tree)
        out = jax.lax.map(jax.vmap(f), grouped)
        return jax.tree.map(lambda y: y.reshape(n, *y.shape[2:]), out)

    return mapped


class Runner:
    """Compiles ``init`` and a chunk of ``update`` for ``seeds`` seeds, then steps chunks.

    Seeds are sharded over the devices; on each device, ``seed_batch`` of them are vmapped
    together (default: :func:`default_seed_batch`). ``step`` returns host numpy metrics
    ``[S, L, ...]``.
    """

    def __init__(
        self,
        init: Callable,
        update: Callable,
        seeds: int,
        chunk: int,
        seed_batch: int | None = None,
    ):
        self.seeds = seeds
        self.chunk = chunk
        self.sharding = seed_sharding(seeds)
        self.seed_batch = seed_batch or default_seed_batch()

        def scan_chunk(state: TrainState):
            return jax.lax.scan(lambda s, _: update(s), state, None, length=chunk)

        # shard_map runs each device's share of the seeds as its own program: seeds never
        # interact, so no cross-device communication is compiled in.
        per_device = lambda f: jax.shard_map(
            map_in_batches(f, self.seed_batch),
            mesh=self.sharding.mesh,
            in_specs=self.sharding.spec,
            out_specs=self.sharding.spec,
            check_vma=False,
        )
        self._init = jax.jit(per_device(init))
        self._chunk = jax.jit(per_device(scan_chunk))
        self._compiled = None
        self.timings = Timings()

    def init(self, key: jax.Array) -> TrainState:
        keys = jax.device_put(jax.random.split(key, self.seeds), self.sharding)
        start = time.perf_counter()
        state = self._init(keys)
        jax.block_until_ready(state)
        self.timings.compile_s += time.perf_counter() - start
        return state

    def abstract_state(self, key: jax.Array):
        """Shapes, dtypes and shardings of :meth:`init`'s state, without computing it (the
        target a checkpoint is restored into)."""
        keys = jax.random.split(key, self.seeds)
        shapes = jax.eval_shape(self._init, keys)
        return jax.tree.map(
            lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=self.sharding), shapes
        )

    def compile(self, state: TrainState) -> None:
        start = time.perf_counter()
        self._compiled = self._chunk.lower(state).compile()
        self.timings.compile_s += time.perf_counter() - start

    def step(self, state: TrainState) -> tuple[TrainState, dict[str, np.ndarray]]:
        """Runs one chunk of iterations; returns the new state and host metrics."""
        if self._compiled is None:
            self.compile(state)
        start = time.perf_counter()
        state, metrics = self._compiled(state)
        metrics = jax.device_get(metrics)
        self.timings.train_s += time.perf_counter() - start
        self.timings.iterations += self.chunk
        return state, metrics


FINAL_WINDOW = 10


def final_metrics(
    history: dict[str, np.ndarray], last: int = FINAL_WINDOW
) -> dict[str, np.ndarray]:
    """Per-seed means over the last ``last`` iterations (single-iteration ERD is noisy)."""
    return {name: np.mean(values[:, -last:], axis=1) for name, values in history.items()}


def concat_history(history: dict | None, metrics: dict[str, np.ndarray]) -> dict:
    if history is None:
        return dict(metrics)
    return {k: np.concatenate([history[k], metrics[k]], axis=1) for k in history}
