"""Full-batch minimisation shared by the E-step and the M-step."""

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from emgail_jax.optim import minimize

TARGET = jnp.array([1.0, -2.0, 0.5])


def quadratic(params):
    """0.5 |x - c|^2, reporting the loss and x itself as metrics."""
    loss = 0.5 * jnp.sum((params["x"] - TARGET) ** 2)
    return loss, {"loss": loss, "x0": params["x"][0]}


def test_sgd_on_a_quadratic_contracts_by_one_minus_the_learning_rate():
    # Gradient x - c, so one SGD step maps x - c to (1 - lr)(x - c): after n steps the error
    # is (1 - lr)^n of the initial one.
    lr, steps = 0.25, 6
    optimizer = optax.sgd(lr)
    params = {"x": jnp.zeros(3)}
    new, _, _ = minimize(quadratic, optimizer, params, optimizer.init(params), steps)
    expected = TARGET + (1 - lr) ** steps * (0.0 - TARGET)
    np.testing.assert_allclose(new["x"], expected, rtol=1e-6)


def test_metrics_are_those_of_the_first_step():
    optimizer = optax.sgd(0.5)
    params = {"x": jnp.array([3.0, 0.0, 0.0])}
    _, _, metrics = minimize(quadratic, optimizer, params, optimizer.init(params), 4)
    # Measured at the initial parameters: 0.5 * ((3 - 1)^2 + 2^2 + 0.5^2) = 4.125.
    assert float(metrics["loss"]) == pytest.approx(4.125)
    assert float(metrics["x0"]) == 3.0
    assert metrics["loss"].shape == ()


def test_adam_reduces_the_loss_and_advances_its_state():
    optimizer = optax.adam(0.1)
    params = {"x": jnp.zeros(3)}
    state = optimizer.init(params)
    before = float(quadratic(params)[0])
    new, new_state, metrics = jax.jit(lambda p, s: minimize(quadratic, optimizer, p, s, 50))(
        params, state
    )
    assert float(metrics["loss"]) == pytest.approx(before)
    assert float(quadratic(new)[0]) < 0.05 * before
    assert int(new_state[0].count) == 50
    # Continuing from the returned state is the same as one longer minimisation.
    more, _, second = minimize(quadratic, optimizer, new, new_state, 10)
    once, _, _ = minimize(quadratic, optimizer, params, state, 60)
    np.testing.assert_allclose(more["x"], once["x"], rtol=1e-5)
    assert float(second["loss"]) == pytest.approx(float(quadratic(new)[0]), rel=1e-5)


def test_one_step_equals_a_hand_written_optimizer_step():
    optimizer = optax.sgd(0.1)
    params = {"x": jnp.array([2.0, 2.0, 2.0])}
    new, _, _ = minimize(quadratic, optimizer, params, optimizer.init(params), 1)
    np.testing.assert_allclose(new["x"], params["x"] - 0.1 * (params["x"] - TARGET), rtol=1e-6)
