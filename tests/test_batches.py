"""The data handed between the steps of an update: the demonstrations and the normalised batch."""

import jax
import numpy as np
import pytest

from emgail_jax.method.batches import DemonstrationPairs
from emgail_jax.method.demonstrations import Demonstrations


def test_a_consistent_batch_passes_its_shape_check(random_batch):
    batch = random_batch()
    assert batch.check() is batch


@pytest.mark.parametrize(
    "broken",
    [
        lambda b: b.replace(executed=b.executed[:, :3]),  # fewer actions than samples
        lambda b: b.replace(expert_actions=b.expert_actions[:5]),  # fewer than the pairs
        lambda b: b.replace(expert_obs=b.expert_obs[:, :1]),  # another observation size
        lambda b: b.replace(obs=b.obs[0]),  # not grouped by intention
    ],
)
def test_a_batch_with_mismatched_shapes_is_refused(broken, random_batch):
    with pytest.raises(AssertionError):
        broken(random_batch()).check()


def test_demonstration_pairs_numbers_the_demonstrations_and_keeps_the_labels():
    starts = np.array([1, 0, 0, 1, 0, 1], bool)
    demos = Demonstrations(
        observations=np.zeros((6, 2)),
        actions=np.zeros((6, 1)),
        episode_starts=starts,
        intentions=np.array([0, 0, 0, 1, 1, 1]),
    )
    expert = DemonstrationPairs.create(demos, np.array([-5.0, -6.0]), 2)
    np.testing.assert_array_equal(expert.episode, [0, 0, 0, 1, 1, 2])
    assert expert.episodes == 3 and expert.has_labels
    assert np.isnan(expert.expert_returns).all() and expert.random_returns.dtype == np.float32


@pytest.mark.parametrize("jit", [False, True])
def test_a_demonstration_shorter_than_an_episode_ends_in_a_termination(jit):
    """Demonstrations of 3, 2 and 1 pairs in episodes of 3 steps: the last pair of the second
    and of the third ended its episode before the time limit; the first ran to it."""
    demos = Demonstrations(
        observations=np.zeros((6, 2)),
        actions=np.zeros((6, 1)),
        episode_starts=np.array([1, 0, 0, 1, 0, 1], bool),
    )
    pairs = DemonstrationPairs.create(demos, np.zeros(1), 1)
    ends = jax.jit(lambda p: p.terminations(3)) if jit else (lambda p: p.terminations(3))
    np.testing.assert_array_equal(ends(pairs), [0, 0, 0, 0, 1, 1])
    np.testing.assert_array_equal(pairs.terminations(2), [0, 0, 0, 0, 0, 1])


@pytest.mark.parametrize("jit", [False, True])
def test_more_samples_follow_the_batchs_own_under_each_intention(random_batch, jit):
    """Further negatives go after the batch's own in each intention's row; the demonstrations
    are untouched."""
    batch = random_batch(k=3, m=4, n=6, obs_dim=2)
    more_obs, more_executed = np.full((3, 2, 2), 7.0), np.full((3, 2, 1), 8.0)
    append = lambda b: b.with_more_samples(more_obs, more_executed)
    out = (jax.jit(append) if jit else append)(batch)
    assert out.check() is out and out.obs.shape == (3, 6, 2) and out.extra is None
    np.testing.assert_array_equal(out.obs[:, :4], batch.obs)
    np.testing.assert_array_equal(out.obs[:, 4:], more_obs)
    np.testing.assert_array_equal(out.executed[:, 4:], more_executed)
    np.testing.assert_array_equal(out.expert_obs, batch.expert_obs)
