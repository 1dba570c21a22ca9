"""Generalised advantage estimation against hand-computed values and a plain Python loop."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from emgail_jax.method.gae import generalized_advantages


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
