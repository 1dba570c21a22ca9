"""A network's parameters with its optimiser state, and the E- and M-step's full-batch steps."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import optax
from flax import struct


@struct.dataclass
class Learner:
    """The parameters of one network and the state of the optimiser that trains them."""

    params: Any
    opt_state: Any

    @classmethod
    def create(cls, params, optimizer: optax.GradientTransformation) -> Learner:
        return cls(params, optimizer.init(params))


def minimize(
    loss: Callable, optimizer: optax.GradientTransformation, learner: Learner, steps: int
) -> tuple[Learner, dict]:
    """``steps`` optimizer steps on ``loss(params) -> (scalar, metrics)``.

    Returns the trained learner and the metrics of the first step, i.e. measured before this
    update moved the parameters (what the data said about the previous ones).
    """
    grad_fn = jax.value_and_grad(loss, has_aux=True)

    def step(learner, _):
        (_, metrics), grads = grad_fn(learner.params)
        updates, opt_state = optimizer.update(grads, learner.opt_state, learner.params)
        return Learner(optax.apply_updates(learner.params, updates), opt_state), metrics

    learner, metrics = jax.lax.scan(step, learner, None, length=steps)
    return learner, jax.tree.map(lambda m: m[0], metrics)
