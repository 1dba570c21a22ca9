"""Full-batch minimisation shared by the E-step and the M-step, on a learner."""

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from emgail_jax.method.optim import Learner, minimize

TARGET = jnp.array([1.0, -2.0, 0.5])


def quadratic(params):
    """0.5 |x - c|^2, reporting the loss and x itself as metrics."""
    loss = 0.5 * jnp.sum((params["x"] - TARGET) ** 2)
    return loss, {"loss": loss, "x0": params["x"][0]}


def learner(optimizer, x):
    return Learner.create({"x": jnp.asarray(x, jnp.float32)}, optimizer)


def test_sgd_on_a_quadratic_contracts_by_one_minus_the_learning_rate():
    # Gradient x - c, so one SGD step maps x - c to (1 - lr)(x - c): after n steps the error
    # is (1 - lr)^n of the initial one.
    lr, steps = 0.25, 6
    optimizer = optax.sgd(lr)
    new, _ = minimize(quadratic, optimizer, learner(optimizer, jnp.zeros(3)), steps)
    expected = TARGET + (1 - lr) ** steps * (0.0 - TARGET)
    np.testing.assert_allclose(new.params["x"], expected, rtol=1e-6)


def test_metrics_are_those_of_the_first_step():
    optimizer = optax.sgd(0.5)
    _, metrics = minimize(quadratic, optimizer, learner(optimizer, [3.0, 0.0, 0.0]), 4)
    # Measured at the initial parameters: 0.5 * ((3 - 1)^2 + 2^2 + 0.5^2) = 4.125.
    assert float(metrics["loss"]) == pytest.approx(4.125)
    assert float(metrics["x0"]) == 3.0
    assert metrics["loss"].shape == ()


def test_adam_reduces_the_loss_and_advances_its_state():
    optimizer = optax.adam(0.1)
    start = learner(optimizer, jnp.zeros(3))
    before = float(quadratic(start.params)[0])
    new, metrics = jax.jit(lambda s: minimize(quadratic, optimizer, s, 50))(start)
    assert float(metrics["loss"]) == pytest.approx(before)
    assert float(quadratic(new.params)[0]) < 0.05 * before
    assert int(new.opt_state[0].count) == 50
    # Continuing from the returned learner is the same as one longer minimisation.
    more, second = minimize(quadratic, optimizer, new, 10)
    once, _ = minimize(quadratic, optimizer, start, 60)
    np.testing.assert_allclose(more.params["x"], once.params["x"], rtol=1e-5)
    assert float(second["loss"]) == pytest.approx(float(quadratic(new.params)[0]), rel=1e-5)


def test_one_step_equals_a_hand_written_optimizer_step():
    optimizer = optax.sgd(0.1)
    new, _ = minimize(quadratic, optimizer, learner(optimizer, [2.0, 2.0, 2.0]), 1)
    expected = 2.0 - 0.1 * (2.0 - TARGET)
    np.testing.assert_allclose(new.params["x"], expected, rtol=1e-6)
