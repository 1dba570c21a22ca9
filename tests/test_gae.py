"""Generalised advantage estimation against hand-computed values and a plain Python loop."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from emgail_jax.method.gae import absorbing_value, generalized_advantages
from emgail_jax.method.rollout import steps_left


def reference_gae(rewards, values, dones, bootstrap, gamma, lam):
    """The textbook backward recursion, one time step at a time in Python."""
    rewards, values, dones = (np.asarray(x, np.float64) for x in (rewards, values, dones))
    advantages = np.zeros_like(rewards)
    carry = np.zeros_like(np.asarray(bootstrap, np.float64))
    next_value = np.asarray(bootstrap, np.float64)
    for t in reversed(range(len(rewards))):
        cont = 1.0 - dones[t]
        delta = rewards[t] + gamma * next_value * cont - values[t]
        carry = delta + gamma * lam * cont * carry
        advantages[t] = carry
        next_value = values[t]
    return advantages, advantages + values


def test_hand_computed_four_steps_with_done_in_the_middle():
    # gamma = 0.9, lambda = 0.5, the episode ends with transition 1 (index from 0).
    rewards = jnp.array([1.0, 2.0, 3.0, 4.0])
    values = jnp.array([0.5, 1.0, 1.5, 2.0])
    dones = jnp.array([0.0, 1.0, 0.0, 0.0])
    bootstrap = jnp.array(3.0)
    # deltas: 1 + .9*1.0 - .5 = 1.4 ; 2 + 0 - 1 = 1.0 (done) ; 3 + .9*2 - 1.5 = 3.3 ;
    #         4 + .9*3 - 2 = 4.7 (bootstrapped from V = 3)
    # advantages (gamma*lambda = 0.45): A3 = 4.7 ; A2 = 3.3 + .45*4.7 = 5.415 ;
    #         A1 = 1.0 (done cuts the recursion) ; A0 = 1.4 + .45*1.0 = 1.85
    advantages, returns = generalized_advantages(rewards, values, dones, bootstrap, 0.9, 0.5)
    np.testing.assert_allclose(advantages, [1.85, 1.0, 5.415, 4.7], rtol=1e-6)
    np.testing.assert_allclose(returns, [2.35, 2.0, 6.915, 6.7], rtol=1e-6)


def test_hand_computed_three_steps_lambda_zero_is_td_error():
    rewards = jnp.array([1.0, 0.0, -1.0])
    values = jnp.array([2.0, 1.0, 0.0])
    dones = jnp.array([0.0, 0.0, 1.0])
    # lambda = 0: A_t = r_t + gamma V_{t+1} (1 - done_t) - V_t with gamma = 0.5:
    # 1 + .5*1 - 2 = -0.5 ; 0 + .5*0 - 1 = -1 ; -1 + 0 (done, bootstrap ignored) - 0 = -1
    advantages, _ = generalized_advantages(rewards, values, dones, jnp.array(100.0), 0.5, 0.0)
    np.testing.assert_allclose(advantages, [-0.5, -1.0, -1.0], rtol=1e-6)


@pytest.mark.parametrize(("gamma", "lam"), [(0.995, 0.97), (0.9, 0.0), (0.99, 1.0), (1.0, 0.5)])
def test_matches_python_loop_on_random_data(gamma, lam):
    rng = np.random.default_rng(0)
    t, k, b = 13, 2, 3
    rewards = rng.normal(size=(t, k, b)).astype(np.float32)
    values = rng.normal(size=(t, k, b)).astype(np.float32)
    dones = (rng.random((t, k, b)) < 0.2).astype(np.float32)
    bootstrap = rng.normal(size=(k, b)).astype(np.float32)
    advantages, returns = generalized_advantages(
        jnp.asarray(rewards),
        jnp.asarray(values),
        jnp.asarray(dones),
        jnp.asarray(bootstrap),
        gamma,
        lam,
    )
    assert advantages.shape == returns.shape == (t, k, b)
    expected_adv, expected_ret = reference_gae(rewards, values, dones, bootstrap, gamma, lam)
    np.testing.assert_allclose(advantages, expected_adv, rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(returns, expected_ret, rtol=1e-4, atol=1e-4)


def test_lambda_one_gives_discounted_returns_minus_values():
    rng = np.random.default_rng(1)
    t, b, gamma = 9, 4, 0.8
    rewards = rng.normal(size=(t, b))
    values = rng.normal(size=(t, b))
    dones = np.zeros((t, b))
    dones[3, 0] = dones[6, 2] = dones[8, 3] = 1.0
    bootstrap = rng.normal(size=b)
    # Monte-Carlo returns, cut at episode ends and bootstrapped at the end of the rollout.
    discounted = np.zeros((t, b))
    following = bootstrap.copy()
    for i in reversed(range(t)):
        following = rewards[i] + gamma * (1.0 - dones[i]) * following
        discounted[i] = following
    advantages, returns = generalized_advantages(
        *(jnp.asarray(x, jnp.float32) for x in (rewards, values, dones, bootstrap)), gamma, 1.0
    )
    np.testing.assert_allclose(advantages, discounted - values, rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(returns, discounted, rtol=1e-4, atol=1e-4)


def test_jit_matches_eager():
    rng = np.random.default_rng(2)
    rewards, values = (jnp.asarray(rng.normal(size=(6, 5)), jnp.float32) for _ in range(2))
    dones = jnp.asarray(rng.random((6, 5)) < 0.3, jnp.float32)
    bootstrap = jnp.asarray(rng.normal(size=5), jnp.float32)
    eager = generalized_advantages(rewards, values, dones, bootstrap, 0.99, 0.95)
    jitted = jax.jit(generalized_advantages, static_argnums=(4, 5))(
        rewards, values, dones, bootstrap, 0.99, 0.95
    )
    for a, b in zip(eager, jitted, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("jit", [False, True])
def test_an_absorbing_state_bootstraps_the_terminating_transition_hand_computed(jit):
    """The four steps above, transition 1 a termination with 2 steps left to the time limit,
    into an absorbing state of reward -1: its return is 2 - (0.9 + 0.81)."""
    rewards = jnp.array([1.0, 2.0, 3.0, 4.0])
    values = jnp.array([0.5, 1.0, 1.5, 2.0])
    dones = jnp.array([0.0, 1.0, 0.0, 0.0])
    # V of the absorbing state with 2 steps left: -1 * (1 + 0.9) = -1.9, read at done only.
    end_values = jnp.array([7.0, -1.9, 7.0, 7.0])
    # delta1 = 2 + .9 * -1.9 - 1 = -0.71 ; A1 = -0.71 (done still cuts the recursion) ;
    # A0 = 1.4 + .45 * -0.71 = 1.0805 ; A2, A3 as without it.
    gae = jax.jit(generalized_advantages, static_argnums=(4, 5)) if jit else generalized_advantages
    advantages, returns = gae(
        rewards, values, dones, jnp.array(3.0), 0.9, 0.5, end_values=end_values
    )
    np.testing.assert_allclose(advantages, [1.0805, -0.71, 5.415, 4.7], rtol=1e-6)
    np.testing.assert_allclose(returns, [1.5805, 0.29, 6.915, 6.7], rtol=1e-6)


@pytest.mark.parametrize("jit", [False, True])
def test_absorbing_value_is_the_reward_of_every_step_left_discounted(jit):
    left = jnp.array([0, 1, 3])
    value = jax.jit(absorbing_value, static_argnums=2) if jit else absorbing_value
    # gamma 0.5: 2 * (0, 1, 1 + .5 + .25); gamma 1: 2 * (0, 1, 3)
    np.testing.assert_allclose(value(jnp.float32(2.0), left, 0.5), [0.0, 2.0, 3.5], rtol=1e-6)
    np.testing.assert_allclose(value(jnp.array([2.0]), left, 1.0), [0.0, 2.0, 6.0], rtol=1e-6)


def test_a_truncation_gets_no_absorbing_value():
    """An episode that ends at its time limit (here 4 steps: the transition taken at t = 3/4)
    has no step left to stay absorbed: its return is the same with or without the absorbing
    state, to the bit, while a termination's (t = 1/4) is not."""
    rewards = jnp.array([1.0, 2.0, 3.0, 4.0])
    values = jnp.array([0.5, 1.0, 1.5, 2.0])
    time = jnp.array([0.5, 0.75, 0.0, 0.25])
    truncated = jnp.array([0.0, 1.0, 0.0, 0.0])
    ends = absorbing_value(jnp.float32(-5.0), steps_left(time, 4), 0.9)
    np.testing.assert_allclose(ends, [-5.0, 0.0, -5.0 * (1 + 0.9 + 0.81), -5.0 * 1.9], rtol=1e-6)
    gae = lambda dones, end_values=None: generalized_advantages(
        rewards, values, dones, jnp.array(3.0), 0.9, 0.5, end_values=end_values
    )
    for with_end, without in zip(gae(truncated, ends), gae(truncated), strict=True):
        np.testing.assert_array_equal(with_end, without)
    terminated = jnp.array([0.0, 0.0, 0.0, 1.0])
    assert not np.array_equal(gae(terminated, ends)[1], gae(terminated)[1])
