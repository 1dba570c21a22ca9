"""The E-step (paper eq. 16/18): the posterior network P(i | s, a; phi) and the responsibilities.

P is trained by maximum likelihood on the policy's own samples, whose intention is known because
the policy of that intention generated them; the responsibilities of the expert pairs are then
gamma(i | s, a) = P(i | s, a). Info/IntentionGAIL trains the same network the same way (eq. 21).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import optax

from emgail_jax.optim import minimize


def posterior_loss(
    apply: Callable, params, obs: jax.Array, actions: jax.Array, intentions: jax.Array
):
    """Cross-entropy of ``P(. | obs [M, D], actions [M, A])`` against ``intentions [M]``."""
    logits = apply(params, obs, actions)
    loss = optax.softmax_cross_entropy_with_integer_labels(logits, intentions).mean()
    accuracy = jnp.mean(jnp.argmax(logits, -1) == intentions)
    return loss, {"posterior/loss": loss, "posterior/policy_accuracy": accuracy}


def posterior_update(
    apply: Callable,
    optimizer: optax.GradientTransformation,
    params,
    opt_state,
    obs: jax.Array,
    actions: jax.Array,
    intentions: jax.Array,
    steps: int,
):
    """E-step training: ``steps`` full-batch steps on the policy samples (labels known)."""
    loss = lambda p: posterior_loss(apply, p, obs, actions, intentions)
    return minimize(loss, optimizer, params, opt_state, steps)


def responsibilities(apply: Callable, params, obs: jax.Array, actions: jax.Array) -> jax.Array:
    """gamma(i | s, a) = P(i | s, a) on the expert pairs: ``[N, K]``, rows sum to one."""
    return jax.nn.softmax(apply(params, obs, actions), axis=-1)


def trajectory_responsibilities(
    apply: Callable, params, obs: jax.Array, actions: jax.Array, episode: jax.Array, episodes: int
) -> jax.Array:
    """gamma of every expert pair from its whole demonstration: ``[N, K]``.

    A demonstration has one intention. Treating its pairs as independent given the intention,
    with a uniform prior, the posterior of the intention of episode e is proportional to
    ``prod_t P(i | s_t, a_t)`` over its pairs; every pair takes the posterior of its episode.

    Args:
      obs, actions: ``[N, D]``, ``[N, A]`` the expert pairs.
      episode: ``[N]`` index of each pair's episode, in ``[0, episodes)``.
    """
    log_posterior = jax.nn.log_softmax(apply(params, obs, actions), axis=-1)
    per_episode = jax.ops.segment_sum(log_posterior, episode, num_segments=episodes)
    return jax.nn.softmax(per_episode, axis=-1)[episode]
