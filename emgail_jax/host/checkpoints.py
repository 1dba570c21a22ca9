"""Checkpoints of a run: the whole train state of every seed, the metric history, and progress.

Orbax writes each checkpoint to a temporary directory and renames it into place once complete,
so an interrupted save never replaces the last complete checkpoint. A checkpoint holds:

- ``state``: the ``TrainState`` pytree with the seeds as leading axis, as host arrays (the
  caller gathers the seeds from their devices, and places them back after a restore);
- ``history``: every metric so far, ``{name: [S, iterations, ...]}`` (exact, unlike the CSV);
- ``meta``: ``{"iteration": n, "layout": ...}``, the layout a fingerprint of the state's leaves
  (paths, shapes, dtypes), so that a state of another layout (an older version's) is named as
  such before orbax tries to read it.

Orbax refuses zero-size arrays, which MJX states hold (``physics.act`` of a model without
actuator activations, ``mocap_pos`` of one without mocap bodies); they carry no values, so they
are left out of the checkpoint and rebuilt from the restore target's shapes.

In a run of several processes, process 0 alone writes checkpoints; every process reads them
(the run directory is on a file system they share).
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import os
import shutil
import sys
import threading
import types

import jax
import numpy as np
import orbax.checkpoint as ocp


class CheckpointError(ValueError):
    """No usable checkpoint; the message says what is wrong."""


def _is_empty(leaf) -> bool:
    return int(np.prod(leaf.shape)) == 0


def _without_empty(tree):
    """``tree`` with its zero-size leaves replaced by ``None`` (an empty subtree)."""
    return jax.tree.map(lambda leaf: None if _is_empty(leaf) else leaf, tree)


def _with_empty(restored, target):
    """``restored`` (saved by :func:`_without_empty`) with ``target``'s zero-size leaves back."""
    filled = iter(jax.tree.leaves(restored))

    def leaf(template):
        if _is_empty(template):
            return np.zeros(template.shape, template.dtype)
        return np.asarray(next(filled))

    return jax.tree.map(leaf, target)


def layout(state) -> str:
    """A fingerprint of a train state's layout: every leaf's path, shape and dtype."""
    leaves = jax.tree_util.tree_flatten_with_path(state)[0]
    text = "\n".join(
        f"{jax.tree_util.keystr(path)} {tuple(leaf.shape)} {np.dtype(leaf.dtype)}"
        for path, leaf in leaves
    )
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def directory(run_dir: str) -> str:
    return os.path.join(os.path.abspath(run_dir), "checkpoints")


def _manager(run_dir: str, keep: int = 2) -> ocp.CheckpointManager:
    # Each process acts alone: no barrier waits for processes that never call in.
    me = jax.process_index()
    alone = ocp.options.MultiprocessingOptions(primary_host=me, active_processes={me})
    options = ocp.CheckpointManagerOptions(
        max_to_keep=keep,
        enable_async_checkpointing=False,
        create=False,  # save creates the directory (orbax cannot with active_processes)
        multiprocessing_options=(
            alone if jax.process_count() > 1 else ocp.options.MultiprocessingOptions()
        ),
    )
    return ocp.CheckpointManager(directory(run_dir), options=options)


class CheckpointWriteError(OSError):
    """A checkpoint could not be written (full disk, read-only directory); the newest complete
    checkpoint before it is untouched."""


@contextlib.contextmanager
def _quiet_on_failure():
    """Holds back what is written to stderr (file descriptor 2) in the block, and lets it
    through unless the block fails: orbax's threads, when a write fails, print tracebacks by
    the dozen before the error reaches the caller, which says it in one line."""
    read, write = os.pipe()
    saved = os.dup(2)
    held = []
    reader = threading.Thread(target=lambda: held.extend(iter(lambda: os.read(read, 65536), b"")))
    reader.start()
    os.dup2(write, 2)
    os.close(write)
    failed = True
    try:
        yield
        failed = False
    finally:
        os.dup2(saved, 2)  # closes the pipe's last write end: the reader ends
        os.close(saved)
        reader.join()
        os.close(read)
        if not failed:
            os.write(2, b"".join(held))


def save(run_dir: str, iteration: int, state, history: dict[str, np.ndarray]) -> None:
    """Writes the checkpoint of ``iteration`` (keeps the two newest); ``state`` is host arrays.

    Raises:
      CheckpointWriteError: the write failed; its partial files are removed.
    """
    os.makedirs(directory(run_dir), exist_ok=True)
    try:
        with _manager(run_dir) as manager, _quiet_on_failure():
            manager.save(
                iteration,
                args=ocp.args.Composite(
                    state=ocp.args.StandardSave(_without_empty(state)),
                    history=ocp.args.StandardSave(history),
                    meta=ocp.args.JsonSave({"iteration": iteration, "layout": layout(state)}),
                ),
            )
            manager.wait_until_finished()
    except Exception as error:  # orbax raises tensorstore's errors as ValueError, or OSError
        # The temporary directory of the failed write: it would only take space.
        for name in os.listdir(directory(run_dir)):
            if name.startswith(f"{iteration}.orbax-checkpoint-tmp"):
                shutil.rmtree(os.path.join(directory(run_dir), name), ignore_errors=True)
        text = str(error).strip().splitlines()
        raise CheckpointWriteError(
            getattr(error, "errno", None),
            f"the checkpoint of iteration {iteration} could not be written "
            f"({text[0][:200] if text else type(error).__name__})",
            directory(run_dir),
        ) from None


def _restore_state(manager, iteration: int, target_state, same_layout: bool):
    """The checkpoint's state, history and meta. A state written before a field that holds no
    arrays (None: an option off) existed has the same layout but not the same tree: with
    ``same_layout`` known, its leaves are then read by their paths into ``target_state``."""
    every = dict(history=ocp.args.StandardRestore(), meta=ocp.args.JsonRestore())
    try:
        state = ocp.args.StandardRestore(_without_empty(target_state))
        return manager.restore(iteration, args=ocp.args.Composite(state=state, **every))
    except Exception as error:  # orbax's type for a mismatch varies
        if not (same_layout and "tree structures do not match" in str(error)):
            raise
    state = ocp.args.StandardRestore()
    restored = manager.restore(iteration, args=ocp.args.Composite(state=state, **every))
    raw = restored.state

    def at(path, template):
        if _is_empty(template):
            return None
        node = raw
        for entry in path:  # a field, a dict key or a sequence index
            for kind in ("name", "key", "idx"):
                if hasattr(entry, kind):
                    node = node[getattr(entry, kind)]
                    break
        return node

    by_path = jax.tree_util.tree_map_with_path(at, target_state)
    return types.SimpleNamespace(state=by_path, history=restored.history, meta=restored.meta)


def latest_iteration(run_dir: str) -> int | None:
    if not os.path.isdir(directory(run_dir)):
        return None
    with _manager(run_dir) as manager:
        return manager.latest_step()


class _UnawaitedReads(logging.Filter):
    """asyncio's report of each read orbax left unawaited, a task or a bare future, made when
    the read is collected (often as the process exits)."""

    REPORTS = ("Task exception was never retrieved", "Future exception was never retrieved")

    def filter(self, record: logging.LogRecord) -> bool:
        return not record.getMessage().startswith(self.REPORTS)


def _drop_damaged_read_leftovers() -> None:
    """When one read of a damaged checkpoint fails, orbax closes its event loop while its other
    reads still finish on tensorstore's threads, posting to that loop or left unawaited: each
    prints a traceback around the one-line error, before it or as the process exits. From the
    first restore on those alone are dropped; any other error still reaches stderr."""
    previous = sys.unraisablehook
    if getattr(previous, "drops_closed_loop_callbacks", False):
        return

    def hook(unraisable):
        error = unraisable.exc_value
        if not (isinstance(error, RuntimeError) and str(error) == "Event loop is closed"):
            previous(unraisable)

    hook.drops_closed_loop_callbacks = True
    sys.unraisablehook = hook
    logging.getLogger("asyncio").addFilter(_UnawaitedReads())


def restore(run_dir: str, target_state, iteration: int | None = None):
    """Restores ``(state, history, iteration)``, the state as host arrays; ``target_state``
    (arrays or shape-dtype structs) gives its structure.

    Raises:
      CheckpointError: no checkpoint, or one that cannot be read into ``target_state``.
    """
    iteration = latest_iteration(run_dir) if iteration is None else iteration
    if iteration is None:
        raise CheckpointError(f"'{run_dir}' holds no checkpoint to resume or evaluate")
    target_state = jax.tree.map(lambda x: np.zeros(x.shape, x.dtype), target_state)
    another_structure = CheckpointError(
        f"the checkpoint of iteration {iteration} in '{directory(run_dir)}' holds a train "
        f"state of another structure than this version of emgail-jax builds for the run "
        f"(written by another version?); read it with the version that wrote it, or "
        f"train afresh in a new directory"
    )
    _drop_damaged_read_leftovers()
    try:
        with _manager(run_dir) as manager:
            meta = manager.restore(iteration, args=ocp.args.Composite(meta=ocp.args.JsonRestore()))
            if meta["meta"].get("layout", layout(target_state)) != layout(target_state):
                raise another_structure
            restored = _restore_state(manager, iteration, target_state, "layout" in meta["meta"])
    except CheckpointError:
        raise
    except Exception as error:  # orbax raises many types for damaged or foreign files
        message = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        # Checkpoints written without a layout: orbax names the mismatch, or fails while
        # formatting it (its diff report tests array leaves for truth).
        if "tree structures do not match" in message or "truth value of an array" in message:
            raise another_structure from None
        raise CheckpointError(
            f"the checkpoint of iteration {iteration} in '{directory(run_dir)}' cannot be "
            f"read ({message[:200]}); delete it to fall back to an older one"
        ) from None
    history = {name: np.asarray(values) for name, values in restored.history.items()}
    state = _with_empty(restored.state, target_state)
    return state, history, int(restored.meta["iteration"])


# ---- snapshots: what was learned, kept through training -------------------------------------
#
# A checkpoint holds the whole state and only the two newest survive; a snapshot holds what a
# learned reward or policy is made of (every seed's policy, discriminator, posterior,
# observation statistics and mixture weights), a few hundred kB, and every one is kept, so
# that the reward of any point of training can be re-optimised (``reoptimize --snapshot``).

SNAPSHOT_FIELDS = ("policy", "discriminator", "posterior", "normalizer", "intention_weights")


def snapshot_directory(run_dir: str) -> str:
    return os.path.join(os.path.abspath(run_dir), "snapshots")


def _snapshot_path(run_dir: str, iteration: int) -> str:
    return os.path.join(snapshot_directory(run_dir), f"iteration_{iteration:06d}.msgpack")


def snapshot_of(state) -> dict:
    """The learned parts of a train state (every seed), without optimiser states or envs."""
    learned = {name: getattr(state, name) for name in SNAPSHOT_FIELDS}
    learned["discriminator"] = state.discriminator.params
    learned["posterior"] = None if state.posterior is None else state.posterior.params
    return learned


def save_snapshot(run_dir: str, iteration: int, snapshot: dict) -> None:
    """Writes :func:`snapshot_of`'s host arrays for ``iteration``, atomically (renamed into
    place once written)."""
    os.makedirs(snapshot_directory(run_dir), exist_ok=True)
    write_tree(_snapshot_path(run_dir, iteration), snapshot)


def write_tree(path: str, tree) -> None:
    """Writes the pytree ``tree`` (host arrays) to ``path`` as msgpack, renamed into place
    once written."""
    from flax import serialization

    with open(path + ".tmp", "wb") as f:
        f.write(serialization.to_bytes(tree))
    os.replace(path + ".tmp", path)


def read_tree(path: str, target, what: str):
    """The pytree :func:`write_tree` wrote to ``path``, in the structure of ``target``.

    Raises:
      CheckpointError: a file that cannot be read, or does not fit ``target``'s shapes
        (``what`` names the file in the message: "the snapshot", "the reward").
    """
    from flax import serialization

    target = jax.tree.map(np.asarray, target)
    try:
        with open(path, "rb") as f:
            tree = serialization.from_bytes(target, f.read())
    except Exception as error:  # msgpack and flax raise many types for foreign files
        raise CheckpointError(f"{what} '{path}' cannot be read ({error})") from None
    leaves, expected = jax.tree.leaves(tree), jax.tree.leaves(target)
    if len(leaves) != len(expected) or any(
        np.shape(a) != np.shape(b) for a, b in zip(leaves, expected, strict=False)
    ):
        raise CheckpointError(f"{what} '{path}' does not fit this run's networks")
    return tree


def snapshot_iterations(run_dir: str) -> list[int]:
    """The iterations of the snapshots a run kept, in order."""
    if not os.path.isdir(snapshot_directory(run_dir)):
        return []
    names = os.listdir(snapshot_directory(run_dir))
    return sorted(
        int(name[len("iteration_") : -len(".msgpack")])
        for name in names
        if name.startswith("iteration_") and name.endswith(".msgpack")
    )


def restore_snapshot(run_dir: str, iteration: int, state):
    """``state`` (every seed's, host arrays) with its learned parts replaced by the snapshot of
    ``iteration``; the optimiser states and envs stay ``state``'s.

    Raises:
      CheckpointError: no snapshot of that iteration, or one that does not fit ``state``.
    """
    path = _snapshot_path(run_dir, iteration)
    if not os.path.exists(path):
        kept = snapshot_iterations(run_dir)
        listed = ", ".join(map(str, kept)) if kept else "none"
        raise CheckpointError(
            f"'{run_dir}' holds no snapshot of iteration {iteration} (snapshots kept: {listed})"
        )
    learned = read_tree(path, snapshot_of(state), "the snapshot")
    replaced = dict(learned)
    replaced["discriminator"] = state.discriminator.replace(params=learned["discriminator"])
    if state.posterior is not None:
        replaced["posterior"] = state.posterior.replace(params=learned["posterior"])
    return state.replace(**replaced)
