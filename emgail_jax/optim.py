"""Full-batch gradient steps, shared by the E-step (posterior) and the M-step (discriminator)."""

from __future__ import annotations

from collections.abc import Callable

import jax
import optax


def minimize(
    loss: Callable,
    optimizer: optax.GradientTransformation,
    params,
    opt_state,
    steps: int,
):
    """``steps`` optimizer steps on ``loss(params) -> (scalar, metrics)``.

    Returns ``(params, opt_state, metrics)`` with the metrics of the first step, i.e. measured
    before this update moved the parameters (what the data said about the previous ones).
    """
    grad_fn = jax.value_and_grad(loss, has_aux=True)

    def step(carry, _):
        params, opt_state = carry
        (_, metrics), grads = grad_fn(params)
        updates, opt_state = optimizer.update(grads, opt_state, params)
        return (optax.apply_updates(params, updates), opt_state), metrics

    (params, opt_state), metrics = jax.lax.scan(step, (params, opt_state), None, length=steps)
    return params, opt_state, jax.tree.map(lambda m: m[0], metrics)
