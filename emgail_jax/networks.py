"""The four networks of the paper (§5.3): policy, value, discriminator and posterior.

All are 64-64 tanh MLPs. The intention enters the policy, the value and (for EM-GAIL) the
discriminator as a one-hot vector concatenated to the input, as in the paper; an unconditioned
network (GAIL's policy, Info/IntentionGAIL's discriminator) receives an empty vector instead, so
the same modules serve all three algorithms. Modules hold no data: parameters live in the
train state and are passed to ``apply``.
"""

from __future__ import annotations

from collections.abc import Sequence

import distrax
import flax.linen as nn
import jax
import jax.numpy as jnp


class MLP(nn.Module):
    """Tanh MLP whose last layer starts ``final_scale`` times smaller than a LeCun-normal one.

    Not the orthogonal initialiser common in RL code: its QR decomposition is a LAPACK call
    that deadlocks XLA:CPU when seeds are sharded over several host devices.
    """

    hidden: Sequence[int]
    out: int
    final_scale: float = 0.01

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        for width in self.hidden:
            x = nn.tanh(nn.Dense(width)(x))
        final_init = nn.initializers.variance_scaling(self.final_scale**2, "fan_in", "normal")
        return nn.Dense(self.out, kernel_init=final_init)(x)


class GaussianPolicy(nn.Module):
    """pi(a | s, i): mean from an MLP of (normalised obs, condition); state-independent log-std."""

    action_size: int
    hidden: Sequence[int] = (64, 64)
    init_log_std: float = 0.0

    @nn.compact
    def __call__(self, obs: jax.Array, condition: jax.Array) -> tuple[jax.Array, jax.Array]:
        mean = MLP(self.hidden, self.action_size)(jnp.concatenate([obs, condition], -1))
        log_std = self.param(
            "log_std", nn.initializers.constant(self.init_log_std), (self.action_size,)
        )
        return mean, jnp.broadcast_to(log_std, mean.shape)


class ValueNet(nn.Module):
    """V(s, i, t): the normalised time t/T is an input because the horizon is fixed."""

    hidden: Sequence[int] = (64, 64)

    @nn.compact
    def __call__(self, obs: jax.Array, condition: jax.Array, time: jax.Array) -> jax.Array:
        x = jnp.concatenate([obs, condition, time[..., None]], -1)
        return MLP(self.hidden, 1, final_scale=1.0)(x)[..., 0]


class Discriminator(nn.Module):
    """The logit f of D = sigmoid(f): f(s, a, i) for EM-GAIL, f(s, a) for the baselines."""

    hidden: Sequence[int] = (64, 64)

    @nn.compact
    def __call__(self, obs: jax.Array, action: jax.Array, condition: jax.Array) -> jax.Array:
        x = jnp.concatenate([obs, action, condition], -1)
        return MLP(self.hidden, 1, final_scale=1.0)(x)[..., 0]


class Posterior(nn.Module):
    """Logits of P(i | s, a) over the K intentions."""

    num_intentions: int
    hidden: Sequence[int] = (64, 64)

    @nn.compact
    def __call__(self, obs: jax.Array, action: jax.Array) -> jax.Array:
        x = jnp.concatenate([obs, action], -1)
        return MLP(self.hidden, self.num_intentions, final_scale=1.0)(x)


def action_distribution(mean: jax.Array, log_std: jax.Array) -> distrax.MultivariateNormalDiag:
    return distrax.MultivariateNormalDiag(mean, jnp.exp(log_std))
