"""Generalised advantage estimation (Schulman et al., 2016)."""

from __future__ import annotations

import jax
import jax.numpy as jnp


def generalized_advantages(
    rewards: jax.Array,
    values: jax.Array,
    dones: jax.Array,
    bootstrap_value: jax.Array,
    gamma: float,
    lam: float,
) -> tuple[jax.Array, jax.Array]:
    """GAE(gamma, lambda) over a rollout.

    Args:
      rewards: ``[T, ...]`` reward of each transition.
      values: ``[T, ...]`` V of the state each transition starts from.
      dones: ``[T, ...]`` 1.0 where the episode ended with that transition. The horizon is fixed
        and the value function sees the time, so a time-limit end is terminal too.
      bootstrap_value: ``[...]`` V of the state after the last transition.

    Returns:
      ``(advantages [T, ...], returns [T, ...])``, returns being the value targets
      ``advantages + values``.
    """
    next_values = jnp.concatenate([values[1:], bootstrap_value[None]], axis=0)
    continues = 1.0 - dones
    deltas = rewards + gamma * next_values * continues - values

    def backward(carry, x):
        delta, cont = x
        advantage = delta + gamma * lam * cont * carry
        return advantage, advantage

    _, advantages = jax.lax.scan(
        backward, jnp.zeros_like(bootstrap_value), (deltas, continues), reverse=True
    )
    return advantages, advantages + values
