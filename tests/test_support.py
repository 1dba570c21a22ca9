"""The M-step's support negatives: a noisy copy of every negative, under its own intention."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from emgail_jax.method.batches import NormalizedBatch
from emgail_jax.method.normalizer import RunningStats
from emgail_jax.method.support import InputBox, with_support_negatives

K, M, D, A = 2, 2000, 3, 2


def _negatives(absorbing=False) -> NormalizedBatch:
    rows = jnp.arange(K, dtype=jnp.float32)[:, None, None]  # row k's samples all at k
    return NormalizedBatch(
        normalizer=RunningStats.create(D),
        obs=jnp.broadcast_to(rows, (K, M, D)),
        executed=jnp.broadcast_to(-rows, (K, M, A)),
        expert_obs=jnp.zeros((3, D)),
        expert_actions=jnp.zeros((3, A)),
        terminal=jnp.ones((K, M)) if absorbing else None,
        expert_terminal=jnp.zeros(3) if absorbing else None,
    )


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
    assert out.terminal is None


@pytest.mark.parametrize("jit", [False, True])
def test_in_the_box_a_copy_that_would_leave_it_lands_on_its_face(jit):
    """Clipped as real inputs are: the noise that leaves the box prices its faces, and the
    samples themselves are untouched."""
    negatives = _negatives()
    box = InputBox(obs_clip=1.5, action_low=-0.5, action_high=0.25)
    add = lambda batch, key: with_support_negatives(batch, key, 2.0, box)
    out = (jax.jit(add) if jit else add)(negatives, jax.random.PRNGKey(0))
    np.testing.assert_array_equal(out.obs[:, :M], negatives.obs)
    np.testing.assert_array_equal(out.executed[:, :M], negatives.executed)  # -1 stays
    obs, executed = np.asarray(out.obs[:, M:]), np.asarray(out.executed[:, M:])
    assert obs.min() == -1.5 and obs.max() == 1.5
    assert executed.min() == -0.5 and executed.max() == 0.25
    # Row 1's samples sit at 1, so about 40 % of its copies (N(1, 4) above 1.5) are on the top
    # face; inside it they are the unclipped copies.
    on_face = np.mean(obs[1] == 1.5)
    assert 0.35 < on_face < 0.45
    free = with_support_negatives(negatives, jax.random.PRNGKey(0), 2.0)
    inside = np.abs(np.asarray(free.obs[:, M:])) < 1.5
    np.testing.assert_array_equal(obs[inside], np.asarray(free.obs[:, M:])[inside])


def test_a_copy_never_terminates():
    out = with_support_negatives(_negatives(absorbing=True), jax.random.PRNGKey(1), 1.0)
    np.testing.assert_array_equal(out.terminal[:, :M], 1.0)
    np.testing.assert_array_equal(out.terminal[:, M:], 0.0)


def test_airl_successors_are_refused():
    negatives = _negatives().replace(
        successor=jnp.zeros((K, M, D + 1)), expert_successor=jnp.zeros((3, D + 1))
    )
    with pytest.raises(ValueError, match="AIRL"):
        with_support_negatives(negatives, jax.random.PRNGKey(0), 1.0)
