"""A ranking of a run's policies by when they were learnt, as a loss on the discriminator.

Trained as GAIL trains it, the discriminator sees every policy sample as a negative alike, so
nothing orders the behaviours between a fresh agent's and the experts': the reward peaks at the
demonstrations but need not rise towards them from where a fresh agent starts. Policies later in
a run are (mostly) nearer the experts, so ranking the run's snapshots by iteration, and the
demonstrations above all of them, gives the reward the slope re-optimisation climbs. The loss is
Bradley–Terry's on the mean logit of a few samples of each of two snapshots (T-REX, Brown et al.
2019; the later policy as the better one: D-REX and SSRR's assumption, Brown et al. 2020, Chen et
al. 2020). The logit orders what every reward form reads from it, as each is increasing in it.
"""

from __future__ import annotations

from collections.abc import Callable

import chex
import jax
import jax.numpy as jnp


def ranked_levels(key: jax.Array, shape: tuple[int, ...], levels: int):
    """``(lower, upper)`` of ``shape``: pairs of levels ``0 <= lower < upper < levels``, every
    such pair equally likely."""
    chex.assert_scalar_positive(levels - 1)
    key_lower, key_upper = jax.random.split(key)
    # Pick two distinct levels uniformly, then order them.
    first = jax.random.randint(key_lower, shape, 0, levels)
    offset = jax.random.randint(key_upper, shape, 1, levels)
    second = (first + offset) % levels
    return jnp.minimum(first, second), jnp.maximum(first, second)


def drawn_by_weight(key: jax.Array, weights: jax.Array, shape: tuple[int, ...]) -> jax.Array:
    """``[K, *shape]`` rows of ``weights [N, K]``, column k's drawn in proportion to it (all
    alike where the column is all zero, as an emptied intention's is)."""
    # The inverse of the cumulative weights: O(N) per column, where a Gumbel draw over N
    # demonstration pairs for every sample would cost O(N) per sample.
    cumulative = jnp.cumsum(weights, 0).T
    cumulative = jnp.where(cumulative[:, -1:] > 0, cumulative, jnp.arange(1, weights.shape[0] + 1))
    uniform = jax.random.uniform(key, (weights.shape[1], *shape))
    found = jax.vmap(lambda c, u: jnp.searchsorted(c, u * c[-1], side="right"))(cumulative, uniform)
    return jnp.minimum(found, weights.shape[0] - 1)


def ranking_loss(
    apply: Callable,
    params,
    key: jax.Array,
    *,
    policy_obs: jax.Array,
    policy_actions: jax.Array,
    expert_obs: jax.Array,
    expert_actions: jax.Array,
    expert_weights: jax.Array,
    condition_of: Callable[[jax.Array], jax.Array],
    pairs: int,
    samples: int,
) -> tuple[jax.Array, dict]:
    """Bradley–Terry's loss, ``-log sigmoid(mean f(upper) - mean f(lower))`` averaged over
    ``pairs`` ranked pairs per intention, each side ``samples`` pairs (s, a) of one level.

    The levels of intention i are its policy's snapshots in the order they were learnt, then
    its demonstrations (drawn by ``expert_weights``) above all of them.

    Args:
      key: the draws of this step (levels and samples).
      policy_obs, policy_actions: ``[K, S, M, D]``, ``[K, S, M, A]``: M samples of each of
        S snapshots (oldest first) of each intention's policy (normalised observations).
      expert_obs, expert_actions: ``[N, D]``, ``[N, A]``: the demonstration pairs.
      expert_weights: ``[N, K]``: how much each pair belongs to each intention (rows need not
        sum to one; an intention that holds none draws every pair alike).
      condition_of: the discriminator condition ``[..., c]`` of intentions ``[...]``.
    Returns:
      the loss and ``ranking/loss``, ``ranking/accuracy`` (the share of pairs the logit
      already orders) and ``ranking/expert_accuracy`` (of the pairs with demonstrations above).
    """
    k, s, m = policy_obs.shape[:3]
    chex.assert_shape(policy_actions, (k, s, m, None))
    chex.assert_shape(expert_weights, (expert_obs.shape[0], k))
    key_levels, key_rows, key_experts = jax.random.split(key, 3)
    lower, upper = ranked_levels(key_levels, (k, pairs), s + 1)
    intention = jnp.arange(k)[:, None, None]
    rows = jax.random.randint(key_rows, (2, k, pairs, samples), 0, m)
    expert_rows = drawn_by_weight(key_experts, expert_weights, (pairs, samples))

    def drawn(levels: jax.Array, level_rows: jax.Array):
        """``[K, pairs * samples, ...]`` observations and actions of ``levels [K, pairs]``."""
        snapshot = jnp.minimum(levels, s - 1)[..., None]
        is_expert = (levels == s)[..., None, None]
        obs = jnp.where(
            is_expert, expert_obs[expert_rows], policy_obs[intention, snapshot, level_rows]
        )
        actions = jnp.where(
            is_expert, expert_actions[expert_rows], policy_actions[intention, snapshot, level_rows]
        )
        return obs.reshape(k, pairs * samples, -1), actions.reshape(k, pairs * samples, -1)

    conditions = condition_of(jnp.broadcast_to(jnp.arange(k)[:, None], (k, pairs * samples)))

    def mean_logits(levels, level_rows):
        obs, actions = drawn(levels, level_rows)
        logits = apply(params, obs, actions, conditions, intention_major=True)
        return logits.reshape(k, pairs, samples).mean(-1)

    margin = mean_logits(upper, rows[1]) - mean_logits(lower, rows[0])
    loss = jnp.mean(jax.nn.softplus(-margin))
    with_experts = upper == s
    ordered = margin > 0
    metrics = {
        "ranking/loss": loss,
        "ranking/accuracy": jnp.mean(ordered),
        "ranking/expert_accuracy": jnp.sum(ordered & with_experts)
        / jnp.maximum(jnp.sum(with_experts), 1),
    }
    return loss, metrics
