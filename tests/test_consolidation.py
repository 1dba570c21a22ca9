"""The consolidated reward: the discriminator refitted against every snapshot's policy."""

import jax
import numpy as np
import pytest

from emgail_jax.host import consolidation
from emgail_jax.host.saved_run import SavedRun


@pytest.fixture(scope="module")
def saved(tiny_run):
    return SavedRun.open(str(tiny_run))


def test_samples_come_from_every_snapshot_up_to_the_networks_held(tiny_run, saved):
    key = jax.random.PRNGKey(0)
    obs, executed = consolidation.snapshot_policy_samples(saved, 0, key)
    rollout = saved.config.method.rollout
    k, b, t = 2, rollout.num_envs, rollout.rollout_length
    assert obs.shape == (k, 2 * b * t, saved.problem.env.observation_size)  # snapshots 2 and 4
    assert executed.shape == (k, 2 * b * t, 1) and np.all(np.abs(executed) <= 1)
    # The two snapshots' policies differ, so do their samples.
    assert not np.array_equal(executed[:, : b * t], executed[:, b * t :])
    earlier = SavedRun.open(str(tiny_run), snapshot=2)
    only_first, _ = consolidation.snapshot_policy_samples(earlier, 0, key)
    assert only_first.shape[1] == b * t


def test_the_refit_lowers_the_loss_and_changes_only_the_discriminator(saved):
    parameters, metrics = consolidation.consolidated_parameters(saved, 1, 30, jax.random.PRNGKey(0))
    before, after = metrics["before"], metrics["after"]
    assert after["discriminator/loss"] < before["discriminator/loss"]
    assert after["discriminator/policy_d"] < before["discriminator/policy_d"]
    original = saved.reward_parameters(1)
    same = lambda a, b: all(
        np.array_equal(x, y) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True)
    )
    assert same(parameters["normalizer"], original["normalizer"])
    assert same(parameters["posterior"], original["posterior"])
    assert not same(parameters["discriminator"], original["discriminator"])


def test_a_run_without_snapshots_is_a_clear_error(saved, monkeypatch):
    from emgail_jax.host.checkpoints import CheckpointError

    monkeypatch.setattr(consolidation.checkpoints, "snapshot_iterations", lambda run_dir: [])
    with pytest.raises(CheckpointError, match="kept no snapshots"):
        consolidation.snapshot_policy_samples(saved, 0, jax.random.PRNGKey(0))
