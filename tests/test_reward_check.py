"""The reward check on a tiny run: the run's matching, the demonstrations' reward, fresh agents
trained, stopped and resumed, and scored on the schedule."""

import jax
import numpy as np
import pytest

from emgail_jax.reward import check, progress

pytestmark = pytest.mark.heavy


@pytest.fixture(scope="module")
def saved(tiny_run):
    from emgail_jax.host.saved_run import SavedRun

    return SavedRun.open(str(tiny_run))


def test_the_run_matching_is_the_last_evaluation_at_or_before_the_iteration(saved):
    history = saved.history["eval/matching"]
    for iteration in (1, 2, 4):
        np.testing.assert_array_equal(
            check.run_matching(saved, 1, iteration), history[1, iteration - 1]
        )


def test_demonstrations_reward_weights_pairs_by_their_responsibilities(saved):
    expert = saved.demonstration_pairs
    gamma = np.asarray(saved.responsibilities(0).gamma)
    reward = saved.reward(0)
    earned = check.demonstrations_reward(saved, 0)
    for i in range(2):
        if gamma[:, i].sum() == 0:  # no demonstration assigned: nothing to earn on
            assert np.isnan(earned[i])
            continue
        per_pair = np.asarray(reward(expert.observations, expert.actions, i))
        expected = (gamma[:, i] * per_pair).sum() / gamma[:, i].sum()
        np.testing.assert_allclose(earned[i], expected, rtol=1e-5)


@pytest.mark.slow  # end to end (make test-slow); cheaper tests cover its parts
def test_a_stopped_training_goes_on_from_its_save_as_if_never_stopped(saved, tmp_path):
    """Fresh agents stopped after a save and started again with it end bit-identical to agents
    trained at once."""
    from emgail_jax.host.saved_run import stacked

    budget = check.Budget(iterations=20, gamma=0.99, gae_lambda=0.97)
    trainer = check.learned_reward_trainer(saved, budget, saved.reward_function())
    keys = check.fresh_keys(saved, [1], rl_seed=0)
    data = stacked([saved.reward_parameters(1)])

    def train(partial=None):
        return check.train_fresh(trainer, keys, data, 20, label="", progress=False, partial=partial)

    whole = train()

    class Stopped(Exception):
        pass

    class StoppedAfterItsFirstSave(progress.PartialTraining):
        def write(self, *args):
            super().write(*args)
            raise Stopped

    path = str(tmp_path / "rl-0.partial.npz")
    with pytest.raises(Stopped):
        train(StoppedAfterItsFirstSave(path, {"check": 1}, every_s=0.0))
    partial = progress.PartialTraining(path, {"check": 1})
    done, *_ = partial.read(whole.states, 10, 20)
    assert done == 10  # the first of two chunks
    resumed = train(partial)
    np.testing.assert_array_equal(resumed.returns, whole.returns)
    np.testing.assert_array_equal(resumed.earned, whole.earned)
    for a, b in zip(jax.tree.leaves(resumed.states), jax.tree.leaves(whole.states), strict=True):
        np.testing.assert_array_equal(a, b)
    assert resumed.returns.shape == (1, 20, 2, 2)


@pytest.mark.slow  # end to end (make test-slow); cheaper tests cover its parts
def test_fresh_agents_scored_on_the_schedule_train_as_if_scored_every_iteration(saved):
    """Evaluation episodes every 10th iteration and each of the last 10 only: the agents, the
    reward they earn and the returns where scored are those of agents scored every iteration;
    the other iterations' returns are NaN."""
    from emgail_jax.host.saved_run import stacked

    budget = check.Budget(iterations=30, gamma=0.99, gae_lambda=0.97)
    trainer = check.learned_reward_trainer(saved, budget, saved.reward_function())
    keys = check.fresh_keys(saved, [0, 1], rl_seed=0)
    data = stacked([saved.reward_parameters(seed) for seed in (0, 1)])
    train = lambda **every: check.train_fresh(
        trainer, keys, data, 30, label="", progress=False, **every
    )
    scheduled, every = train(), train(curve_every=1)
    for a, b in zip(jax.tree.leaves(scheduled.states), jax.tree.leaves(every.states), strict=True):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(scheduled.earned, every.earned)
    scored = np.zeros(30, bool)
    scored[[9, *range(19, 30)]] = True  # iterations 10 and 20 to 30
    np.testing.assert_array_equal(scheduled.returns[:, scored], every.returns[:, scored])
    assert np.isnan(scheduled.returns[:, ~scored]).all()
    assert np.isfinite(every.returns).all()
