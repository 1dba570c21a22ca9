"""The M-step (paper eq. 19 / 22) and the pseudo-reward the discriminator defines (eq. 20).

The discriminator outputs the logit f with D = sigmoid(f). Every loss term and the reward are
written in terms of f with softplus, which never overflows:
  -log D = softplus(-f),   -log(1 - D) = softplus(f).

One loss serves both forms of the paper. Each expert pair is scored under every discriminator
condition c with a weight w[n, c]: EM-GAIL's conditions are the K one-hot intentions and its
weights are the responsibilities gamma (eq. 19); the baselines' D(s, a) has a single, empty
condition with weight one (eq. 22). Policy samples are scored under their own condition only.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import optax

from emgail_jax.optim import minimize


def expert_logits(apply: Callable, params, obs, actions, conditions: jax.Array) -> jax.Array:
    """``[N, C]``: f(s, a, c) of every expert pair under every condition ``conditions [C, c]``
    (broadcast, so that a discriminator with one head per intention runs each head once)."""
    return apply(params, obs[None], actions[None], conditions[:, None, :], intention_major=True).T


def discriminator_loss(
    apply: Callable,
    params,
    expert_obs: jax.Array,
    expert_actions: jax.Array,
    expert_weights: jax.Array,
    conditions: jax.Array,
    policy_obs: jax.Array,
    policy_actions: jax.Array,
    policy_conditions: jax.Array,
):
    """Logistic loss: expert pairs are real, weighted over conditions; policy samples are fake.

    Args:
      expert_obs, expert_actions: ``[N, D]``, ``[N, A]`` (normalised observations).
      expert_weights: ``[N, C]`` weight of each expert pair under each condition.
      conditions: ``[C, c]`` the discriminator conditions (one-hot rows, or one empty row).
      policy_obs, policy_actions, policy_conditions: ``[C, M, D]``, ``[C, M, A]``,
        ``[C, M, c]``: M samples of each condition, row c generated under condition c (the
        intention-major layout of :func:`~emgail_jax.rollout.intention_major`).
    """
    real = expert_logits(apply, params, expert_obs, expert_actions, conditions)
    fake = apply(params, policy_obs, policy_actions, policy_conditions, intention_major=True)
    expert_term = jnp.mean(jnp.sum(expert_weights * jax.nn.softplus(-real), -1))
    policy_term = jnp.mean(jax.nn.softplus(fake))
    loss = expert_term + policy_term
    real_d = jnp.sum(expert_weights * jax.nn.sigmoid(real), -1)
    return loss, {
        "discriminator/loss": loss,
        "discriminator/expert_d": jnp.mean(real_d),
        "discriminator/policy_d": jnp.mean(jax.nn.sigmoid(fake)),
    }


def discriminator_update(
    apply: Callable,
    optimizer: optax.GradientTransformation,
    params,
    opt_state,
    steps: int,
    **batch,
):
    """M-step training: ``steps`` full-batch steps of :func:`discriminator_loss` on ``batch``."""
    loss = lambda p: discriminator_loss(apply, p, **batch)
    return minimize(loss, optimizer, params, opt_state, steps)


REWARD_FORMS = ("gail", "logit")


def imitation_reward(logit: jax.Array, form: str = "gail") -> jax.Array:
    """The reward of a pair the discriminator scores ``logit``, high where D takes it for the
    expert's. "gail": -log(1 - D) = softplus(f), the paper's; positive everywhere, so where
    episodes can end early it also pays for staying alive. "logit": log D - log(1 - D) = f
    (AIRL's form), negative where D rejects the pair, so survival alone earns nothing."""
    if form == "logit":
        return logit
    return jax.nn.softplus(logit)
