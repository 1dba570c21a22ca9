"""The discriminator's gradient penalty (``--set discriminator_gradient_penalty=W``; 0, none,
by default): a regulariser of the M-step's loss, W times the mean squared norm of the logit's
input gradient, so that the learned reward does not grow steeply where the data lie."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import jax
import jax.numpy as jnp

from emgail_jax.method.discriminator import LossHook, LossInputs, expert_logits


def input_gradient_norms(apply: Callable, params, inputs: LossInputs) -> jax.Array:
    """The mean squared norm of d f / d(s, a) on the expert pairs (under each condition, weighted
    as in the loss) and on the policy samples, half each: a zero-centred penalty that keeps
    the logit, and so the reward, from growing steeply where the data lie."""
    expert_obs, expert_actions, expert_weights, conditions = inputs[:4]
    policy_obs, policy_actions, policy_conditions = inputs[4:]

    def squared(grads):
        return sum(jnp.sum(g**2, -1) for g in grads)

    real = []
    for c in range(conditions.shape[0]):  # K <= 4 heads, each pair's gradient under each
        one = lambda o, a, c=c: jnp.sum(expert_logits(apply, params, o, a, conditions)[:, c])
        real.append(squared(jax.grad(one, (0, 1))(expert_obs, expert_actions)))
    real = jnp.mean(jnp.sum(expert_weights * jnp.stack(real, -1), -1))
    fake_sum = lambda o, a: jnp.sum(apply(params, o, a, policy_conditions, intention_major=True))
    fake = jnp.mean(squared(jax.grad(fake_sum, (0, 1))(policy_obs, policy_actions)))
    return 0.5 * (real + fake)


@dataclass(frozen=True)
class GradientPenalty(LossHook):
    """``weight`` times :func:`input_gradient_norms` added to the loss. The norms read f alone,
    without a form's offsets."""

    weight: float

    def regulariser(self, apply: Callable, params, inputs: LossInputs):
        norms = input_gradient_norms(apply, params, inputs)
        return self.weight * norms, {"discriminator/gradient_norm": norms}
