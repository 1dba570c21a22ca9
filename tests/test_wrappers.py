"""EpisodeWrapper (time limit) and AutoResetWrapper (fresh episode after done) on the driver."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from envs.core import State

LENGTH = 4


@pytest.fixture(scope="module")
def driver():
    return envs.make("driver", intentions=2)


def run(env, key, steps, action=0.2):
    """``steps`` jitted steps with a constant action; returns the reset state and every
    following state, stacked ``[steps, ...]``."""

    @jax.jit
    def go(key):
        state = env.reset(key)

        def body(state, _):
            state = env.step(state, jnp.array([action]))
            return state, state

        return state, jax.lax.scan(body, state, None, length=steps)[1]

    return go(key)


def test_wrapper_delegates_properties_and_extras(driver):
    wrapped = envs.wrap_for_training(driver, LENGTH)
    assert isinstance(wrapped, envs.AutoResetWrapper)
    assert isinstance(wrapped.env, envs.EpisodeWrapper)
    assert wrapped.unwrapped is driver
    assert wrapped.num_intentions == 2 and wrapped.observation_size == 10
    assert wrapped.action_size == 1 and wrapped.name == "driver"
    assert wrapped.episode_length == LENGTH  # the wrapper's limit, not the env's 100
    assert envs.wrap_for_training(driver).episode_length == driver.episode_length
    # Env-specific extras (the analytic expert) are reachable through the wrappers.
    state = wrapped.reset(jax.random.PRNGKey(0))
    action = wrapped.expert_action(state, jnp.asarray(1))
    np.testing.assert_allclose(action, driver.expert_action(state, jnp.asarray(1)))


def test_episode_wrapper_ends_episode_at_its_length(driver):
    env = envs.EpisodeWrapper(driver, LENGTH)
    first, states = run(env, jax.random.PRNGKey(0), LENGTH + 2)
    assert int(first.info["steps"]) == 0 and float(first.done) == 0.0
    np.testing.assert_array_equal(states.info["steps"], [1, 2, 3, 4, 5, 6])
    # Done exactly from step LENGTH on, and it was the time limit (truncation 1), not the env.
    np.testing.assert_array_equal(states.done, [0, 0, 0, 1, 1, 1])
    np.testing.assert_array_equal(states.info["truncation"], [0, 0, 0, 1, 1, 1])
    # The wrapper does not change the dynamics.
    _, raw = run(driver, jax.random.PRNGKey(0), LENGTH + 2)
    np.testing.assert_allclose(states.obs, raw.obs, rtol=1e-6)
    np.testing.assert_allclose(states.reward, raw.reward, rtol=1e-6)


class _Terminating(envs.Env):
    """A 1-D counter that terminates on its own when it reaches 2 (to tell termination from
    truncation)."""

    name = "counter"
    intention_names = ("count",)
    observation_size = 1
    action_size = 1
    episode_length = 10

    def reset(self, key):
        return State(
            physics=jnp.zeros(()), obs=jnp.zeros(1), reward=jnp.zeros(1), done=jnp.zeros(())
        )

    def step(self, state, action):
        count = state.physics + 1
        return state.replace(
            physics=count, obs=count[None], reward=jnp.ones(1), done=(count >= 2).astype(float)
        )


def test_episode_wrapper_termination_is_not_truncation():
    env = envs.EpisodeWrapper(_Terminating(), episode_length=2)
    state = env.step(env.step(env.reset(jax.random.PRNGKey(0)), jnp.zeros(1)), jnp.zeros(1))
    # The env itself ended the episode at the very step the time limit was reached.
    assert float(state.done) == 1.0
    assert float(state.info["truncation"]) == 0.0


def test_auto_reset_starts_a_new_episode_after_done(driver):
    env = envs.wrap_for_training(driver, LENGTH)
    limited = envs.EpisodeWrapper(driver, LENGTH)
    key = jax.random.PRNGKey(5)
    first, states = run(env, key, 2 * LENGTH + 1)
    _, reference = run(limited, jax.random.split(key)[0], LENGTH)  # the first episode alone
    # Reward and done of the last transition of episode 1 are kept ...
    np.testing.assert_allclose(states.reward[:LENGTH], reference.reward, rtol=1e-6)
    np.testing.assert_array_equal(states.done[: 2 * LENGTH], [0, 0, 0, 1, 0, 0, 0, 1])
    # ... while the state is already the first state of episode 2: a new random initial state.
    np.testing.assert_allclose(states.obs[: LENGTH - 1], reference.obs[: LENGTH - 1], rtol=1e-6)
    second_start = states.obs[LENGTH - 1]
    assert not np.allclose(second_start, reference.obs[LENGTH - 1], atol=1e-3)
    assert not np.allclose(second_start, first.obs, atol=1e-3)
    assert int(states.info["steps"][LENGTH - 1]) == 0
    # It is a proper initial state: history extrapolated backwards at constant spacing.
    history = np.asarray(second_start).reshape(5, 2)
    spacing = np.linalg.norm(np.diff(history, axis=0), axis=1)
    np.testing.assert_allclose(spacing, driver.speed, rtol=1e-4)
    # Episode 2 runs its full length; without a refresh the third episode starts where the
    # second did (the start drawn in advance is kept) ...
    np.testing.assert_array_equal(states.info["steps"][LENGTH : 2 * LENGTH], [1, 2, 3, 0])
    np.testing.assert_allclose(states.obs[2 * LENGTH - 1], second_start)


def test_auto_reset_refresh_draws_a_new_start(driver):
    env = envs.wrap_for_training(driver, LENGTH)
    state = env.reset(jax.random.PRNGKey(5))
    planned = state.info["next_start"].obs
    refreshed = env.refresh(state, jax.random.PRNGKey(6))
    assert not np.allclose(refreshed.info["next_start"].obs, planned, atol=1e-3)
    np.testing.assert_array_equal(refreshed.obs, state.obs)  # the current episode is untouched
    new_start = refreshed.info["next_start"].obs
    for _ in range(LENGTH):
        refreshed = env.step(refreshed, jnp.zeros(1))
    # After the episode ends, the next one begins from the refreshed start.
    np.testing.assert_allclose(refreshed.obs, new_start)
