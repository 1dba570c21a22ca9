"""Fitting the value baseline V(s, i, t) to the GAE returns (regression with Adam).

With target scaling the network predicts V standardised by the running mean and variance of
every target it was fitted to, so that a reward far from 0 per step (a learned log D near -1
over a thousand steps) needs no output of hundreds that Adam's small steps take hundreds of
iterations to reach (see docs/defaults.md, ``value_target_scaling``). Its losses are then
in standardised units.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import optax
from flax import struct

from emgail_jax.method import normalizer as running
from emgail_jax.method.optim import Learner


@struct.dataclass
class ValueLearner(Learner):
    """The value network's learner; ``targets``: the running statistics ``[1]`` of the targets
    it was fitted to when it predicts them standardised, None when it predicts them raw."""

    targets: running.RunningStats | None = None

    @classmethod
    def create(
        cls, params, optimizer: optax.GradientTransformation, target_scaling: bool = False
    ) -> ValueLearner:
        stats = running.RunningStats.create(1) if target_scaling else None
        return cls(params, optimizer.init(params), stats)

    def values(self, raw: jax.Array) -> jax.Array:
        """V ``[...]`` from the network's output ``raw [...]``."""
        if self.targets is None:
            return raw
        return raw * jnp.sqrt(self.targets.var[0] + 1e-8) + self.targets.mean[0]

    def fitting_targets(self, targets: jax.Array) -> tuple[ValueLearner, jax.Array]:
        """The learner with ``targets [...]`` in its statistics, and what the network is
        fitted to: ``targets`` standardised by them (unchanged without scaling)."""
        if self.targets is None:
            return self, targets
        stats = running.update(self.targets, targets[..., None])
        standardised = (targets - stats.mean[0]) / jnp.sqrt(stats.var[0] + 1e-8)
        return self.replace(targets=stats), standardised


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
        params = optax.apply_updates(learner.params, updates)
        return learner.replace(params=params, opt_state=opt_state), loss

    def epoch(carry, epoch_key):
        order = jax.random.permutation(epoch_key, n)[: size * minibatches]
        return jax.lax.scan(minibatch_step, carry, order.reshape(minibatches, size))

    before = value_loss(predict, value.params, inputs, targets)
    value, _ = jax.lax.scan(epoch, value, jax.random.split(key, epochs))
    after = value_loss(predict, value.params, inputs, targets)
    return value, {"value/loss_before": before, "value/loss": after}
