"""LearnedRewardEnv: an env of this package paying a learned reward in place of its own, a
termination paid for every step left as the check's TRPO bootstraps it."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from falling import FALLS_AT, LENGTH, Falling, toy_reward

import envs
from emgail_jax.reward import LearnedRewardEnv


def _rollout(env, steps, action=0.5):
    """``(states before, states after)`` of ``steps`` jitted steps, stacked."""

    @jax.jit
    def go(key):
        def body(state, _):
            after = env.step(state, jnp.array([action]))
            return after, (state, after)

        return jax.lax.scan(body, env.reset(key), None, length=steps)[1]

    return go(jax.random.PRNGKey(0))


@pytest.mark.parametrize("gamma", [1.0, 0.9])
def test_intention_i_is_paid_its_learned_reward_and_a_fall_every_step_left(gamma):
    reward = toy_reward()
    env = LearnedRewardEnv(Falling(), reward, intention=1, gamma=gamma)
    before, after = _rollout(env, FALLS_AT)
    learned = reward(before.obs, jnp.full((FALLS_AT, 1), 0.5), 1)
    np.testing.assert_allclose(after.reward[:, 0], 1.0)  # intention 0 keeps the env's own
    np.testing.assert_allclose(after.reward[:-1, 1], learned[:-1], rtol=1e-6)
    left = LENGTH - FALLS_AT  # the steps the fall leaves after the last one taken
    discounted = sum(gamma**j for j in range(1, left + 1))
    np.testing.assert_allclose(after.reward[-1, 1], learned[-1] - 1.0 * discounted, rtol=1e-5)


def test_every_intention_is_paid_its_own_and_a_time_limit_pays_no_fall():
    reward = toy_reward()
    # The time limit (inside) ends the episode before the env falls: nothing is left to pay.
    env = LearnedRewardEnv(envs.EpisodeWrapper(Falling(), FALLS_AT - 1), reward, gamma=1.0)
    before, after = _rollout(env, FALLS_AT - 1)
    assert float(after.done[-1]) == 1.0
    actions = jnp.full((FALLS_AT - 1, 1), 0.5)
    for i in (0, 1):
        np.testing.assert_allclose(after.reward[:, i], reward(before.obs, actions, i), rtol=1e-6)


def test_the_count_of_steps_starts_anew_after_an_auto_reset():
    env = envs.wrap_for_training(LearnedRewardEnv(Falling(), toy_reward(), intention=0, gamma=1.0))
    _, after = _rollout(env, 2 * FALLS_AT)
    paid_falls = after.reward[FALLS_AT - 1 :: FALLS_AT, 0] - after.reward[0, 0]
    assert len(paid_falls) == 2
    np.testing.assert_allclose(paid_falls[0], paid_falls[1], rtol=1e-5)


def test_an_intention_the_env_does_not_have_is_refused():
    with pytest.raises(envs.EnvError, match=r"intention 2: the env has intentions 0\.\.1"):
        LearnedRewardEnv(Falling(), toy_reward(), intention=2)


def test_on_the_driver_it_pays_what_the_loaded_reward_pays(tiny_run):
    from emgail_jax.host.saved_run import SavedRun
    from emgail_jax.reward import load_reward

    reward = load_reward(str(tiny_run), seed=1)
    env = LearnedRewardEnv(SavedRun.open(str(tiny_run)).problem.env, reward, intention=1)
    before, after = _rollout(envs.wrap_for_training(env), 5, action=0.3)
    expected = reward(before.obs, jnp.full((5, 1), 0.3), 1)
    np.testing.assert_allclose(after.reward[:, 1], expected, rtol=1e-5, atol=1e-6)
