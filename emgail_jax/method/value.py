"""Fitting the value baseline V(s, i, t) to the GAE returns (regression with Adam)."""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import optax

from emgail_jax.method.optim import Learner


def value_loss(predict: Callable, params, inputs, targets: jax.Array) -> jax.Array:
    """Mean squared error of ``predict(params, *inputs) [...]`` against ``targets [...]``."""
    return jnp.mean((predict(params, *inputs) - targets) ** 2)


def fit_value(
    predict: Callable,
    optimizer: optax.GradientTransformation,
    value: Learner,
    inputs: tuple[jax.Array, ...],
    targets: jax.Array,
    key: jax.Array,
    *,
    epochs: int,
    minibatches: int,
):
    """Epochs of shuffled minibatch Adam steps on the value loss.

    ``inputs`` and ``targets`` have leading dimensions ``[G, M]``: G groups (the intentions, in
    the layout of :func:`~emgail_jax.method.rollout.intention_major`) of M samples, shuffled
    along M, so that every minibatch holds the same number of samples of every group.
    Returns the fitted learner and the loss before and after.
    """
    n = targets.shape[1]
    size = n // minibatches
    grad_fn = jax.value_and_grad(lambda p, x, y: value_loss(predict, p, x, y))

    def minibatch_step(learner, index):
        batch_inputs = tuple(x[:, index] for x in inputs)
        loss, grads = grad_fn(learner.params, batch_inputs, targets[:, index])
        updates, opt_state = optimizer.update(grads, learner.opt_state, learner.params)
        return Learner(optax.apply_updates(learner.params, updates), opt_state), loss

    def epoch(carry, epoch_key):
        order = jax.random.permutation(epoch_key, n)[: size * minibatches]
        return jax.lax.scan(minibatch_step, carry, order.reshape(minibatches, size))

    before = value_loss(predict, value.params, inputs, targets)
    value, _ = jax.lax.scan(epoch, value, jax.random.split(key, epochs))
    after = value_loss(predict, value.params, inputs, targets)
    return value, {"value/loss_before": before, "value/loss": after}
