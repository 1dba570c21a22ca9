"""The M-step's support negatives: a noisy copy of every negative, under its own intention."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from emgail_jax.method.batches import NormalizedBatch
from emgail_jax.method.normalizer import RunningStats
from emgail_jax.variants.extras import attached
from emgail_jax.variants.support import with_support_negatives

K, M, D, A = 2, 2000, 3, 2


def _negatives(absorbing=False) -> NormalizedBatch:
    rows = jnp.arange(K, dtype=jnp.float32)[:, None, None]  # row k's samples all at k
    batch = NormalizedBatch(
        normalizer=RunningStats.create(D),
        obs=jnp.broadcast_to(rows, (K, M, D)),
        executed=jnp.broadcast_to(-rows, (K, M, A)),
        expert_obs=jnp.zeros((3, D)),
        expert_actions=jnp.zeros((3, A)),
    )
    if absorbing:
        batch = attached(batch, terminal=jnp.ones((K, M)), expert_terminal=jnp.zeros(3))
    return batch


@pytest.mark.parametrize("jit", [False, True])
def test_each_negative_gets_a_copy_moved_by_noise_of_the_scale(jit):
    negatives = _negatives()
    add = lambda batch, key: with_support_negatives(batch, key, 0.5)
    out = (jax.jit(add) if jit else add)(negatives, jax.random.PRNGKey(0))
    assert out.obs.shape == (K, 2 * M, D) and out.executed.shape == (K, 2 * M, A)
    np.testing.assert_array_equal(out.obs[:, :M], negatives.obs)  # its own kept first
    np.testing.assert_array_equal(out.executed[:, :M], negatives.executed)
    for k in range(K):  # each copy stays in its intention's row, about its sample
        moved_obs, moved_action = out.obs[k, M:] - k, out.executed[k, M:] + k
        for moved in (moved_obs, moved_action):
            assert abs(float(moved.mean())) < 0.02
            assert float(moved.std()) == pytest.approx(0.5, rel=0.03)
    assert not np.allclose(moved_obs[:, :A], moved_action)  # independent draws
    np.testing.assert_array_equal(out.expert_obs, negatives.expert_obs)
    assert out.extra is None


def test_a_copy_never_terminates():
    out = with_support_negatives(_negatives(absorbing=True), jax.random.PRNGKey(1), 1.0)
    np.testing.assert_array_equal(out.extra.terminal[:, :M], 1.0)
    np.testing.assert_array_equal(out.extra.terminal[:, M:], 0.0)


def test_airl_successors_are_refused():
    negatives = attached(
        _negatives(), successor=jnp.zeros((K, M, D + 1)), expert_successor=jnp.zeros((3, D + 1))
    )
    with pytest.raises(ValueError, match="AIRL"):
        with_support_negatives(negatives, jax.random.PRNGKey(0), 1.0)
