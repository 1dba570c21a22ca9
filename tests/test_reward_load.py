"""load_reward and load_absorbing_reward: the run's reward, or a refit it saved."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from emgail_jax.host.checkpoints import CheckpointError
from emgail_jax.host.saved_run import SavedRun
from emgail_jax.reward import load
from emgail_jax.reward import refit as refitting
from emgail_jax.reward import saved as store


def test_a_saved_refit_is_the_reward_load_reward_returns(copied_run):
    import emgail_jax

    run = SavedRun.open(str(copied_run))
    refit = refitting.Refit(steps=5, fresh=True)
    parameters, losses = refitting.consolidated_parameters(run, 1, refit, jax.random.PRNGKey(0))
    description = store.refit_description(refit, None, run.iteration)
    store.save_refitted(
        str(copied_run), "mine", 1, parameters["discriminator"], description, losses
    )
    assert store.saved_refits(str(copied_run)) == ["mine"]
    assert store.read_losses(str(copied_run), "mine", 1)["after"]

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
        load.reward_of(run, 0, refit="mine")
    discriminator = run.reward_parameters(0)["discriminator"]
    description = store.refit_description(refitting.Refit(steps=5), None, run.iteration)
    store.save_refitted(str(copied_run), "mine", 0, discriminator, description, {})
    with pytest.raises(RunError, match=r"seed 1 .* has no refitted reward 'mine'.*--seed 1"):
        load.reward_of(run, 1, refit="mine")
    with pytest.raises(RunError, match="not a refitted one"):
        load.reward_of(run, 0, across_seeds=True, refit="mine")
    with pytest.raises(RunError, match="refitted from snapshot None; this run was opened at 2"):
        load.reward_of(SavedRun.open(str(copied_run), snapshot=2), 0, refit="mine")
    (copied_run / "rewards" / "mine" / "seed-0.msgpack").write_bytes(b"not a reward")
    with pytest.raises(CheckpointError, match="cannot be read"):
        load.reward_of(run, 0, refit="mine")


@pytest.mark.slow  # end to end (make test-slow); cheaper tests cover its parts
def test_a_saved_absorbing_refit_is_read_with_its_absorbing_state(copied_run):
    import emgail_jax

    run = SavedRun.open(str(copied_run))
    refit = refitting.Refit(steps=5, fresh=True, absorbing=True)
    absorbing_run = run.with_absorbing_states()
    parameters, losses = refitting.consolidated_parameters(
        absorbing_run, 0, refit, jax.random.PRNGKey(0)
    )
    description = store.refit_description(refit, None, run.iteration)
    store.save_refitted(
        str(copied_run), "falls", 0, parameters["discriminator"], description, losses
    )
    reopened = load.run_for_refit(SavedRun.open(str(copied_run)), "falls")
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
    # The loaded reward pays it itself, no second call.
    assert reward.source == "refit"
    np.testing.assert_allclose(reward.termination(jnp.arange(2)), learned, rtol=1e-6)
    random = emgail_jax.load_absorbing_reward(
        str(copied_run), seed=0, refit="falls", price="random"
    )
    price = refitting.random_actions_reward(
        absorbing_run, parameters, absorbing_run.reward_function()
    )
    np.testing.assert_allclose(random(jnp.arange(2)), price, rtol=1e-6)
    with pytest.raises(ValueError, match="unknown absorbing price 'zero': learned or random"):
        emgail_jax.load_absorbing_reward(str(copied_run), seed=0, refit="falls", price="zero")
    # The run's own reward, trained without absorbing states, has none.
    assert emgail_jax.load_absorbing_reward(str(copied_run), seed=0) is None
    # A refit without absorbing states still reads the run's own network.
    plain = refitting.Refit(steps=5, fresh=True)
    plain_parameters, _ = refitting.consolidated_parameters(run, 0, plain, jax.random.PRNGKey(0))
    store.save_refitted(
        str(copied_run),
        "plain",
        0,
        plain_parameters["discriminator"],
        store.refit_description(plain, None, run.iteration),
        losses,
    )
    assert not load.run_for_refit(
        SavedRun.open(str(copied_run)), "plain"
    ).networks.discriminator.absorbing
