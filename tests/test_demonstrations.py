"""Demonstrations in memory: generation with the driver's analytic expert and the pure
transforms."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from emgail_jax.method import demonstrations
from emgail_jax.method.demonstrations import Demonstrations

EPISODES, LENGTH, K = 5, 100, 2


@pytest.fixture(scope="module")
def env():
    return envs.make("driver", intentions=K)


@pytest.fixture(scope="module")
def generated(env):
    return demonstrations.generate(env, env.expert_policy, EPISODES, jax.random.PRNGKey(0))


def test_generate_sizes_labels_and_episode_starts(generated):
    assert len(generated) == K * EPISODES * LENGTH
    assert generated.observations.shape == (1000, 10)
    assert generated.actions.shape == (1000, 1)
    assert generated.observations.dtype == generated.actions.dtype == np.float32
    np.testing.assert_array_equal(np.bincount(generated.intentions), [500, 500])
    # Intention-major, then episode, then time.
    np.testing.assert_array_equal(generated.intentions, np.repeat([0, 1], 500))
    np.testing.assert_array_equal(np.flatnonzero(generated.episode_starts), np.arange(0, 1000, 100))
    assert generated.num_intentions == K
    assert np.all(np.abs(generated.actions) <= 1.0)
    assert np.all(np.isfinite(generated.observations))


def test_episode_starts_are_initial_states_and_episodes_are_contiguous(env, generated):
    history = generated.observations.reshape(-1, 5, 2)
    spacing = np.linalg.norm(np.diff(history, axis=1), axis=-1)  # [N, 4]
    np.testing.assert_allclose(spacing, env.speed, rtol=1e-3)  # constant speed everywhere
    starts = generated.episode_starts
    # A start is near the origin; every other observation continues the previous one.
    assert np.all(np.linalg.norm(history[starts, -1], axis=-1) < 0.3)
    following = ~starts[1:]
    np.testing.assert_allclose(history[1:][following, :-1], history[:-1][following, 1:], atol=1e-6)


def test_generate_is_deterministic_for_a_key(env, generated):
    again = demonstrations.generate(env, env.expert_policy, EPISODES, jax.random.PRNGKey(0))
    np.testing.assert_array_equal(again.observations, generated.observations)
    np.testing.assert_array_equal(again.actions, generated.actions)
    np.testing.assert_array_equal(again.expert_returns, generated.expert_returns)
    other = demonstrations.generate(env, env.expert_policy, EPISODES, jax.random.PRNGKey(1))
    assert not np.allclose(other.actions, generated.actions)


def test_expert_returns_equal_the_own_path_return_recomputed_from_the_pairs(env, generated):
    """Replays each pair's action from its observation (the heading is the direction of the last
    move) and sums minus the distance to the own path: the mean per intention is expert_returns."""
    history = generated.observations.reshape(-1, 5, 2)
    move = history[:, -1] - history[:, -2]
    heading = np.arctan2(move[:, 1], move[:, 0]) + env.max_turn * generated.actions[:, 0]
    position = history[:, -1] + env.speed * np.stack([np.cos(heading), np.sin(heading)], -1)
    distances = np.asarray(jax.vmap(env.path_distances)(jnp.asarray(position)))  # [N, K]
    own = -distances[np.arange(len(position)), generated.intentions]
    per_episode = own.reshape(K, EPISODES, LENGTH).sum(-1)
    np.testing.assert_allclose(generated.expert_returns, per_episode.mean(-1), rtol=2e-3)
    # Near the maximum (0) of the own path's reward: the expert follows its path.
    assert np.all(generated.expert_returns > -5.0)


class _Counter(envs.Env):
    """Counts its steps and terminates on its own after ``stop`` of them; reward 1 per step."""

    name = "counter"
    intention_names = ("a", "b")
    observation_size = 1
    action_size = 1
    episode_length = 10
    stop = 3

    def reset(self, key):
        return envs.State(
            physics=jnp.zeros(()), obs=jnp.zeros(1), reward=jnp.zeros(2), done=jnp.zeros(())
        )

    def step(self, state, action):
        count = state.physics + 1
        done = (count >= self.stop).astype(jnp.float32)
        return state.replace(physics=count, obs=count[None], reward=jnp.ones(2), done=done)


def test_generate_drops_pairs_after_an_early_termination():
    counter = _Counter()
    expert = lambda state, intention, key: jnp.zeros(1)
    demos = demonstrations.generate(counter, expert, 2, jax.random.PRNGKey(0))
    # 2 intentions x 2 episodes x 3 steps before the env ended each episode (of 10 allowed).
    assert len(demos) == 12
    np.testing.assert_array_equal(demos.observations[:, 0], np.tile([0, 1, 2], 4))
    np.testing.assert_array_equal(np.flatnonzero(demos.episode_starts), [0, 3, 6, 9])
    np.testing.assert_array_equal(demos.intentions, np.repeat([0, 1], 6))
    np.testing.assert_array_equal(demos.expert_returns, [3.0, 3.0])


def test_first_intentions_keeps_the_first_k(generated):
    four = Demonstrations(
        observations=np.arange(8, dtype=np.float32)[:, None],
        actions=np.zeros((8, 1), np.float32),
        episode_starts=np.array([1, 0, 1, 0, 1, 0, 1, 0], bool),
        intentions=np.array([0, 0, 1, 1, 2, 2, 3, 3]),
        expert_returns=np.array([-1.0, -2.0, -3.0, -4.0], np.float32),
    )
    two = demonstrations.first_intentions(four, 2)
    np.testing.assert_array_equal(two.observations[:, 0], [0, 1, 2, 3])
    np.testing.assert_array_equal(two.intentions, [0, 0, 1, 1])
    np.testing.assert_array_equal(two.expert_returns, [-1.0, -2.0])
    assert two.num_intentions == 2


def test_first_episodes_keeps_the_first_n_of_each_intention():
    starts = np.array([1, 0, 1, 0, 1, 0, 1, 0, 1, 0, 1, 0], bool)  # 6 episodes of 2 pairs
    intentions = np.array([0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 1, 1])
    demos = Demonstrations(
        np.arange(12, dtype=np.float32)[:, None], np.zeros((12, 1)), starts, intentions
    )
    kept = demonstrations.first_episodes(demos, [2, 1])
    np.testing.assert_array_equal(kept.observations[:, 0], [0, 1, 2, 3, 6, 7])
    np.testing.assert_array_equal(kept.episode_starts, [1, 0, 1, 0, 1, 0])
    with pytest.raises(ValueError, match="has 3 episodes, not 4"):
        demonstrations.first_episodes(demos, [4, 1])


def test_episode_and_step_in_episode_restart_at_each_demonstration():
    starts = np.array([1, 0, 0, 1, 0, 1], bool)
    demos = Demonstrations(np.zeros((6, 2)), np.zeros((6, 1)), starts)
    assert demos.episode.tolist() == [0, 0, 0, 1, 1, 2]
    assert demos.step_in_episode.tolist() == [0, 1, 2, 0, 1, 0]


def test_next_observations_are_the_next_pairs_and_each_final_observation(generated):
    """AIRL's s' of a demonstration pair: the next pair's observation within its
    demonstration, the demonstration's final observation after its last pair."""
    following = generated.next_observations()
    assert following.shape == generated.observations.shape and following.dtype == np.float32
    last = np.append(generated.episode[1:] != generated.episode[:-1], True)
    np.testing.assert_array_equal(following[~last], generated.observations[1:][~last[:-1]])
    np.testing.assert_array_equal(following[last], generated.final_observations)
    assert (
        Demonstrations(
            generated.observations, generated.actions, generated.episode_starts
        ).next_observations()
        is None
    )
