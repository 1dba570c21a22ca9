"""The consolidated reward: the discriminator refitted against every snapshot's policy."""

import dataclasses
import shutil

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from emgail_jax.host import consolidation
from emgail_jax.host.checkpoints import CheckpointError
from emgail_jax.host.saved_run import SavedRun


@pytest.fixture(scope="module")
def saved(tiny_run):
    return SavedRun.open(str(tiny_run))


def test_samples_come_from_every_snapshot_up_to_the_networks_held(tiny_run, saved):
    key = jax.random.PRNGKey(0)
    obs, executed, terminal = consolidation.snapshot_policy_samples(saved, 0, key)
    rollout = saved.config.method.rollout
    k, b, t = 2, rollout.num_envs, rollout.rollout_length
    assert obs.shape == (k, 2 * b * t, saved.problem.env.observation_size)  # snapshots 2 and 4
    assert executed.shape == (k, 2 * b * t, 1) and np.all(np.abs(executed) <= 1)
    # The driver's episodes only ever end at the time limit: no transition terminates.
    assert terminal.shape == (k, 2 * b * t) and not terminal.any()
    # The two snapshots' policies differ, so do their samples.
    assert not np.array_equal(executed[:, : b * t], executed[:, b * t :])
    earlier = SavedRun.open(str(tiny_run), snapshot=2)
    only_first, *_ = consolidation.snapshot_policy_samples(earlier, 0, key)
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


@pytest.fixture
def copied_run(tiny_run, tmp_path):
    """A copy of the tiny run that a test may write rewards into."""
    copy = tmp_path / "run"
    shutil.copytree(tiny_run, copy, ignore=shutil.ignore_patterns("rewards"))
    return copy


def test_a_saved_refit_is_the_reward_load_reward_returns(copied_run):
    import emgail_jax

    run = SavedRun.open(str(copied_run))
    refit = consolidation.Refit(steps=5, fresh=True)
    parameters, losses = consolidation.consolidated_parameters(run, 1, refit, jax.random.PRNGKey(0))
    description = consolidation.refit_description(refit, None, run.iteration)
    consolidation.save_refitted(
        str(copied_run), "mine", 1, parameters["discriminator"], description, losses
    )
    assert consolidation.saved_refits(str(copied_run)) == ["mine"]
    assert consolidation.read_losses(str(copied_run), "mine", 1)["after"]

    pairs = run.demonstration_pairs
    obs, actions = pairs.observations[:50], pairs.actions[:50]
    expected = run.with_reward_form("log-d").reward_function()(parameters, obs, actions, 1)
    reward = emgail_jax.load_reward(str(copied_run), seed=1, refit="mine", reward_form="log-d")
    for read in (reward, jax.jit(reward)):
        np.testing.assert_allclose(read(obs, actions, 1), expected, rtol=1e-6, atol=1e-6)
    # log(D) is never positive, the run's own -log(1 - D) never negative: the form was read.
    assert np.all(np.asarray(expected) <= 0)
    as_run = emgail_jax.load_reward(str(copied_run), seed=1, refit="mine")(obs, actions, 1)
    assert np.all(np.asarray(as_run) >= 0)
    own = emgail_jax.load_reward(str(copied_run), seed=1)(obs, actions, 1)
    assert not np.allclose(own, as_run)


def test_a_saved_refit_refuses_what_it_cannot_give(copied_run):
    from emgail_jax.host.run_spec import RunError

    run = SavedRun.open(str(copied_run))
    with pytest.raises(CheckpointError, match=r"saved no refitted reward 'mine' .saved: none"):
        run.reward(0, refit="mine")
    discriminator = run.reward_parameters(0)["discriminator"]
    description = consolidation.refit_description(consolidation.Refit(steps=5), None, run.iteration)
    consolidation.save_refitted(str(copied_run), "mine", 0, discriminator, description, {})
    with pytest.raises(RunError, match=r"seed 1 .* has no refitted reward 'mine'.*--seed 1"):
        run.reward(1, refit="mine")
    with pytest.raises(RunError, match="not a refitted one"):
        run.reward(0, across_seeds=True, refit="mine")
    with pytest.raises(RunError, match="refitted from snapshot None; this run was opened at 2"):
        SavedRun.open(str(copied_run), snapshot=2).reward(0, refit="mine")
    (copied_run / "rewards" / "mine" / "seed-0.msgpack").write_bytes(b"not a reward")
    with pytest.raises(CheckpointError, match="cannot be read"):
        run.reward(0, refit="mine")


def test_a_ranking_refit_learns_to_order_the_snapshots(saved):
    key = jax.random.PRNGKey(0)
    refit = consolidation.Refit(steps=60, fresh=True, ranking=1.0)
    _, metrics = consolidation.consolidated_parameters(saved, 0, refit, key)
    before, after = metrics["before"], metrics["after"]
    assert after["ranking/loss"] < before["ranking/loss"]
    assert after["ranking/expert_accuracy"] == 1.0


def test_random_and_still_actions_are_one_snapshot_of_samples_below_the_ranked_ones(saved):
    obs, executed, _ = consolidation.random_action_samples(saved, jax.random.PRNGKey(0))
    rollout = saved.config.method.rollout
    k, m = 2, rollout.num_envs * rollout.rollout_length
    assert obs.shape == (k, m, saved.problem.env.observation_size)
    assert executed.shape == (k, m, saved.problem.env.action_size)
    env = saved.problem.env
    assert (executed >= env.action_low).all() and (executed <= env.action_high).all()
    # Uniform over the box, not a policy's: spread over it.
    assert executed.std() > 0.25 * float(np.max(env.action_high - env.action_low))

    still_obs, still, _ = consolidation.still_action_samples(saved, jax.random.PRNGKey(0))
    assert still_obs.shape == obs.shape and still.shape == executed.shape
    np.testing.assert_array_equal(
        still, np.broadcast_to((env.action_low + env.action_high) / 2, still.shape)
    )
    # The episodes start where the random ones do (same key) and then go their own way.
    assert not np.array_equal(still_obs, obs)

    refit = consolidation.Refit(
        steps=60, fresh=True, ranking=1.0, ranking_random=True, ranking_still=True
    )
    _, metrics = consolidation.consolidated_parameters(saved, 0, refit, jax.random.PRNGKey(0))
    before, after = metrics["before"], metrics["after"]
    assert after["ranking/loss"] < before["ranking/loss"]
    assert after["ranking/expert_accuracy"] == 1.0


def test_a_refit_saved_before_an_option_existed_reads_as_its_default(copied_run):
    run = SavedRun.open(str(copied_run))
    refit = consolidation.Refit(steps=5, fresh=True)
    description = consolidation.refit_description(refit, None, run.iteration)
    older = {
        **description,
        "refit": {k: v for k, v in description["refit"].items() if not k.startswith("ranking")},
    }
    parameters, losses = consolidation.consolidated_parameters(run, 0, refit, jax.random.PRNGKey(0))
    consolidation.save_refitted(
        str(copied_run), "older", 0, parameters["discriminator"], older, losses
    )
    assert consolidation.read_description(str(copied_run), "older") == description
    # Saved before the iteration was recorded: a snapshot's refit is of its iteration, the
    # final networks' of an unknown one, which no run is read with.
    del older["iteration"]
    consolidation.save_refitted(
        str(copied_run), "older", 0, parameters["discriminator"], older, losses
    )
    assert consolidation.read_description(str(copied_run), "older")["iteration"] is None
    with pytest.raises(CheckpointError, match="an unrecorded iteration"):
        run.reward(0, refit="older")
    consolidation.save_refitted(
        str(copied_run), "older", 0, parameters["discriminator"], {**older, "snapshot": 2}, losses
    )
    assert consolidation.read_description(str(copied_run), "older")["iteration"] == 2


def test_a_refit_of_networks_the_run_has_replaced_is_refused_in_one_line(copied_run):
    """A run resumed after its reward was refitted holds other networks than those the refit
    was made from: reading the refit with them would pair it with other statistics."""
    import emgail_jax

    run = SavedRun.open(str(copied_run))
    refit = consolidation.Refit(steps=5, fresh=True)
    parameters, losses = consolidation.consolidated_parameters(run, 0, refit, jax.random.PRNGKey(0))
    earlier = consolidation.refit_description(refit, None, run.iteration - 1)
    consolidation.save_refitted(
        str(copied_run), "earlier", 0, parameters["discriminator"], earlier, losses
    )
    expected = (
        f"refitted from the networks of iteration {run.iteration - 1}, not those of iteration "
        f"{run.iteration}: delete .*rewards/earlier to refit it"
    )
    with pytest.raises(CheckpointError, match=expected):
        emgail_jax.load_reward(str(copied_run), seed=0, refit="earlier")


def test_fresh_agents_each_act_on_their_own_intentions_row():
    import jax.numpy as jnp

    seen = []

    def policy_of(state):
        def act(obs, key):
            seen.append(obs.shape)
            return jnp.broadcast_to(state + obs[..., :1], (*obs.shape[:-1], 1))

        return act

    policy = consolidation.agents_policy(policy_of, jnp.array([10.0, 20.0]))
    obs = jnp.zeros((2, 3, 4)).at[1].set(1.0)  # [K, B, D]
    for act in (policy, jax.jit(policy)):
        action = act(obs, jax.random.PRNGKey(0))
        assert action.shape == (2, 3, 1)
        np.testing.assert_array_equal(action[:, :, 0], [[10.0] * 3, [21.0] * 3])
    assert seen[0] == (1, 3, 4)  # one agent's rows, as it trained on them


def test_a_refit_against_agents_pays_their_samples_less(saved):
    key = jax.random.PRNGKey(0)
    refit = consolidation.Refit(steps=60, fresh=True, batch=50)
    agents = consolidation.still_action_samples(saved, jax.random.PRNGKey(1))
    plain, _ = consolidation.consolidated_parameters(saved, 0, refit, key)
    again, _ = consolidation.consolidated_parameters(saved, 0, refit, key)
    against, _ = consolidation.consolidated_parameters(saved, 0, refit, key, agents)
    assert same(plain, again)
    reward = saved.reward_function()
    paid = lambda parameters: np.mean(
        [np.asarray(reward(parameters, agents[0][i], agents[1][i], i)).mean() for i in range(2)]
    )
    assert paid(against) < paid(plain)


def test_a_state_only_refit_pays_no_action_more_than_another(copied_run):
    import emgail_jax

    run = SavedRun.open(str(copied_run))
    refit = consolidation.Refit(steps=5, fresh=True, state_only=True)
    parameters, losses = consolidation.consolidated_parameters(run, 0, refit, jax.random.PRNGKey(0))
    description = consolidation.refit_description(refit, None, run.iteration)
    consolidation.save_refitted(
        str(copied_run), "states", 0, parameters["discriminator"], description, losses
    )
    assert run.refit_is_state_only("states")
    pairs = run.demonstration_pairs
    obs = pairs.observations[:50]
    reward = emgail_jax.load_reward(str(copied_run), seed=0, refit="states")
    low, high = (np.full(pairs.actions[:50].shape, bound) for bound in (-1.0, 1.0))
    np.testing.assert_array_equal(reward(obs, low, 0), reward(obs, high, 0))
    # The same weights read with the actions, as a refit of D(s, a, i) would be, differ.
    with_actions = run.reward_function()
    assert not np.allclose(
        with_actions(parameters, obs, low, 0), with_actions(parameters, obs, high, 0)
    )


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
    samples = consolidation.snapshot_policy_samples(saved, 0, key)
    refit = consolidation.Refit(steps=60, fresh=True, absorbing=True)
    falls, metrics = consolidation.consolidated_parameters(
        run, 0, refit, key, samples=falls_marked(samples, 4)
    )
    never, _ = consolidation.consolidated_parameters(run, 0, refit, key, samples=samples)
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
    _, metrics = consolidation.consolidated_parameters(
        run, 0, drawn, key, samples=falls_marked(samples, 4)
    )
    assert metrics["after"]["discriminator/absorbing_d"] < 0.25


def test_random_actions_reward_is_the_mean_a_fixed_draw_of_random_actions_earns(saved):
    parameters, reward = saved.reward_parameters(0), saved.reward_function()
    price = consolidation.random_actions_reward(saved, parameters, reward)
    assert price.shape == (2,)
    np.testing.assert_array_equal(
        price, consolidation.random_actions_reward(saved, parameters, reward)
    )
    key = jax.random.key(consolidation.ABSORBING_PRICE_KEY)
    obs, actions, _ = consolidation.random_action_samples(saved, key)
    for intention in range(2):
        paid = reward(parameters, obs[intention], actions[intention], intention)
        assert price[intention] == pytest.approx(float(np.mean(paid)), rel=1e-6)
    # Another seed's reward prices it otherwise.
    other = consolidation.random_actions_reward(saved, saved.reward_parameters(1), reward)
    assert not np.array_equal(price, other)
    # The price a check's parameters carry is the absorbing reward, jitted or not.
    carried = {**parameters, "absorbing_price": price}
    for absorbing in (
        consolidation.priced_absorbing_reward,
        jax.jit(consolidation.priced_absorbing_reward),
    ):
        assert float(absorbing(carried, 1)) == price[1]


def test_an_absorbing_refit_needs_the_network_and_fresh_weights(saved):
    key = jax.random.PRNGKey(0)
    with pytest.raises(ValueError, match="with_absorbing_states"):
        consolidation.consolidated_parameters(
            saved, 0, consolidation.Refit(steps=2, fresh=True, absorbing=True), key
        )
    assert not saved.trained_with_absorbing_states
    with pytest.raises(ValueError, match="refit it fresh"):
        consolidation.consolidated_parameters(
            saved.with_absorbing_states(), 0, consolidation.Refit(steps=2, absorbing=True), key
        )


def test_a_saved_absorbing_refit_is_read_with_its_absorbing_state(copied_run):
    import emgail_jax

    run = SavedRun.open(str(copied_run))
    refit = consolidation.Refit(steps=5, fresh=True, absorbing=True)
    absorbing_run = run.with_absorbing_states()
    parameters, losses = consolidation.consolidated_parameters(
        absorbing_run, 0, refit, jax.random.PRNGKey(0)
    )
    description = consolidation.refit_description(refit, None, run.iteration)
    consolidation.save_refitted(
        str(copied_run), "falls", 0, parameters["discriminator"], description, losses
    )
    reopened = SavedRun.open(str(copied_run)).for_refit("falls")
    assert reopened.networks.discriminator.absorbing
    assert reopened.absorbing_reward_function() is not None
    pairs = run.demonstration_pairs
    obs, actions = pairs.observations[:30], pairs.actions[:30]
    expected = absorbing_run.reward_function()(parameters, obs, actions, 0)
    reward = emgail_jax.load_reward(str(copied_run), seed=0, refit="falls")
    np.testing.assert_allclose(reward(obs, actions, 0), expected, rtol=1e-6, atol=1e-6)
    # What a fall is worth under it: the absorbing state's learned reward, or what random
    # actions earn per step under the same reward, jitted or not.
    fall = emgail_jax.load_absorbing_reward(str(copied_run), seed=0, refit="falls")
    learned = absorbing_run.absorbing_reward_function()(parameters, jnp.arange(2))
    for paid in (fall, jax.jit(fall)):
        np.testing.assert_allclose(paid(jnp.arange(2)), learned, rtol=1e-6)
    random = emgail_jax.load_absorbing_reward(
        str(copied_run), seed=0, refit="falls", price="random"
    )
    price = consolidation.random_actions_reward(
        absorbing_run, parameters, absorbing_run.reward_function()
    )
    np.testing.assert_allclose(random(jnp.arange(2)), price, rtol=1e-6)
    with pytest.raises(ValueError, match="unknown absorbing price 'zero': learned or random"):
        emgail_jax.load_absorbing_reward(str(copied_run), seed=0, refit="falls", price="zero")
    # The run's own reward, trained without absorbing states, has none.
    assert emgail_jax.load_absorbing_reward(str(copied_run), seed=0) is None
    # A refit without absorbing states still reads the run's own network.
    plain = consolidation.Refit(steps=5, fresh=True)
    plain_parameters, _ = consolidation.consolidated_parameters(
        run, 0, plain, jax.random.PRNGKey(0)
    )
    consolidation.save_refitted(
        str(copied_run),
        "plain",
        0,
        plain_parameters["discriminator"],
        consolidation.refit_description(plain, None, run.iteration),
        losses,
    )
    assert not SavedRun.open(str(copied_run)).for_refit("plain").networks.discriminator.absorbing
