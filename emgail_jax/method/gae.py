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
    *,
    end_values: jax.Array | None = None,
) -> tuple[jax.Array, jax.Array]:
    """GAE(gamma, lambda) over a rollout.

    Args:
      rewards: ``[T, ...]`` reward of each transition.
      values: ``[T, ...]`` V of the state each transition starts from.
      dones: ``[T, ...]`` 1.0 where the episode ended with that transition. The horizon is fixed
        and the value function sees the time, so a time-limit end is terminal too.
      bootstrap_value: ``[...]`` V of the state after the last transition.
      end_values: ``[T, ...]`` V of the state an episode ends in, after the transition that
        ends it (an absorbing state's, :func:`absorbing_value`); read where ``dones``. None:
        0, nothing follows an episode's end.

    Returns:
      ``(advantages [T, ...], returns [T, ...])``, returns being the value targets
      ``advantages + values``.
    """
    next_values = jnp.concatenate([values[1:], bootstrap_value[None]], axis=0)
    continues = 1.0 - dones
    deltas = rewards + gamma * next_values * continues - values
    if end_values is not None:
        # The bootstrap at an episode's end; the recursion below still stops there, since
        # what follows is deterministic (its advantage 0).
        deltas = deltas + gamma * dones * end_values

    def backward(carry, x):
        delta, cont = x
        advantage = delta + gamma * lam * cont * carry
        return advantage, advantage

    _, advantages = jax.lax.scan(
        backward, jnp.zeros_like(bootstrap_value), (deltas, continues), reverse=True
    )
    return advantages, advantages + values


def absorbing_value(reward: jax.Array, steps_left: jax.Array, gamma: float) -> jax.Array:
    """``[...]`` V of an absorbing state entered with ``steps_left [...]`` steps to the time
    limit, each paying ``reward [...]``: reward * sum_{j<m} gamma^j (0 at the limit itself), so
    that the transition into it bootstraps reward * sum_{j=1..m} gamma^j (DAC)."""
    m = steps_left.astype(jnp.float32)
    steps = m if gamma == 1.0 else (1.0 - gamma**m) / (1.0 - gamma)
    return reward * steps
