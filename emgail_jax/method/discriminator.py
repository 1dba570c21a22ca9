"""The M-step (paper eq. 19 / 22): the discriminator learns the expert pairs against the policy's.

The discriminator outputs the logit f with D = sigmoid(f). Every loss term and the reward are
written in terms of f with softplus, which never overflows:
  -log D = softplus(-f),   -log(1 - D) = softplus(f).

One loss serves both forms of the paper. Each expert pair is scored under every discriminator
condition c with a weight w[n, c]: EM-GAIL's conditions are the K one-hot intentions and its
weights are the responsibilities gamma (eq. 19); the baselines' D(s, a) has a single, empty
condition with weight one (eq. 22). Policy samples are scored under their own condition only.
The reward the discriminator defines is in :mod:`emgail_jax.method.algorithms`.

AIRL's discriminator (``--set discriminator_form=airl``, :mod:`emgail_jax.method.airl`) runs
through the same loss: its network reads a pair's successor where GAIL's reads the action, and
its logit is f - log pi, the log-densities entering here as fixed offsets of the logit.

With absorbing states (``--set absorbing_state=true``, DAC), a termination leads to the
absorbing state, one pair (normalised observation and action zeros, the absorbing indicator 1:
:class:`~emgail_jax.method.networks.Discriminator`) that the discriminator learns like any
other: one absorbing sample per policy transition that terminated, as a negative, and per
demonstration that ended in one, as a positive. One sample per termination, as DAC's replay
holds one: the horizon it lasts enters the B-step's value
(:func:`~emgail_jax.method.gae.absorbing_value`), not D's loss, where a policy that falls early
would otherwise put most of the negatives' weight on that one pair.
"""

from __future__ import annotations

from collections.abc import Callable

import chex
import jax
import jax.numpy as jnp
import optax
from flax import struct

from emgail_jax.method.algorithms import Algorithm
from emgail_jax.method.batches import NormalizedBatch
from emgail_jax.method.config import MStepConfig
from emgail_jax.method.optim import Learner, minimize


def expert_logits(apply: Callable, params, obs, actions, conditions: jax.Array) -> jax.Array:
    """``[N, C]``: f(s, a, c) of every expert pair under every condition ``conditions [C, c]``
    (broadcast, so that a discriminator with one head per intention runs each head once)."""
    return apply(params, obs[None], actions[None], conditions[:, None, :], intention_major=True).T


def expert_scores(apply: Callable, params, batch: NormalizedBatch, conditions) -> jax.Array:
    """``[N, C]``: the logit of every expert pair of ``batch`` under every condition
    ``conditions [C, c]``, as the loss scores it (AIRL's: f - log pi)."""
    _, expert_inputs = batch.discriminated()
    logits = expert_logits(apply, params, batch.expert_obs, expert_inputs, conditions)
    return logits if batch.expert_log_policy is None else logits - batch.expert_log_policy


def absorbing_logits(
    apply: Callable, params, conditions: jax.Array, obs_size: int, action_size: int
) -> jax.Array:
    """``[C]``: f of the absorbing pair (observation and action zeros, the absorbing indicator
    1) under every condition ``conditions [C, c]``."""
    c = conditions.shape[0]
    zeros = lambda size: jnp.zeros((c, 1, size))
    logits = apply(
        params,
        zeros(obs_size),
        zeros(action_size),
        conditions[:, None, :],
        intention_major=True,
        absorbed=jnp.ones((c, 1)),
    )
    return logits[:, 0]


def _with_absorbing(losses: jax.Array, absorbing_losses: jax.Array, counts: jax.Array):
    """The mean loss over ``losses`` (one per sample) and ``counts [C]`` absorbing samples
    whose losses are ``absorbing_losses [C]``."""
    return (losses.sum() + jnp.sum(counts * absorbing_losses)) / (losses.size + counts.sum())


def discriminator_loss(
    apply: Callable,
    params,
    *,
    expert_obs: jax.Array,
    expert_actions: jax.Array,
    expert_weights: jax.Array,
    conditions: jax.Array,
    policy_obs: jax.Array,
    policy_actions: jax.Array,
    policy_conditions: jax.Array,
    gradient_penalty: float | jax.Array = 0.0,
    expert_absorbed: jax.Array | None = None,
    policy_absorbed: jax.Array | None = None,
    expert_log_policy: jax.Array | None = None,
    policy_log_policy: jax.Array | None = None,
):
    """Logistic loss: expert pairs are real, weighted over conditions; policy samples are fake;
    plus ``gradient_penalty`` times :func:`input_gradient_norms` (none computed at 0).

    Args:
      expert_obs, expert_actions: ``[N, D]``, ``[N, A]`` (normalised observations).
      expert_weights: ``[N, C]`` weight of each expert pair under each condition.
      conditions: ``[C, c]`` the discriminator conditions (one-hot rows, or one empty row).
      policy_obs, policy_actions, policy_conditions: ``[C, M, D]``, ``[C, M, A]``,
        ``[C, M, c]``: M samples of each condition, row c generated under condition c (the
        intention-major layout of :func:`~emgail_jax.method.rollout.intention_major`).
      expert_absorbed, policy_absorbed: with absorbing states (both or neither), the
        absorbing pair as a real sample, weighted ``[C]`` under each condition (the summed
        weights of the demonstrations that ended in a termination), and as a fake one,
        ``[rows]`` samples under each row's condition (its terminations); each counts as one
        sample more in its term's mean.
      expert_log_policy, policy_log_policy: AIRL's (both or neither; ``expert_actions`` and
        ``policy_actions`` then hold the successors): ``[N, C]`` log pi of every expert pair
        under every condition, ``[C, M]`` of every sample under its own, subtracted from f.
        The gradient penalty reads f alone.
    """
    real = expert_logits(apply, params, expert_obs, expert_actions, conditions)
    fake = apply(params, policy_obs, policy_actions, policy_conditions, intention_major=True)
    if policy_log_policy is not None:
        real, fake = real - expert_log_policy, fake - policy_log_policy
    expert_losses = jnp.sum(expert_weights * jax.nn.softplus(-real), -1)
    policy_losses = jax.nn.softplus(fake)
    absorbing_metrics = {}
    if policy_absorbed is None:
        expert_term, policy_term = jnp.mean(expert_losses), jnp.mean(policy_losses)
    else:
        sizes = (policy_obs.shape[-1], policy_actions.shape[-1])
        real_absorbing = absorbing_logits(apply, params, conditions, *sizes)
        fake_absorbing = absorbing_logits(apply, params, policy_conditions[:, 0], *sizes)
        expert_term = _with_absorbing(
            expert_losses, jax.nn.softplus(-real_absorbing), expert_absorbed
        )
        policy_term = _with_absorbing(
            policy_losses, jax.nn.softplus(fake_absorbing), policy_absorbed
        )
        absorbing_metrics = {"discriminator/absorbing_d": jnp.mean(jax.nn.sigmoid(fake_absorbing))}
    loss = expert_term + policy_term
    real_d = jnp.sum(expert_weights * jax.nn.sigmoid(real), -1)
    metrics = {
        "discriminator/loss": loss,
        "discriminator/expert_d": jnp.mean(real_d),
        "discriminator/policy_d": jnp.mean(jax.nn.sigmoid(fake)),
        **absorbing_metrics,
    }
    if isinstance(gradient_penalty, jax.Array) or gradient_penalty:
        norms = input_gradient_norms(
            apply,
            params,
            expert_obs=expert_obs,
            expert_actions=expert_actions,
            expert_weights=expert_weights,
            conditions=conditions,
            policy_obs=policy_obs,
            policy_actions=policy_actions,
            policy_conditions=policy_conditions,
        )
        loss = loss + gradient_penalty * norms
        metrics["discriminator/gradient_norm"] = norms
    return loss, metrics


def input_gradient_norms(
    apply: Callable,
    params,
    *,
    expert_obs,
    expert_actions,
    expert_weights,
    conditions,
    policy_obs,
    policy_actions,
    policy_conditions,
) -> jax.Array:
    """The mean squared norm of d f / d(s, a) on the expert pairs (under each condition, weighted
    as in the loss) and on the policy samples, half each: a zero-centred penalty that keeps
    the logit, and so the reward, from growing steeply where the data lie."""

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


def discriminator_update(
    apply: Callable,
    optimizer: optax.GradientTransformation,
    discriminator: Learner,
    steps: int,
    **batch,
) -> tuple[Learner, dict]:
    """M-step training: ``steps`` full-batch steps of :func:`discriminator_loss` on ``batch``."""
    loss = lambda p: discriminator_loss(apply, p, **batch)
    return minimize(loss, optimizer, discriminator, steps)


@struct.dataclass
class MStep:
    """What the M-step hands on."""

    discriminator: Learner
    metrics: dict


def gradient_penalty_at(config: MStepConfig, iteration: jax.Array | None) -> float | jax.Array:
    """The gradient penalty's weight at ``iteration`` (the updates done before this one): a
    constant, or 0 before ``config.gradient_penalty_from``."""
    if not config.gradient_penalty_from or iteration is None:
        return config.gradient_penalty
    return jnp.where(iteration >= config.gradient_penalty_from, config.gradient_penalty, 0.0)


def make_m_step(apply: Callable, optimizer: optax.GradientTransformation, config: MStepConfig):
    """``m_step(discriminator, batch, gamma, algorithm, iteration=None) -> MStep`` (Algorithm 1,
    M-step): the discriminator (a :class:`Learner`) learns the expert pairs of ``batch`` (a
    :class:`NormalizedBatch`), weighted over intentions by ``gamma [N, K]`` as ``algorithm``
    says (eq. 19 or 22), against the policy samples under their own intention; ``config.steps``
    full-batch steps, with the gradient penalty :func:`gradient_penalty_at` ``iteration`` weighs.
    A batch with termination flags adds the absorbing pair on both sides (module docstring)."""

    def m_step(
        discriminator: Learner,
        batch: NormalizedBatch,
        gamma: jax.Array,
        algorithm: Algorithm,
        iteration: jax.Array | None = None,
    ) -> MStep:
        k = batch.obs.shape[0]
        chex.assert_shape(gamma, (batch.expert_obs.shape[0], k))
        own_intention = batch.own_intention()
        policy_inputs, expert_inputs = batch.discriminated()
        absorbed = {}
        if batch.terminal is not None:
            absorbed = dict(
                expert_absorbed=batch.expert_terminal @ algorithm.expert_weights(gamma),
                policy_absorbed=batch.terminal.sum(1),
            )
        trained, metrics = discriminator_update(
            apply,
            optimizer,
            discriminator,
            config.steps,
            expert_obs=batch.expert_obs,
            expert_actions=expert_inputs,
            expert_weights=algorithm.expert_weights(gamma),
            conditions=algorithm.discriminator_conditions(k),
            policy_obs=batch.obs,
            policy_actions=policy_inputs,
            policy_conditions=algorithm.discriminator_condition(own_intention, k),
            gradient_penalty=gradient_penalty_at(config, iteration),
            **absorbed,
            **batch.log_policy_offsets(),
        )
        return MStep(trained, metrics)

    return m_step


def learned_reward(
    apply: Callable,
    params,
    algorithm: Algorithm,
    num_intentions: int,
    *,
    obs: jax.Array,
    executed: jax.Array,
    intention: jax.Array,
    own_log_posterior: jax.Array,
    intention_major: bool = False,
    log_policy: jax.Array | None = None,
) -> jax.Array:
    """The learned reward ``[...]`` of pairs (normalised ``obs [..., D]``, ``executed [..., A]``)
    under their ``intention [...]``: -log(1 - D(s, a, i)) for EM-GAIL (eq. 20), plus lambda
    log P(i | s, a) (``own_log_posterior [...]``) for Info/IntentionGAIL (eq. 23), and
    -log(1 - D(s, a)) for GAIL. ``intention_major``: the leading axis of the inputs is the
    intention (the rollouts' layout ``[K, ...]``, see
    :func:`~emgail_jax.method.networks.conditioned_mlp`). AIRL's: ``executed`` holds the
    successors and ``log_policy [...]`` log pi of the pairs' actions, the logit f - log pi.
    """
    condition = algorithm.discriminator_condition(intention, num_intentions)
    logit = apply(params, obs, executed, condition, intention_major=intention_major)
    if log_policy is not None:
        logit = logit - log_policy
    return algorithm.pseudo_reward(logit, own_log_posterior)


def absorbing_reward(
    apply: Callable,
    params,
    algorithm: Algorithm,
    num_intentions: int,
    obs_size: int,
    action_size: int,
) -> jax.Array:
    """``[K]`` the learned reward of the absorbing state under each intention, as
    :func:`learned_reward` scores a pair; Info/IntentionGAIL's lambda log P(i | s, a) taken at
    1/K, since the absorbing state tells no intention from another."""
    intentions = jnp.arange(num_intentions)
    conditions = algorithm.discriminator_condition(intentions, num_intentions)  # [K, c]
    logits = absorbing_logits(apply, params, conditions, obs_size, action_size)
    return algorithm.pseudo_reward(logits, jnp.full(num_intentions, -jnp.log(num_intentions)))
