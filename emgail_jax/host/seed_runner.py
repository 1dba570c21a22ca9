"""Runs the update step for many seeds: ``jit(vmap(scan(update)))``, sharded over devices.

Seeds are the leading axis of every leaf of the train state. They are sharded over as many
devices as divide the seed count (XLA:CPU runs one core per device), each device vmapping its
share. Iterations are scanned in chunks of ``chunk_size`` inside one compiled call; the host
only acts between chunks (logs, progress, checkpoints).
"""

from __future__ import annotations

import collections
import dataclasses
import time
from collections.abc import Callable, Hashable

import jax
import numpy as np
from jax.experimental import multihost_utils
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from emgail_jax.host import jax_setup, program_cache
from emgail_jax.host.run_spec import RunError
from emgail_jax.method import rl
from emgail_jax.method.training import TrainState


@dataclasses.dataclass
class Timings:
    compile_s: float = 0.0
    train_s: float = 0.0
    iterations: int = 0


def chunk_length(iterations: int, chunk_size: int) -> int:
    """The largest chunk <= ``chunk_size`` that divides ``iterations`` (one compile only)."""
    return max(d for d in range(1, min(chunk_size, iterations) + 1) if iterations % d == 0)


def seed_sharding(seeds: int) -> NamedSharding:
    """The seeds sharded over as many devices as divide them, the same number of each process
    (every process of a multi-process run trains a share, whatever devices it has).

    Raises:
      RunError: the processes cannot share the seeds equally (checked before anything
        compiles, with the same outcome in every process).
    """
    processes = jax.process_count()
    if error := jax_setup.seed_share_error(seeds, processes):
        raise RunError(error)
    per_process = max(
        d for d in range(1, jax.local_device_count() + 1) if (seeds // processes) % d == 0
    )
    by_process = collections.defaultdict(list)
    for device in jax.devices():
        by_process[device.process_index].append(device)
    devices = [d for index in sorted(by_process) for d in by_process[index][:per_process]]
    return NamedSharding(Mesh(np.asarray(devices), ("seed",)), PartitionSpec("seed"))


def default_seed_batch() -> int | None:
    """Seeds vmapped together on one device: one on CPU, all of a device's on accelerators.

    XLA:CPU runs a device's program on one core, so vmapping seeds there batches nothing and
    is slower (docs/speed.md, "On a CPU").
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
    """Compiles ``init`` and chunks of ``update`` for ``seeds`` seeds, then steps chunks.

    ``init(key, data)`` builds one seed's state; ``update(state, x, data) -> (state, metrics)``
    takes, besides one seed's state, one element ``x`` of a per-iteration input that every seed
    shares (e.g. whether to evaluate) and the run's ``data`` (a pytree of arrays, e.g. the
    demonstrations). Neither is batched over seeds: a ``lax.cond`` on ``x`` really skips the
    branch not taken, and ``data`` is an argument of the compiled program, not constants in it,
    so runs that differ only in their data share one program. Seeds are sharded over the
    devices; on each device, ``seed_batch`` of them are vmapped together (default:
    :func:`default_seed_batch`). ``step`` returns host numpy metrics ``[S, L, ...]``; a program
    is compiled for every chunk length used (a run uses at most two: its chunk and a remainder).

    Runners given the same ``program_key`` (which must then identify ``init`` and ``update`` up
    to their data, e.g. the config and the env without its data) and the same seeds and data
    shapes share their compiled programs within a process: a second driver radius neither
    traces nor compiles again (:data:`~emgail_jax.host.program_cache.SHARED`).
    """

    def __init__(
        self,
        init: Callable,
        update: Callable,
        seeds: int,
        data=None,
        *,
        seed_batch: int | None = None,
        program_key: Hashable | None = None,
    ):
        self.seeds = seeds
        self.sharding = seed_sharding(seeds)
        self.seed_batch = seed_batch or default_seed_batch()
        mesh = self.sharding.mesh
        # One copy of the data on every device, placed before the first call: a program fed
        # from another device's memory deadlocks XLA:CPU when seeds are sharded over devices.
        self.data = place(data, NamedSharding(mesh, PartitionSpec()))
        self.timings = Timings()

        def build() -> _Programs:
            return _Programs.build(init, update, self.sharding, self.seed_batch)

        if program_key is None:
            self._programs = build()
        else:
            leaves, structure = jax.tree.flatten(self.data)
            shapes = tuple((x.shape, str(x.dtype)) for x in leaves)
            key = (program_key, seeds, self.seed_batch, mesh, structure, shapes)
            self._programs = program_cache.SHARED.get(key, build)

    def init(self, key: jax.Array) -> TrainState:
        """Every seed's initial state, seed s from the s-th key of ``split(key, seeds)``."""
        keys = place(np.asarray(jax.random.split(key, self.seeds)), self.sharding)
        start = time.perf_counter()
        state = self._programs.init(keys, self.data)
        jax.block_until_ready(state)
        self.timings.compile_s += time.perf_counter() - start
        return state

    def abstract_state(self, key: jax.Array):
        """Shapes, dtypes and shardings of :meth:`init`'s state, without computing it (the
        target a checkpoint is restored into)."""
        keys = jax.random.split(key, self.seeds)
        shapes = jax.eval_shape(self._programs.init, keys, self.data)
        return jax.tree.map(
            lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=self._sharding_of(x)),
            shapes,
        )

    def _sharding_of(self, leaf) -> NamedSharding:
        """Where a leaf of the state lives, as the compiled programs leave it: sharded by seed,
        except leaves of size zero (MJX's empty fields), which they return replicated."""
        if np.prod(np.shape(leaf)):
            return self.sharding
        return NamedSharding(self.sharding.mesh, PartitionSpec())

    def _replicated(self, inputs) -> jax.Array:
        return place(np.asarray(inputs), NamedSharding(self.sharding.mesh, PartitionSpec()))

    def place_state(self, host_state) -> TrainState:
        """A state of host arrays (a restored checkpoint) on the seeds' devices, placed as
        :meth:`init` and :meth:`step` leave it (any other placement makes the chunk program
        compiled for it reject the state it returns)."""
        return jax.tree.map(lambda x: place(x, self._sharding_of(x)), host_state)

    def compile(self, state: TrainState, inputs) -> None:
        """Compiles the chunk program for ``len(inputs)`` iterations (once per length)."""
        length = len(inputs)
        if length in self._programs.compiled:
            return
        start = time.perf_counter()
        lowered = self._programs.chunk.lower(state, self._replicated(inputs), self.data)
        self._programs.compiled[length] = lowered.compile()
        self.timings.compile_s += time.perf_counter() - start

    @property
    def programs(self) -> int:
        """How many chunk programs were compiled."""
        return len(self._programs.compiled)

    def step(self, state: TrainState, inputs) -> tuple[TrainState, dict[str, np.ndarray]]:
        """Runs ``len(inputs)`` iterations, iteration ``l`` with ``inputs[l]``; returns the new
        state and host metrics."""
        self.compile(state, inputs)
        start = time.perf_counter()
        compiled = self._programs.compiled[len(inputs)]
        state, metrics = compiled(state, self._replicated(inputs), self.data)
        metrics = gather(metrics)
        self.timings.train_s += time.perf_counter() - start
        self.timings.iterations += len(inputs)
        return state, metrics

    def run(
        self,
        state: TrainState,
        plan: list[tuple[int, int]],
        inputs_of: Callable[[int, int], np.ndarray],
        after_chunk: Callable[[int, int, TrainState, dict], bool],
    ) -> TrainState:
        """The chunk loop: steps ``state`` through ``plan`` (``(first, length)`` pairs, see
        :func:`chunks`), chunk ``(first, length)`` with the inputs ``inputs_of(first, length)``.
        ``after_chunk(first, length, state, metrics)`` acts on each chunk's result on the host
        (logs, progress, checkpoints) and returns False to stop. Returns the last state."""
        return run_chunks(self.step, state, plan, inputs_of, after_chunk)


def intention_runner(trainer: rl.RLTrainer, intentions: jax.Array, seeds: int) -> Runner:
    """A :class:`Runner` of ``seeds`` seeds, each training one policy per
    entry of ``intentions [I]`` (vmapped; policy i on intention ``intentions[i]``), from the
    ``I`` keys its seed key splits into. The runner's per-iteration input is unused."""
    k = len(intentions)
    init = lambda seed_key, _: jax.vmap(trainer.init)(jax.random.split(seed_key, k))
    update = lambda states, _, __: jax.vmap(trainer.update)(states, intentions)
    return Runner(init, update, seeds)


def run_chunks(step: Callable, state, plan, inputs_of: Callable, after_chunk: Callable):
    """The chunk loop of :meth:`Runner.run` for any ``step(state, inputs) -> (state, metrics)``
    (e.g. a program that is not sharded over seeds)."""
    for first, length in plan:
        state, metrics = step(state, inputs_of(first, length))
        if not after_chunk(first, length, state, metrics):
            break
    return state


@dataclasses.dataclass
class _Programs:
    """The jitted init and chunk functions of a :class:`Runner`, and its chunk programs
    compiled per chunk length."""

    init: Callable
    chunk: Callable
    compiled: dict[int, Callable]

    @classmethod
    def build(cls, init, update, sharding: NamedSharding, seed_batch: int | None) -> _Programs:
        mesh, spec, replicated = sharding.mesh, sharding.spec, PartitionSpec()

        def init_seeds(keys, data):
            return map_in_batches(lambda key: init(key, data), seed_batch)(keys)

        def scan_chunk(state: TrainState, inputs: jax.Array, data):
            per_seed = lambda s: jax.lax.scan(lambda s, x: update(s, x, data), s, inputs)
            return map_in_batches(per_seed, seed_batch)(state)

        # shard_map runs each device's share of the seeds as its own program: seeds never
        # interact, so no cross-device communication is compiled in.
        def sharded(f, in_specs):
            return jax.jit(
                jax.shard_map(f, mesh=mesh, in_specs=in_specs, out_specs=spec, check_vma=False)
            )

        return cls(
            init=sharded(init_seeds, (spec, replicated)),
            chunk=sharded(scan_chunk, (spec, replicated, replicated)),
            compiled={},
        )


def place(tree, sharding: NamedSharding):
    """Host arrays onto ``sharding``'s devices, also when some of them belong to other processes
    of a multi-process run (each process places its own devices' shares; every process passes
    the same values)."""

    def put(x):
        x = np.asarray(x)
        return jax.make_array_from_callback(x.shape, sharding, lambda index: x[index])

    return jax.tree.map(put, tree)


def gather(tree):
    """Device arrays back to host numpy arrays, whole, in every process of a run (a
    multi-process run gathers the other processes' shares)."""
    if jax.process_count() == 1:
        return jax.device_get(tree)
    return jax.tree.map(np.asarray, multihost_utils.process_allgather(tree, tiled=True))


def chunks(done: int, total: int, chunk_size: int) -> list[tuple[int, int]]:
    """``(first, length)`` of the chunks from iteration ``done`` to ``total``: full chunks of
    ``chunk_size`` and one shorter remainder, so at most two programs are compiled."""
    starts = range(done, total, chunk_size)
    return [(first, min(chunk_size, total - first)) for first in starts]
