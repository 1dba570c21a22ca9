"""The B-step: GAE on the rollout, advantages standardised per intention, one TRPO step and a
refit of the value baseline, wired together as written out here by hand."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from emgail_jax.method.b_step import PolicySamples, make_b_step
from emgail_jax.method.config import BStepConfig
from emgail_jax.method.gae import generalized_advantages
from emgail_jax.method.networks import GaussianPolicy, ValueNet, action_distribution
from emgail_jax.method.rollout import intention_major, time_major
from emgail_jax.method.trpo import trpo_step
from emgail_jax.method.value import ValueLearner, fit_value

T, K, B, D, A = 4, 2, 3, 3, 2


@pytest.fixture(scope="module")
def problem():
    keys = jax.random.split(jax.random.PRNGKey(0), 8)
    condition = jnp.broadcast_to(jnp.eye(K)[None, :, None, :], (T, K, B, K))
    samples = PolicySamples(
        obs=jax.random.normal(keys[0], (T, K, B, D)),
        action=jax.random.normal(keys[1], (T, K, B, A)),
        condition=condition,
        time=jnp.broadcast_to(jnp.arange(T)[:, None, None] / 10.0, (T, K, B)),
        done=jnp.zeros((T, K, B)).at[1].set(1.0),
        last_obs=jax.random.normal(keys[2], (K, B, D)),
        last_condition=condition[0],
        last_time=jnp.full((K, B), T / 10.0),
    )
    # Intention 1's reward is 100 times intention 0's: per-intention standardisation.
    reward = jax.random.normal(keys[3], (T, K, B)) * jnp.array([1.0, 100.0])[None, :, None]
    policy_net, value_net = GaussianPolicy(A, (8,), heads=True), ValueNet((8,), heads=True)
    policy = policy_net.init(keys[4], samples.obs[0, 0], samples.condition[0, 0])
    value = value_net.init(keys[5], samples.obs[0, 0], samples.condition[0, 0], samples.time[0, 0])
    config = BStepConfig(value_epochs=3, value_minibatches=2)
    return samples, reward, policy_net, value_net, policy, value, config, keys[6]


@pytest.mark.parametrize("absorbing", [False, True])
def test_b_step_is_gae_then_standardised_trpo_then_value_fit(problem, absorbing):
    """With ``end_values`` (an absorbing state's), GAE bootstraps the episodes' ends from
    them."""
    samples, reward, policy_net, value_net, policy, value, config, key = problem
    end_values = jnp.full((T, K, B), -30.0) if absorbing else None
    optimizer = optax.adam(1e-3)
    b_step = jax.jit(make_b_step(policy_net.apply, value_net.apply, optimizer, config))
    result = b_step(policy, ValueLearner.create(value, optimizer), samples, reward, key, end_values)
    expected_policy, expected_value, _ = jax.jit(by_hand, static_argnums=(0, 1, 2))(
        policy_net, value_net, config, policy, value, samples, reward, key, end_values
    )
    for got, want in zip(
        jax.tree.leaves((result.policy, result.value)),
        jax.tree.leaves((expected_policy, expected_value)),
        strict=True,
    ):
        np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-7)
    # The value fit took epochs x minibatches Adam steps; the policy moved.
    assert int(result.value.opt_state[0].count) == config.value_epochs * config.value_minibatches
    policies = zip(jax.tree.leaves(policy), jax.tree.leaves(result.policy), strict=True)
    assert any(not np.allclose(a, b) for a, b in policies)
    assert {"policy/kl", "value/loss", "value/loss_before"} <= set(result.metrics)


def by_hand(
    policy_net, value_net, config, policy, value, samples, reward, key, end_values=None, scale=None
):
    """The B-step written out from its parts; ``scale(returns) -> targets`` the value's."""
    optimizer = optax.adam(1e-3)
    obs, action, condition, time = map(
        intention_major, (samples.obs, samples.action, samples.condition, samples.time)
    )
    predict = lambda p, *x: value_net.apply(p, *x, intention_major=True)
    bootstrap = predict(value, samples.last_obs, samples.last_condition, samples.last_time)
    advantages, returns = generalized_advantages(
        reward,
        time_major(predict(value, obs, condition, time), T),
        samples.done,
        bootstrap,
        config.gamma,
        config.gae_lambda,
        end_values=end_values,
    )
    advantages = intention_major(advantages)
    advantages = (advantages - advantages.mean(1, keepdims=True)) / (
        advantages.std(1, keepdims=True) + 1e-8
    )
    distribution = lambda p: action_distribution(
        *policy_net.apply(p, obs, condition, intention_major=True)
    )
    expected_policy, _ = trpo_step(distribution, policy, action, advantages, config.trpo)
    expected_value, _ = fit_value(
        predict,
        optimizer,
        ValueLearner.create(value, optimizer),
        (obs, condition, time),
        intention_major(returns) if scale is None else scale(intention_major(returns)),
        key,
        epochs=config.value_epochs,
        minibatches=config.value_minibatches,
    )
    return expected_policy, expected_value, returns


def test_b_step_refuses_a_reward_of_another_shape(problem):
    samples, reward, policy_net, value_net, policy, value, config, key = problem
    optimizer = optax.adam(1e-3)
    b_step = make_b_step(policy_net.apply, value_net.apply, optimizer, config)
    with pytest.raises(AssertionError):
        b_step(policy, ValueLearner.create(value, optimizer), samples, reward[:, :, :2], key)


@pytest.mark.slow  # op-by-op TRPO and value fit; test_skeleton runs it eagerly on a smaller net
def test_b_step_is_the_same_jitted_and_not(problem):
    samples, reward, policy_net, value_net, policy, value, config, key = problem
    optimizer = optax.adam(1e-3)
    b_step = make_b_step(policy_net.apply, value_net.apply, optimizer, config)
    learner = ValueLearner.create(value, optimizer)
    eager = b_step(policy, learner, samples, reward, key)
    jitted = jax.jit(b_step)(policy, learner, samples, reward, key)
    # CG on this nearly singular Fisher and Adam's division by small gradients magnify
    # roundoff: op by op and fused, the parameters agree to about one percent.
    for a, b in zip(jax.tree.leaves(eager), jax.tree.leaves(jitted), strict=True):
        np.testing.assert_allclose(a, b, rtol=2e-2, atol=1e-4)


def test_scaled_value_targets_change_the_value_fit_alone(problem):
    """A fresh scaled value (mean 0, variance 1) predicts what an unscaled one does, so the
    policy moves as it would; the value is fitted to the returns standardised by their mean
    and variance, which its statistics now hold."""
    samples, reward, policy_net, value_net, policy, value, config, key = problem
    optimizer = optax.adam(1e-3)
    config = dataclasses.replace(config, value_target_scaling=True)
    b_step = jax.jit(make_b_step(policy_net.apply, value_net.apply, optimizer, config))
    start = ValueLearner.create(value, optimizer, target_scaling=True)
    result = b_step(policy, start, samples, reward, key)
    written_out = jax.jit(by_hand, static_argnums=(0, 1, 2), static_argnames="scale")
    returns = written_out(policy_net, value_net, config, policy, value, samples, reward, key)[2]
    mean, var = float(returns.mean()), float(returns.var())
    standardise = lambda targets: (targets - mean) / np.sqrt(var + 1e-8)
    expected_policy, expected_value, _ = written_out(
        policy_net, value_net, config, policy, value, samples, reward, key, scale=standardise
    )
    np.testing.assert_allclose(result.value.targets.mean, [mean], rtol=1e-5)
    np.testing.assert_allclose(result.value.targets.var, [var], rtol=1e-5)
    assert float(result.value.targets.count) == T * K * B
    expected = jax.tree.leaves((expected_policy, expected_value.params))
    for got, want in zip(
        jax.tree.leaves((result.policy, result.value.params)), expected, strict=True
    ):
        np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-6)
