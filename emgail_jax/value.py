"""Fitting the value baseline V(s, i, t) to the GAE returns (regression with Adam)."""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import optax


def value_loss(predict: Callable, params, inputs, targets: jax.Array) -> jax.Array:
    """Mean squared error of ``predict(params, *inputs) [...]`` against ``targets [...]``."""
    return jnp.mean((predict(params, *inputs) - targets) ** 2)


def fit_value(
    predict: Callable,
    optimizer: optax.GradientTransformation,
    params,
    opt_state,
    inputs: tuple[jax.Array, ...],
    targets: jax.Array,
    key: jax.Array,
    epochs: int,
    minibatches: int,
):
    """Epochs of shuffled minibatch Adam steps on the value loss.

    ``inputs`` and ``targets`` have leading dimensions ``[G, M]``: G groups (the intentions, in
    the layout of :func:`~emgail_jax.rollout.intention_major`) of M samples, shuffled along M,
    so that every minibatch holds the same number of samples of every group.
    Returns ``(params, opt_state, metrics)``.
    """
    n = targets.shape[1]
    size = n // minibatches
    grad_fn = jax.value_and_grad(lambda p, x, y: value_loss(predict, p, x, y))

    def minibatch_step(carry, index):
        params, opt_state = carry
        batch_inputs = tuple(x[:, index] for x in inputs)
        loss, grads = grad_fn(params, batch_inputs, targets[:, index])
        updates, opt_state = optimizer.update(grads, opt_state, params)
        return (optax.apply_updates(params, updates), opt_state), loss

    def epoch(carry, epoch_key):
        order = jax.random.permutation(epoch_key, n)[: size * minibatches]
        return jax.lax.scan(minibatch_step, carry, order.reshape(minibatches, size))

    before = value_loss(predict, params, inputs, targets)
    (params, opt_state), _ = jax.lax.scan(epoch, (params, opt_state), jax.random.split(key, epochs))
    after = value_loss(predict, params, inputs, targets)
    return params, opt_state, {"value/loss_before": before, "value/loss": after}
