"""Checkpoints: a round trip of a state with zero-size arrays (as MJX states have) through the
host, and the errors for a run without checkpoints or with foreign ones."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct
from jax.sharding import NamedSharding, PartitionSpec

from emgail_jax.host import checkpoints


def _state():
    mesh = jax.make_mesh((jax.device_count(),), ("seeds",))
    sharding = NamedSharding(mesh, PartitionSpec("seeds"))
    seeds = 2 * jax.device_count()
    state = {
        "params": jnp.arange(seeds * 3, dtype=jnp.float32).reshape(seeds, 3),
        "physics": {"act": jnp.zeros((seeds, 0)), "qpos": jnp.ones((seeds, 5), jnp.float32)},
        "step": jnp.arange(seeds, dtype=jnp.int32),
    }
    return jax.device_put(state, sharding), sharding


def test_round_trip_keeps_zero_size_arrays(tmp_path):
    """Saved from the host (the runner gathers a sharded state first), restored to the host
    (the runner places it back on its devices)."""
    state, sharding = _state()
    history = {"erd": np.linspace(0, 1, 8).reshape(2, 4)}
    checkpoints.save(str(tmp_path), 4, jax.device_get(state), history)
    abstract = lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=sharding)
    target = jax.tree.map(abstract, state)
    restored, restored_history, iteration = checkpoints.restore(str(tmp_path), target)
    assert iteration == 4
    assert jax.tree.structure(restored) == jax.tree.structure(state)
    for saved, loaded in zip(jax.tree.leaves(state), jax.tree.leaves(restored), strict=True):
        assert loaded.shape == saved.shape and loaded.dtype == saved.dtype
        assert isinstance(loaded, np.ndarray)
        np.testing.assert_array_equal(loaded, saved)
    np.testing.assert_array_equal(restored_history["erd"], history["erd"])


def test_a_run_without_checkpoints_is_a_clear_error(tmp_path):
    state, _ = _state()
    with pytest.raises(checkpoints.CheckpointError, match="holds no checkpoint"):
        checkpoints.restore(str(tmp_path), state)


def test_a_checkpoint_of_another_structure_is_a_clear_error_and_stays(tmp_path):
    """A train state laid out differently (an older version's) is named as such, and the
    checkpoint is left as it was: no advice to delete it."""
    state, _ = _state()
    checkpoints.save(str(tmp_path), 4, jax.device_get(state), {"erd": np.zeros((2, 4))})
    before = sorted(p.name for p in (tmp_path / "checkpoints").iterdir())
    regrouped = {"learner": {"params": state["params"]}, "physics": state["physics"]}
    with pytest.raises(checkpoints.CheckpointError, match="another structure") as error:
        checkpoints.restore(str(tmp_path), regrouped)
    assert "delete" not in str(error.value) and "\n" not in str(error.value)
    assert sorted(p.name for p in (tmp_path / "checkpoints").iterdir()) == before
    assert checkpoints.restore(str(tmp_path), state)[2] == 4
    grown = {**state, "weights": np.zeros(3, np.float32)}  # a field a newer version added
    with pytest.raises(checkpoints.CheckpointError, match="another structure"):
        checkpoints.restore(str(tmp_path), grown)
    resized = {**state, "params": np.zeros((3, 5), np.float32)}
    with pytest.raises(checkpoints.CheckpointError, match="another structure"):
        checkpoints.restore(str(tmp_path), resized)


@struct.dataclass
class _Before:
    params: jax.Array
    physics: dict
    step: jax.Array


@struct.dataclass
class _After(_Before):
    added: dict | None = None  # a field a newer version added, None when its option is off


def test_a_state_written_before_an_empty_field_existed_restores_into_it(tmp_path):
    """A field holding no arrays (None) changes the tree but not the layout: a checkpoint
    written without it restores, every leaf by its path (as runs from before re-seeding do)."""
    state, _ = _state()
    checkpoints.save(str(tmp_path), 4, jax.device_get(_Before(**state)), {"erd": np.zeros(2)})
    restored, _, iteration = checkpoints.restore(str(tmp_path), _After(**state))
    assert iteration == 4 and isinstance(restored, _After) and restored.added is None
    for saved, loaded in zip(jax.tree.leaves(state), jax.tree.leaves(restored), strict=True):
        assert loaded.shape == saved.shape and loaded.dtype == saved.dtype
        np.testing.assert_array_equal(loaded, saved)
    with pytest.raises(checkpoints.CheckpointError, match="another structure"):
        grown = _After(**state, added={"weights": np.zeros(3, np.float32)})
        checkpoints.restore(str(tmp_path), grown)


def test_a_damaged_checkpoints_leftover_reads_alone_are_dropped(monkeypatch, caplog):
    """Orbax's reads still under way when one fails post to its closed event loop, or are left
    unawaited: those reports are dropped (they would print a traceback each around the one-line
    error), every other error still reaches stderr, and a second restore adds no filter."""
    import logging
    import sys
    import types

    seen = []
    monkeypatch.setattr(sys, "unraisablehook", seen.append)
    asyncio_log = logging.getLogger("asyncio")
    monkeypatch.setattr(asyncio_log, "filters", [])
    checkpoints._drop_damaged_read_leftovers()
    checkpoints._drop_damaged_read_leftovers()
    closed = types.SimpleNamespace(exc_value=RuntimeError("Event loop is closed"))
    other = types.SimpleNamespace(exc_value=ValueError("Event loop is closed"))
    sys.unraisablehook(closed)
    sys.unraisablehook(other)
    assert seen == [other]
    assert len(asyncio_log.filters) == 1
    with caplog.at_level(logging.ERROR, logger="asyncio"):
        asyncio_log.error("Task exception was never retrieved\nfuture: <Task finished>")
        asyncio_log.error("Future exception was never retrieved\nfuture: <Future finished>")
        asyncio_log.error("Unclosed client session")
    assert [r.getMessage() for r in caplog.records] == ["Unclosed client session"]
