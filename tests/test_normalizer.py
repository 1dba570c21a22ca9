"""Running observation statistics (Chan et al.'s parallel merge) and the clipped normaliser."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from emgail_jax.method import normalizer


def test_create_is_identity_before_any_data():
    stats = normalizer.RunningStats.create(3)
    assert stats.mean.shape == stats.var.shape == (3,)
    assert float(stats.count) == 0.0
    x = jnp.array([0.5, -1.0, 2.0])
    np.testing.assert_allclose(normalizer.normalize(stats, x), x, rtol=1e-6)


def test_single_update_hand_computed():
    # Two observations of a 2-D quantity: mean (2, 10), population variance (1, 0).
    batch = jnp.array([[1.0, 10.0], [3.0, 10.0]])
    stats = normalizer.update(normalizer.RunningStats.create(2), batch)
    np.testing.assert_allclose(stats.mean, [2.0, 10.0])
    np.testing.assert_allclose(stats.var, [1.0, 0.0])
    assert float(stats.count) == 2.0


@pytest.mark.parametrize("sizes", [(7, 3, 11, 1), (1, 1, 1), (50, 5)])
def test_running_stats_equal_numpy_over_concatenated_batches(sizes):
    rng = np.random.default_rng(0)
    batches = [
        rng.normal(loc=[3.0, -2.0, 0.0, 100.0], scale=[1.0, 0.1, 5.0, 20.0], size=(n, 4))
        for n in sizes
    ]
    stats = normalizer.RunningStats.create(4)
    for i, batch in enumerate(batches):
        stats = normalizer.update(stats, jnp.asarray(batch, jnp.float32))
        seen = np.concatenate(batches[: i + 1])
        np.testing.assert_allclose(stats.mean, seen.mean(0), rtol=1e-5, atol=1e-4)
        np.testing.assert_allclose(stats.var, seen.var(0), rtol=1e-4, atol=1e-5)
        assert float(stats.count) == len(seen)


def test_update_flattens_leading_batch_dims():
    rng = np.random.default_rng(1)
    data = rng.normal(size=(5, 2, 3, 6)).astype(np.float32)  # e.g. [T, K, B, D]
    stats = normalizer.update(normalizer.RunningStats.create(6), jnp.asarray(data))
    flat = data.reshape(-1, 6)
    np.testing.assert_allclose(stats.mean, flat.mean(0), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(stats.var, flat.var(0), rtol=1e-4, atol=1e-6)
    assert float(stats.count) == 30.0


def test_normalize_shapes_and_values_with_leading_dims():
    stats = normalizer.RunningStats(
        mean=jnp.array([1.0, -2.0]), var=jnp.array([4.0, 0.25]), count=jnp.array(10.0)
    )
    x = jnp.array([[[3.0, -2.5]], [[1.0, -1.0]]])  # [2, 1, 2]
    out = normalizer.normalize(stats, x)
    assert out.shape == (2, 1, 2)
    # (3 - 1) / 2 = 1, (-2.5 + 2) / 0.5 = -1, (1 - 1) / 2 = 0, (-1 + 2) / 0.5 = 2.
    np.testing.assert_allclose(out, [[[1.0, -1.0]], [[0.0, 2.0]]], rtol=1e-6, atol=1e-6)


def test_normalize_clips_at_five():
    stats = normalizer.RunningStats(mean=jnp.zeros(3), var=jnp.ones(3), count=jnp.array(1.0))
    out = normalizer.normalize(stats, jnp.array([100.0, -7.0, 4.9]))
    np.testing.assert_allclose(out, [5.0, -5.0, 4.9], rtol=1e-6)
    out = normalizer.normalize(stats, jnp.array([3.0, -3.0, 0.0]), clip=2.0)
    np.testing.assert_allclose(out, [2.0, -2.0, 0.0])


def test_constant_dimension_stays_finite():
    stats = normalizer.update(normalizer.RunningStats.create(2), jnp.ones((8, 2)))
    out = normalizer.normalize(stats, jnp.array([[1.0, 2.0]]))
    assert np.all(np.isfinite(out))
    np.testing.assert_allclose(out, [[0.0, 5.0]])


def test_update_and_normalize_jit_match_eager():
    rng = np.random.default_rng(2)
    batch = jnp.asarray(rng.normal(size=(4, 3, 5)), jnp.float32)
    stats = normalizer.update(normalizer.RunningStats.create(5), batch[:2])
    eager = normalizer.normalize(normalizer.update(stats, batch), batch)
    jitted = jax.jit(lambda s, b: normalizer.normalize(normalizer.update(s, b), b))(stats, batch)
    np.testing.assert_allclose(eager, jitted, rtol=1e-6, atol=1e-6)
