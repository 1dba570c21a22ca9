"""Fitting the value baseline V(s, i, t) to the GAE returns."""

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from emgail_jax.method.networks import ValueNet
from emgail_jax.method.optim import Learner
from emgail_jax.method.value import ValueLearner, fit_value, value_loss


def test_value_loss_hand_computed():
    predict = lambda w, x: w * x
    # Predictions 2 * (1, 2, 3) = (2, 4, 6) against (1, 4, 8): errors (1, 0, -2) -> MSE 5 / 3.
    loss = value_loss(predict, 2.0, (jnp.array([1.0, 2.0, 3.0]),), jnp.array([1.0, 4.0, 8.0]))
    assert float(loss) == pytest.approx(5.0 / 3.0)


@pytest.fixture(scope="module", params=[False, True], ids=["one-hot", "heads"])
def regression(request):
    """V(s, i, t) on a smooth toy target that depends on all three inputs; samples grouped by
    intention ``[K, M]`` as the B-step passes them."""
    k, m = 2, 32
    keys = jax.random.split(jax.random.PRNGKey(0), 3)
    obs = jax.random.normal(keys[0], (k, m, 3))
    condition = jnp.broadcast_to(jnp.eye(k)[:, None, :], (k, m, k))
    time = jax.random.uniform(keys[1], (k, m))
    targets = jnp.sin(obs[..., 0]) + 2.0 * condition[..., 1] - time + 1.0
    net = ValueNet(hidden=(16,), heads=request.param)
    params = net.init(keys[2], obs, condition, time)
    predict = lambda p, *inputs: net.apply(p, *inputs, intention_major=True)
    return predict, params, (obs, condition, time), targets


def test_fit_reduces_the_loss(regression):
    predict, params, inputs, targets = regression
    optimizer = optax.adam(1e-2)
    fit = jax.jit(
        lambda value, key: fit_value(
            predict, optimizer, value, inputs, targets, key, epochs=30, minibatches=4
        )
    )
    fitted, metrics = fit(Learner.create(params, optimizer), jax.random.PRNGKey(1))
    new_params, opt_state = fitted.params, fitted.opt_state
    before = float(value_loss(predict, params, inputs, targets))
    after = float(value_loss(predict, new_params, inputs, targets))
    assert float(metrics["value/loss_before"]) == pytest.approx(before, rel=1e-5)
    assert float(metrics["value/loss"]) == pytest.approx(after, rel=1e-5)
    assert after < 0.2 * before
    # 30 epochs x 4 minibatches = 120 Adam steps.
    assert int(opt_state[0].count) == 120


def test_fit_uses_whole_minibatches_when_m_is_not_divisible(regression):
    predict, params, inputs, targets = regression
    inputs = tuple(x[:, :10] for x in inputs)
    optimizer = optax.sgd(1e-2)
    fitted, metrics = fit_value(
        predict,
        optimizer,
        Learner.create(params, optimizer),
        inputs,
        targets[:, :10],
        jax.random.PRNGKey(2),
        epochs=2,
        minibatches=3,
    )
    assert all(np.all(np.isfinite(x)) for x in jax.tree.leaves(fitted.params))
    assert float(metrics["value/loss"]) < float(metrics["value/loss_before"])


def test_without_scaling_the_network_predicts_the_targets_themselves():
    learner = ValueLearner.create({"w": jnp.ones(2)}, optax.adam(1e-3))
    raw = jnp.array([[-3.0, 250.0]])
    assert learner.targets is None
    np.testing.assert_array_equal(learner.values(raw), raw)
    same, targets = learner.fitting_targets(raw)
    assert same is learner
    np.testing.assert_array_equal(targets, raw)


@pytest.mark.parametrize("jit", [False, True], ids=["eager", "jitted"])
def test_scaled_targets_are_standardised_by_every_target_seen(jit):
    learner = ValueLearner.create({"w": jnp.ones(2)}, optax.adam(1e-3), target_scaling=True)
    first, second = jnp.array([[-800.0, -400.0]]), jnp.array([[0.0, -400.0]])
    fitting = jax.jit(ValueLearner.fitting_targets) if jit else ValueLearner.fitting_targets
    learner, standardised = fitting(learner, first)
    # One batch: its own mean -600 and standard deviation 200.
    np.testing.assert_allclose(standardised, [[-1.0, 1.0]], rtol=1e-5)
    learner, standardised = fitting(learner, second)
    # Both batches: mean -400, variance (400^2 + 0 + 400^2 + 0) / 4 = 80000.
    std = np.sqrt(80000.0)
    np.testing.assert_allclose(standardised, [[400.0 / std, 0.0]], rtol=1e-5)
    # The network's output 1 is one standard deviation above the mean, in the targets' units.
    np.testing.assert_allclose(learner.values(jnp.ones(())), -400.0 + std, rtol=1e-5)


def test_scaling_fits_targets_far_from_zero_that_raw_adam_steps_cannot_reach(regression):
    """Targets of hundreds (a reward near -1 per step over a thousand steps): after the same
    Adam steps the network of raw targets is still far from them, the scaled one close, in
    the targets' units."""
    predict, params, inputs, targets = regression
    far = targets * 50.0 - 400.0
    optimizer = optax.adam(1e-3)
    loss = {}
    for scaling in (False, True):
        value = ValueLearner.create(params, optimizer, target_scaling=scaling)
        value, fitted_to = value.fitting_targets(far)
        value, _ = fit_value(
            predict,
            optimizer,
            value,
            inputs,
            fitted_to,
            jax.random.PRNGKey(3),
            epochs=30,
            minibatches=4,
        )
        error = value.values(predict(value.params, *inputs)) - far
        loss[scaling] = float(jnp.mean(error**2))
    # Scaled: most of the targets' spread explained; raw: still off by more than ten times it.
    spread = float(jnp.var(far))
    assert loss[True] < 0.5 * spread and loss[False] > 10.0 * spread
