"""The refit: the discriminator fitted again against every snapshot's policy."""

import dataclasses
import shutil

import jax
import numpy as np
import pytest

from emgail_jax.host.checkpoints import CheckpointError
from emgail_jax.host.saved_run import SavedRun
from emgail_jax.reward import refit as refitting


@pytest.fixture(scope="module")
def saved(tiny_run):
    return SavedRun.open(str(tiny_run))


def test_samples_come_from_every_snapshot_up_to_the_networks_held(tiny_run, saved):
    key = jax.random.PRNGKey(0)
    obs, executed, terminal = refitting.snapshot_policy_samples(saved, 0, key)
    rollout = saved.config.method.rollout
    k, b, t = 2, rollout.num_envs, rollout.rollout_length
    assert obs.shape == (k, 2 * b * t, saved.problem.env.observation_size)  # snapshots 2 and 4
    assert executed.shape == (k, 2 * b * t, 1) and np.all(np.abs(executed) <= 1)
    # The driver's episodes only ever end at the time limit: no transition terminates.
    assert terminal.shape == (k, 2 * b * t) and not terminal.any()
    # The two snapshots' policies differ, so do their samples.
    assert not np.array_equal(executed[:, : b * t], executed[:, b * t :])
    earlier = SavedRun.open(str(tiny_run), snapshot=2)
    only_first, *_ = refitting.snapshot_policy_samples(earlier, 0, key)
    assert only_first.shape[1] == b * t


def same(a, b) -> bool:
    leaves = zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True)
    return all(np.array_equal(x, y) for x, y in leaves)


def test_the_refit_lowers_the_loss_and_changes_only_the_discriminator(saved):
    refit = refitting.Refit(steps=30)
    parameters, metrics = refitting.consolidated_parameters(saved, 1, refit, jax.random.PRNGKey(0))
    before, after = metrics["before"], metrics["after"]
    assert after["discriminator/loss"] < before["discriminator/loss"]
    assert after["discriminator/policy_d"] < before["discriminator/policy_d"]
    original = saved.reward_parameters(1)
    assert same(parameters["normalizer"], original["normalizer"])
    assert same(parameters["posterior"], original["posterior"])
    assert not same(parameters["discriminator"], original["discriminator"])


def test_a_fresh_refit_starts_from_an_undecided_discriminator(saved):
    key = jax.random.PRNGKey(0)
    refit = lambda **options: refitting.consolidated_parameters(
        saved, 0, refitting.Refit(steps=30, **options), key
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
    plain, plain_metrics = refitting.consolidated_parameters(
        saved, 0, refitting.Refit(steps=5), key
    )
    noisy, noisy_metrics = refitting.consolidated_parameters(
        saved, 0, refitting.Refit(steps=5, support_noise=1.0), key
    )
    # The same starting weights score the demonstrations alike, and the extra negatives apart.
    before = plain_metrics["before"], noisy_metrics["before"]
    assert before[0]["discriminator/expert_d"] == pytest.approx(before[1]["discriminator/expert_d"])
    assert before[0]["discriminator/policy_d"] != before[1]["discriminator/policy_d"]
    assert not same(plain["discriminator"], noisy["discriminator"])


def test_a_run_without_snapshots_is_a_clear_error(tiny_run, tmp_path):

    copy = tmp_path / "run"
    shutil.copytree(tiny_run, copy)
    shutil.rmtree(copy / "snapshots")  # as a run with --snapshot-every 0 leaves it
    with pytest.raises(CheckpointError, match="kept no snapshots"):
        refitting.snapshot_policy_samples(SavedRun.open(str(copy)), 0, jax.random.PRNGKey(0))


def test_a_refit_in_minibatches_draws_from_every_snapshot(saved):
    key = jax.random.PRNGKey(0)
    refit = refitting.Refit(steps=20, fresh=True, support_noise=1.0, batch=7)
    parameters, metrics = refitting.consolidated_parameters(saved, 0, refit, key)
    whole, _ = refitting.consolidated_parameters(saved, 0, dataclasses.replace(refit, batch=0), key)
    assert metrics["after"]["discriminator/loss"] < metrics["before"]["discriminator/loss"]
    assert not same(parameters["discriminator"], whole["discriminator"])


def test_a_ranking_refit_learns_to_order_the_snapshots(saved):
    key = jax.random.PRNGKey(0)
    refit = refitting.Refit(steps=60, fresh=True, ranking=1.0)
    _, metrics = refitting.consolidated_parameters(saved, 0, refit, key)
    before, after = metrics["before"], metrics["after"]
    assert after["ranking/loss"] < before["ranking/loss"]
    assert after["ranking/expert_accuracy"] == 1.0


@pytest.mark.slow  # end to end (make test-slow); cheaper tests cover its parts
def test_random_and_still_actions_are_one_snapshot_of_samples_below_the_ranked_ones(saved):
    obs, executed, _ = refitting.random_action_samples(saved, jax.random.PRNGKey(0))
    rollout = saved.config.method.rollout
    k, m = 2, rollout.num_envs * rollout.rollout_length
    assert obs.shape == (k, m, saved.problem.env.observation_size)
    assert executed.shape == (k, m, saved.problem.env.action_size)
    env = saved.problem.env
    assert (executed >= env.action_low).all() and (executed <= env.action_high).all()
    # Uniform over the box, not a policy's: spread over it.
    assert executed.std() > 0.25 * float(np.max(env.action_high - env.action_low))

    still_obs, still, _ = refitting.still_action_samples(saved, jax.random.PRNGKey(0))
    assert still_obs.shape == obs.shape and still.shape == executed.shape
    np.testing.assert_array_equal(
        still, np.broadcast_to((env.action_low + env.action_high) / 2, still.shape)
    )
    # The episodes start where the random ones do (same key) and then go their own way.
    assert not np.array_equal(still_obs, obs)

    refit = refitting.Refit(
        steps=60, fresh=True, ranking=1.0, ranking_random=True, ranking_still=True
    )
    _, metrics = refitting.consolidated_parameters(saved, 0, refit, jax.random.PRNGKey(0))
    before, after = metrics["before"], metrics["after"]
    assert after["ranking/loss"] < before["ranking/loss"]
    assert after["ranking/expert_accuracy"] == 1.0


def falls_marked(samples, every: int):
    """The snapshots' ``samples`` with every ``every``-th transition marked as ending its
    episode: the driver never falls, so a test marks where a hopper would."""
    obs, executed, terminal = samples
    marked = np.zeros_like(terminal)
    marked[:, ::every] = 1.0
    return obs, executed, marked


def test_an_absorbing_refit_learns_the_falls_absorbing_state_as_fake(saved):
    key = jax.random.PRNGKey(0)
    run = saved.with_absorbing_states().with_reward_form("log-d")
    assert run.networks.discriminator.absorbing and not saved.networks.discriminator.absorbing
    samples = refitting.snapshot_policy_samples(saved, 0, key)
    refit = refitting.Refit(steps=60, fresh=True, absorbing=True)
    falls, metrics = refitting.consolidated_parameters(
        run, 0, refit, key, samples=falls_marked(samples, 4)
    )
    never, _ = refitting.consolidated_parameters(run, 0, refit, key, samples=samples)
    before, after = metrics["before"], metrics["after"]
    assert abs(before["discriminator/absorbing_d"] - 0.5) < 0.1
    assert after["discriminator/absorbing_d"] < 0.25
    # A fall now costs every step left what the absorbing state pays, well below 0 as log D.
    absorbing = jax.jit(run.absorbing_reward_function())
    for intention in range(2):
        paid, unpaid = absorbing(falls, intention), absorbing(never, intention)
        assert paid < np.log(0.25) and paid < unpaid
    # In minibatches the falls come along with their samples.
    drawn = dataclasses.replace(refit, batch=50)
    _, metrics = refitting.consolidated_parameters(
        run, 0, drawn, key, samples=falls_marked(samples, 4)
    )
    assert metrics["after"]["discriminator/absorbing_d"] < 0.25


def test_random_actions_reward_is_the_mean_a_fixed_draw_of_random_actions_earns(saved):
    parameters, reward = saved.reward_parameters(0), saved.reward_function()
    price = refitting.random_actions_reward(saved, parameters, reward)
    assert price.shape == (2,)
    np.testing.assert_array_equal(price, refitting.random_actions_reward(saved, parameters, reward))
    key = jax.random.key(refitting.ABSORBING_PRICE_KEY)
    obs, actions, _ = refitting.random_action_samples(saved, key)
    for intention in range(2):
        paid = reward(parameters, obs[intention], actions[intention], intention)
        assert price[intention] == pytest.approx(float(np.mean(paid)), rel=1e-6)
    # Another seed's reward prices it otherwise.
    other = refitting.random_actions_reward(saved, saved.reward_parameters(1), reward)
    assert not np.array_equal(price, other)
    # The price a check's parameters carry is the absorbing reward, jitted or not.
    carried = {**parameters, "absorbing_price": price}
    for absorbing in (
        refitting.priced_absorbing_reward,
        jax.jit(refitting.priced_absorbing_reward),
    ):
        assert float(absorbing(carried, 1)) == price[1]


def test_an_absorbing_refit_needs_the_network_and_fresh_weights(saved):
    key = jax.random.PRNGKey(0)
    with pytest.raises(ValueError, match="with_absorbing_states"):
        refitting.consolidated_parameters(
            saved, 0, refitting.Refit(steps=2, fresh=True, absorbing=True), key
        )
    assert not saved.trained_with_absorbing_states
    with pytest.raises(ValueError, match="refit it fresh"):
        refitting.consolidated_parameters(
            saved.with_absorbing_states(), 0, refitting.Refit(steps=2, absorbing=True), key
        )


def test_the_steps_run_in_parts_of_one_length_the_last_shorter():
    assert refitting.step_parts(4000, 10) == [(i * 400, 400) for i in range(10)]
    assert refitting.step_parts(3, 10) == [(0, 1), (1, 1), (2, 1)]
    assert refitting.step_parts(23, 10) == [(i * 3, 3) for i in range(7)] + [(21, 2)]
    assert refitting.step_parts(7, 1) == [(0, 7)]


@pytest.mark.parametrize("batch", [0, 7])
def test_a_refit_that_shows_its_progress_is_the_refit_that_does_not(saved, batch):
    """In parts, with the metrics of each part's first step as it goes, to the same bits."""
    key = jax.random.PRNGKey(0)
    refit = refitting.Refit(steps=5, fresh=True, support_noise=1.0, batch=batch)
    shown = []
    parts, metrics = refitting.consolidated_parameters(
        saved, 0, refit, key, on_steps=lambda steps, metrics: shown.append((steps, metrics))
    )
    whole, whole_metrics = refitting.consolidated_parameters(saved, 0, refit, key)
    assert [steps for steps, _ in shown] == [1] * 5
    assert same(parts["discriminator"], whole["discriminator"])
    assert same(metrics, whole_metrics) and same(shown[0][1], whole_metrics["before"])
