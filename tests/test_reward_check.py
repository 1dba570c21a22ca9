"""The reward check on a tiny run: the run's matching, the demonstrations' reward, fresh agents
trained, stopped and resumed, and scored on the schedule."""

import types

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
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


class _Pays(envs.Env):
    """Pays ``[a, 2a]`` per step for action ``a`` over 4 steps, in the action box [low, high]."""

    name = "pays"
    intention_names = ("a", "b")
    observation_size = 1
    action_size = 1
    episode_length = 4

    def __init__(self, low=-1.0, high=1.0):
        super().__init__()
        self.low, self.high = low, high

    action_low = property(lambda self: self.low)
    action_high = property(lambda self: self.high)

    def reset(self, key):
        return envs.State({}, jnp.zeros(1), jnp.zeros(2), jnp.zeros(()))

    def step(self, state, action):
        return state.replace(reward=action[0] * jnp.array([1.0, 2.0]))


def _problem(env):
    demos = types.SimpleNamespace(expert_returns=[8.0, 8.0])
    return types.SimpleNamespace(
        env=env, demos=demos, random_returns=[4.0, 0.0], true_intentions=2,
        random_episodes=3, random_seed=1,
    )  # fmt: skip


def test_doing_nothing_is_scored_against_the_experts_and_random_actions_untrained():
    """Zero actions earn 0: ERD |8 - 0| / |8 - 4| = 2 and 8 / 8 = 1. In a box [0, 2] the middle,
    1, earns 4 and 8: ERD 1 and 0; a centred box has the zero row alone."""
    centred = check.do_nothing(_problem(_Pays()))
    assert [row["actions"] for row in centred] == ["zero"]
    np.testing.assert_allclose(centred[0]["erd_per_intention"], [2.0, 1.0])
    assert centred[0]["erd"] == pytest.approx(1.5)
    zero, middle = check.do_nothing(_problem(_Pays(low=0.0, high=2.0)))
    assert middle["actions"] == "mid-range" and zero["erd"] == pytest.approx(1.5)
    np.testing.assert_allclose(middle["returns"], [4.0, 8.0])
    assert middle["erd"] == pytest.approx(0.5)


def test_the_fresh_agents_budget_is_the_runs_with_what_its_env_declares_in_place(monkeypatch):
    """The run's own iterations, gamma, lambda and scaling where its env declares nothing;
    each one the env declares replaces the run's."""
    b_step = types.SimpleNamespace(gamma=0.99, gae_lambda=0.97, value_target_scaling=False)
    config = types.SimpleNamespace(
        schedule=types.SimpleNamespace(iterations=30), method=types.SimpleNamespace(b_step=b_step)
    )
    run = types.SimpleNamespace(spec=types.SimpleNamespace(env="driver"), config=config)
    assert check.default_budget(run) == check.Budget(30, 0.99, 0.97, False)
    declared = {"iterations": 7, "value_target_scaling": True}
    monkeypatch.setattr(envs.env_class("driver"), "rl_budget", declared)
    assert check.default_budget(run) == check.Budget(7, 0.99, 0.97, True)
    assert check.env_budget({"gamma": 0.5}, 30, 0.99, 0.97) == check.Budget(30, 0.5, 0.97)


def test_the_success_measure_is_the_share_of_episodes_meeting_the_bars_beside_the_distance():
    """A reacher's agents recorded before the per-episode share: their reached share is it."""
    agents = [
        {"reached": 0.9, "final_distance": 0.01},
        {"reached": 0.3, "final_distance": 0.05, "episodes_meeting_bar": 0.3},
    ]
    found = check.success_summary(agents)
    assert found["success_rate"] == pytest.approx(0.6)
    assert found["final_distance"] == pytest.approx(0.03)
    assert check.success_summary([{"episodes_meeting_bar": None}])["success_rate"] is None
