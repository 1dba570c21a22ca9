"""Rollouts of K x B envs: shapes, time and episode ends under auto-reset, evaluation returns
(hand-computed on a counting env, and the driver's analytic expert), random actions."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from emgail_jax.method import demonstrations
from emgail_jax.method.rollout import (
    batch_reset,
    episode_returns,
    episode_totals,
    intention_major,
    rollout,
    steps_left,
    still_policy,
    terminations,
    time_major,
    uniform_random_policy,
)
from envs.driver import DriverPhysics

K, B = 2, 3


class _Counter(envs.Env):
    """Counts its steps; the observation is a random start offset ``u`` plus the count.

    Reward ``[a, 2a]`` for action ``a`` (intention k's reward is (k + 1) a); terminates on its
    own once ``stop`` steps are done; after that its reward is ``after_stop``.
    """

    name = "counter"
    intention_names = ("a", "b")
    observation_size = 1
    action_size = 1

    def __init__(self, length=10, stop=1000, after_stop=None, low=-1.0, high=1.0):
        super().__init__()
        self._length, self.stop, self.after_stop = length, stop, after_stop
        self.low, self.high = low, high

    episode_length = property(lambda self: self._length)
    action_low = property(lambda self: self.low)
    action_high = property(lambda self: self.high)

    def reset(self, key):
        u = jax.random.uniform(key, ())
        physics = {"count": jnp.zeros(()), "u": u}
        return envs.State(physics, u[None], jnp.zeros(2), jnp.zeros(()))

    def step(self, state, action):
        count = state.physics["count"] + 1
        reward = action[0] * jnp.array([1.0, 2.0])
        if self.after_stop is not None:
            reward = jnp.where(count > self.stop, self.after_stop, reward)
        done = (count >= self.stop).astype(jnp.float32)
        physics = {**state.physics, "count": count}
        return state.replace(
            physics=physics, obs=(state.physics["u"] + count)[None], reward=reward, done=done
        )


def row_policy(obs, key):
    """Row k of the [K, B] envs always acts k + 1."""
    del key
    rows = jnp.arange(obs.shape[0], dtype=jnp.float32) + 1.0
    return jnp.broadcast_to(rows[:, None, None], (*obs.shape[:2], 1))


def _roll(env, length):
    @jax.jit
    def go(key):
        key_reset, key_first, key_second = jax.random.split(key, 3)
        state = batch_reset(env, key_reset, (K, B))
        middle, first = rollout(env, row_policy, state, key_first, length)
        end, second = rollout(env, row_policy, middle, key_second, length)
        return state, middle, first, end, second

    return go(jax.random.PRNGKey(0))


@pytest.fixture(scope="module")
def time_limited():
    """Episodes end by the 4-step time limit only."""
    return _roll(envs.wrap_for_training(_Counter(), 4), 10)


@pytest.fixture(scope="module")
def terminating():
    """Episodes end by the env's own termination after 3 steps (time limit 4)."""
    return _roll(envs.wrap_for_training(_Counter(stop=3), 4), 10)


def test_batch_reset_gives_independent_k_by_b_states():
    env = envs.wrap_for_training(envs.make("driver", intentions=K))
    state = jax.jit(lambda key: batch_reset(env, key, (K, B)))(jax.random.PRNGKey(1))
    assert state.obs.shape == (K, B, 10)
    assert state.done.shape == (K, B) and state.reward.shape == (K, B, K)
    assert state.info["steps"].shape == (K, B)
    np.testing.assert_array_equal(state.info["steps"], np.zeros((K, B)))
    positions = np.asarray(state.obs[..., -2:]).reshape(K * B, 2)
    assert len(np.unique(positions, axis=0)) == K * B


def test_transition_shapes(time_limited):
    _, _, first, _, _ = time_limited
    assert first.obs.shape == (10, K, B, 1)
    assert first.action.shape == (10, K, B, 1)
    assert first.time.shape == first.done.shape == (10, K, B)
    assert first.true_reward.shape == (10, K, B, K)


def test_time_and_done_under_a_time_limit(time_limited):
    _, middle, first, end, second = time_limited
    # Steps 0..9 of 4-step episodes: t = (0, 1, 2, 3, 0, ...) / 4, done at t = 3 and 7.
    expected_time = np.array([0, 1, 2, 3, 0, 1, 2, 3, 0, 1]) / 4
    np.testing.assert_allclose(
        first.time, np.broadcast_to(expected_time[:, None, None], (10, K, B))
    )
    np.testing.assert_array_equal(np.flatnonzero(first.done[:, 0, 0]), [3, 7])
    np.testing.assert_array_equal(first.done, np.broadcast_to(first.done[:, :1, :1], (10, K, B)))
    # The next rollout continues mid-episode (2 steps in): done at t = 1, 5, 9.
    np.testing.assert_array_equal(middle.info["steps"], np.full((K, B), 2))
    np.testing.assert_allclose(second.time[:2, 0, 0], [0.5, 0.75])
    np.testing.assert_array_equal(np.flatnonzero(second.done[:, 1, 2]), [1, 5, 9])
    np.testing.assert_array_equal(end.info["steps"], np.full((K, B), 0))


@pytest.mark.parametrize("stop", [1000, 3])
def test_next_observations_are_those_reached_before_the_auto_reset(stop):
    """AIRL's s': the counter's observation plus one on every step, at a time limit (4 steps)
    and at a termination (3) alike, where the state already holds the next episode's start."""
    env = envs.wrap_for_training(_Counter(stop=stop), 4)

    @jax.jit
    def go(key):
        state = batch_reset(env, key, (K, B))
        return rollout(env, row_policy, state, key, 10, next_obs=True)

    _, transitions = go(jax.random.PRNGKey(0))
    assert transitions.next_obs.shape == transitions.obs.shape
    np.testing.assert_allclose(transitions.next_obs, transitions.obs + 1.0, rtol=1e-6)
    ends = np.asarray(transitions.done[:-1]) > 0
    assert ends.any()
    following = np.asarray(transitions.obs[1:, ..., 0])
    assert np.all(np.abs(following[ends] - transitions.next_obs[:-1, ..., 0][ends]) > 1e-6)
    assert (
        rollout(
            env,
            row_policy,
            batch_reset(env, jax.random.PRNGKey(0), (K, B)),
            jax.random.PRNGKey(1),
            2,
        )[1].next_obs
        is None
    )


def test_observations_restart_at_a_fresh_start_after_done(time_limited):
    start, _, first, _, _ = time_limited
    obs = np.asarray(first.obs[..., 0])  # [T, K, B]
    u0 = np.asarray(start.obs[..., 0])
    np.testing.assert_allclose(obs[:4], u0 + np.arange(4)[:, None, None], rtol=1e-6)
    # After the first episode: a new start drawn for this rollout (and reused by the next
    # episode within the same rollout, as AutoResetWrapper documents).
    u1 = obs[4]
    assert np.all(np.abs(u1 - u0) > 1e-6)
    np.testing.assert_allclose(obs[4:8], u1 + np.arange(4)[:, None, None], rtol=1e-6)
    np.testing.assert_allclose(obs[8], u1, rtol=1e-6)
    # Every env has its own start.
    assert len(np.unique(u1)) == K * B


def test_actions_and_true_rewards_follow_the_rows(time_limited):
    _, _, first, _, _ = time_limited
    for k in range(K):
        np.testing.assert_array_equal(first.action[:, k], np.full((10, B, 1), k + 1.0))
        # Reward of intention i for action a is (i + 1) a.
        np.testing.assert_allclose(first.true_reward[:, k], np.full((10, B, K), [1, 2]) * (k + 1))


def test_time_and_done_when_the_env_terminates_early(terminating):
    _, middle, first, _, _ = terminating
    expected_time = np.array([0, 1, 2, 0, 1, 2, 0, 1, 2, 0]) / 4
    np.testing.assert_allclose(first.time[:, 1, 0], expected_time)
    np.testing.assert_array_equal(np.flatnonzero(first.done[:, 1, 0]), [2, 5, 8])
    np.testing.assert_array_equal(middle.info["steps"], np.ones((K, B)))


def test_terminations_are_the_envs_ends_before_the_time_limit(time_limited, terminating):
    """The env's own ends after 3 steps of 4 are terminations, with one step left; the time
    limit's are not (none left), although after the auto-reset neither state says which."""
    _, _, limited, _, _ = time_limited
    _, _, ended, _, _ = terminating
    np.testing.assert_array_equal(steps_left(ended.time[:3, 1, 0], 4), [3, 2, 1])
    np.testing.assert_array_equal(steps_left(limited.time[:4, 1, 0], 4), [3, 2, 1, 0])
    assert not np.any(terminations(limited, 4)) and np.any(limited.done)
    np.testing.assert_array_equal(terminations(ended, 4), ended.done)
    # The state after a time limit's end already holds the next episode's truncation flag.
    _, after, one_episode, _, _ = _roll(envs.wrap_for_training(_Counter(), 4), 4)
    assert np.all(one_episode.done[-1]) and not np.any(after.info["truncation"])
    # An end at the limit itself counts as the limit's: nothing is left to absorb.
    _, _, at_limit, _, _ = _roll(envs.wrap_for_training(_Counter(stop=4), 4), 10)
    assert np.any(at_limit.done) and not np.any(terminations(at_limit, 4))
    jitted = jax.jit(terminations, static_argnums=1)(ended, 4)
    np.testing.assert_array_equal(jitted, terminations(ended, 4))


def _returns(env, policy, num_policies, episodes):
    return jax.jit(lambda key: episode_returns(env, policy, key, num_policies, episodes))(
        jax.random.PRNGKey(2)
    )


def test_episode_returns_sum_rewards_of_each_row_over_full_episodes():
    returns = _returns(envs.EpisodeWrapper(_Counter(length=5)), row_policy, 3, 2)
    assert returns.shape == (3, K)
    # Row j acts j + 1 for 5 steps: return 5 (j + 1) under intention 0, twice that under 1.
    np.testing.assert_allclose(returns, [[5, 10], [10, 20], [15, 30]])


def test_episode_returns_ignore_rewards_after_a_termination():
    returns = _returns(envs.EpisodeWrapper(_Counter(length=10, stop=3)), row_policy, 2, 2)
    np.testing.assert_allclose(returns, [[3, 6], [6, 12]])


def test_episode_returns_ignore_non_finite_rewards_after_a_termination():
    env = envs.EpisodeWrapper(_Counter(length=10, stop=3, after_stop=jnp.nan))
    returns = _returns(env, row_policy, 2, 2)
    np.testing.assert_allclose(returns, [[3, 6], [6, 12]])


def test_driver_expert_returns_match_the_demonstrations():
    """The noiseless analytic expert, acting from observations only (the heading is the
    direction of the last move), scores what ``demos.generate`` reports for it when both start
    from the same states (same key): the diagonal of the [policy, intention] returns."""
    driver = envs.make("driver", intentions=K)
    episodes = 2

    def expert_from_obs(obs, key):
        del key
        history = obs.reshape(*obs.shape[:-1], 5, 2)
        move = history[..., -1, :] - history[..., -2, :]
        physics = DriverPhysics(heading=jnp.arctan2(move[..., 1], move[..., 0]), history=history)
        state = envs.State(physics, obs, jnp.zeros((*obs.shape[:-1], K)), jnp.zeros(obs.shape[:-1]))
        rows = jnp.broadcast_to(jnp.arange(K)[:, None], obs.shape[:2])
        return jax.vmap(jax.vmap(driver.expert_action))(state, rows)

    key = jax.random.PRNGKey(3)
    returns = jax.jit(
        lambda key: episode_returns(envs.EpisodeWrapper(driver), expert_from_obs, key, K, episodes)
    )(key)
    noiseless = lambda state, intention, key: driver.expert_action(state, intention)
    demos = demonstrations.generate(driver, noiseless, episodes, key)
    np.testing.assert_allclose(np.diag(returns), demos.expert_returns, rtol=1e-3)
    # Each expert follows its own path: under intention i, expert i beats expert j.
    assert returns[0, 0] > returns[1, 0] + 10 and returns[1, 1] > returns[0, 1] + 10


def test_uniform_random_policy_covers_the_action_box():
    env = _Counter(low=-2.0, high=0.5)
    policy = uniform_random_policy(env)
    obs = jnp.zeros((K, 500, 1))
    actions = np.asarray(policy(obs, jax.random.PRNGKey(4)))
    assert actions.shape == (K, 500, 1)
    assert actions.min() >= -2.0 and actions.max() <= 0.5
    assert actions.min() < -1.95 and actions.max() > 0.45
    assert actions.mean() == pytest.approx(-0.75, abs=0.1)
    other = np.asarray(policy(obs, jax.random.PRNGKey(5)))
    assert not np.allclose(actions, other)
    driver = envs.make("driver", intentions=K)
    driver_actions = uniform_random_policy(driver)(jnp.zeros((K, B, 10)), jax.random.PRNGKey(6))
    assert driver_actions.shape == (K, B, 1)
    assert np.all(np.abs(driver_actions) <= 1.0)


def test_still_policy_holds_the_middle_of_the_action_box_jitted_and_not():
    env = _Counter(low=-2.0, high=0.5)
    policy = still_policy(env)
    obs = jnp.zeros((K, 7, 1))
    eager = np.asarray(policy(obs, jax.random.PRNGKey(4)))
    jitted = np.asarray(jax.jit(policy)(obs, jax.random.PRNGKey(5)))
    np.testing.assert_array_equal(eager, np.full((K, 7, 1), -0.75, np.float32))
    np.testing.assert_array_equal(jitted, eager)


def test_intention_major_groups_samples_by_intention_and_time_major_undoes_it():
    t, k, b = 3, 2, 4
    x = np.arange(t * k * b * 2).reshape(t, k, b, 2)  # time, intention, env, feature
    major = np.asarray(intention_major(jnp.asarray(x)))
    assert major.shape == (k, t * b, 2)
    # Row k holds intention k's samples, time-major within the row: sample s = (time s // b,
    # env s % b).
    for i in range(k):
        for s in range(t * b):
            np.testing.assert_array_equal(major[i, s], x[s // b, i, s % b])
    np.testing.assert_array_equal(time_major(jnp.asarray(major), t), x)


def test_rollout_and_episode_totals_are_the_same_jitted_and_not():
    env = envs.wrap_for_training(_Counter(), 4)
    state = batch_reset(env, jax.random.PRNGKey(2), (K, B))

    def go(state, key):
        end, transitions = rollout(env, uniform_random_policy(env), state, key, 6)
        return end, transitions, episode_totals(transitions, jnp.ones((K, B)))

    eager = go(state, jax.random.PRNGKey(3))
    jitted = jax.jit(go)(state, jax.random.PRNGKey(3))
    for a, b in zip(jax.tree.leaves(eager), jax.tree.leaves(jitted), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-6)
