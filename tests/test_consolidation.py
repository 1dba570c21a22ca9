"""The consolidated reward: the discriminator refitted against every snapshot's policy."""

import dataclasses
import shutil

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


def same(a, b) -> bool:
    leaves = zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True)
    return all(np.array_equal(x, y) for x, y in leaves)


def test_the_refit_lowers_the_loss_and_changes_only_the_discriminator(saved):
    refit = consolidation.Refit(steps=30)
    parameters, metrics = consolidation.consolidated_parameters(
        saved, 1, refit, jax.random.PRNGKey(0)
    )
    before, after = metrics["before"], metrics["after"]
    assert after["discriminator/loss"] < before["discriminator/loss"]
    assert after["discriminator/policy_d"] < before["discriminator/policy_d"]
    original = saved.reward_parameters(1)
    assert same(parameters["normalizer"], original["normalizer"])
    assert same(parameters["posterior"], original["posterior"])
    assert not same(parameters["discriminator"], original["discriminator"])


def test_a_fresh_refit_starts_from_an_undecided_discriminator(saved):
    key = jax.random.PRNGKey(0)
    refit = lambda **options: consolidation.consolidated_parameters(
        saved, 0, consolidation.Refit(steps=30, **options), key
    )
    from_final, final_metrics = refit()
    from_fresh, fresh_metrics = refit(fresh=True)
    # New weights say about 0.5 everywhere before the refit; the run's final ones do not.
    for side in ("expert_d", "policy_d"):
        assert abs(fresh_metrics["before"][f"discriminator/{side}"] - 0.5) < 0.1
    assert (
        fresh_metrics["before"]["discriminator/loss"]
        != final_metrics["before"]["discriminator/loss"]
    )
    assert (
        fresh_metrics["after"]["discriminator/loss"] < fresh_metrics["before"]["discriminator/loss"]
    )
    assert not same(from_fresh["discriminator"], from_final["discriminator"])


def test_noisy_negatives_change_the_refit_and_not_the_samples(saved):
    key = jax.random.PRNGKey(0)
    plain, plain_metrics = consolidation.consolidated_parameters(
        saved, 0, consolidation.Refit(steps=5), key
    )
    noisy, noisy_metrics = consolidation.consolidated_parameters(
        saved, 0, consolidation.Refit(steps=5, support_noise=1.0), key
    )
    # The same starting weights score the demonstrations alike, and the extra negatives apart.
    before = plain_metrics["before"], noisy_metrics["before"]
    assert before[0]["discriminator/expert_d"] == pytest.approx(before[1]["discriminator/expert_d"])
    assert before[0]["discriminator/policy_d"] != before[1]["discriminator/policy_d"]
    assert not same(plain["discriminator"], noisy["discriminator"])


def test_a_run_without_snapshots_is_a_clear_error(tiny_run, tmp_path):
    from emgail_jax.host.checkpoints import CheckpointError

    copy = tmp_path / "run"
    shutil.copytree(tiny_run, copy)
    shutil.rmtree(copy / "snapshots")  # as a run with --snapshot-every 0 leaves it
    with pytest.raises(CheckpointError, match="kept no snapshots"):
        consolidation.snapshot_policy_samples(SavedRun.open(str(copy)), 0, jax.random.PRNGKey(0))


def test_a_refit_in_minibatches_draws_from_every_snapshot(saved):
    key = jax.random.PRNGKey(0)
    refit = consolidation.Refit(steps=20, fresh=True, support_noise=1.0, batch=7)
    parameters, metrics = consolidation.consolidated_parameters(saved, 0, refit, key)
    whole, _ = consolidation.consolidated_parameters(
        saved, 0, dataclasses.replace(refit, batch=0), key
    )
    assert metrics["after"]["discriminator/loss"] < metrics["before"]["discriminator/loss"]
    assert not same(parameters["discriminator"], whole["discriminator"])
