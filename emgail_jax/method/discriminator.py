"""The M-step (paper eq. 19 / 22): the discriminator learns the expert pairs against the policy's.

The discriminator outputs the logit f with D = sigmoid(f). Every loss term and the reward are
written in terms of f with softplus, which never overflows:
  -log D = softplus(-f),   -log(1 - D) = softplus(f).

One loss serves both forms of the paper. Each expert pair is scored under every discriminator
condition c with a weight w[n, c]: EM-GAIL's conditions are the K one-hot intentions and its
weights are the responsibilities gamma (eq. 19); the baselines' D(s, a) has a single, empty
condition with weight one (eq. 22). Policy samples are scored under their own condition only.
The reward the discriminator defines is in :mod:`emgail_jax.method.algorithms`.

Variants change the loss through a :class:`LossHook` (:mod:`emgail_jax.method.hooks`): what is
subtracted from the logit, how each term averages its samples, and a regulariser.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

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


class Read(NamedTuple):
    """What the discriminator's logit reads beside the observation: ``samples [K, M, X]`` and
    ``experts [N, X]`` (the paper's: the executed actions), and what is subtracted from the
    logit (None: nothing), ``[K, M]`` of the samples and ``[N, C]`` of the expert pairs under
    every condition."""

    samples: jax.Array
    experts: jax.Array
    offsets: jax.Array | None = None
    expert_offsets: jax.Array | None = None

    @classmethod
    def of(cls, batch: NormalizedBatch) -> Read:
        """The paper's: the executed actions of ``batch``."""
        return cls(batch.executed, batch.expert_actions)


def expert_scores(apply: Callable, params, expert_obs, read: Read, conditions) -> jax.Array:
    """``[N, C]``: the logit of every expert pair ``expert_obs [N, D]``, reading ``read``, under
    every condition ``conditions [C, c]``, as the loss scores it (its offsets subtracted)."""
    logits = expert_logits(apply, params, expert_obs, read.experts, conditions)
    return logits if read.expert_offsets is None else logits - read.expert_offsets


class LossInputs(NamedTuple):
    """The discriminator loss's inputs (see :func:`discriminator_loss`)."""

    expert_obs: jax.Array
    expert_actions: jax.Array
    expert_weights: jax.Array
    conditions: jax.Array
    policy_obs: jax.Array
    policy_actions: jax.Array
    policy_conditions: jax.Array


class LossHook:
    """What a variant changes in :func:`discriminator_loss`; this base changes nothing (the
    paper's loss)."""

    def logits(self, real: jax.Array, fake: jax.Array) -> tuple[jax.Array, jax.Array]:
        """The logits the loss scores, from f of the expert pairs ``real [N, C]`` and of the
        policy samples ``fake [C, M]``."""
        return real, fake

    def terms(self, apply: Callable, params, inputs: LossInputs, expert_losses, policy_losses):
        """``(expert term, policy term, metrics)``: each term's mean over its samples' losses
        (``expert_losses [N]``, ``policy_losses [C, M]``)."""
        return jnp.mean(expert_losses), jnp.mean(policy_losses), {}

    def regulariser(self, apply: Callable, params, inputs: LossInputs):
        """``(penalty or None, metrics)``: a term added to the loss (None: none)."""
        return None, {}


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
    hook: LossHook | None = None,
):
    """Logistic loss: expert pairs are real, weighted over conditions; policy samples are fake;
    with what a variant's ``hook`` changes (None: nothing, the paper's loss).

    Args:
      expert_obs, expert_actions: ``[N, D]``, ``[N, A]`` (normalised observations).
      expert_weights: ``[N, C]`` weight of each expert pair under each condition.
      conditions: ``[C, c]`` the discriminator conditions (one-hot rows, or one empty row).
      policy_obs, policy_actions, policy_conditions: ``[C, M, D]``, ``[C, M, A]``,
        ``[C, M, c]``: M samples of each condition, row c generated under condition c (the
        intention-major layout of :func:`~emgail_jax.method.rollout.intention_major`).
    """
    hook = hook or LossHook()
    inputs = LossInputs(
        expert_obs,
        expert_actions,
        expert_weights,
        conditions,
        policy_obs,
        policy_actions,
        policy_conditions,
    )
    real = expert_logits(apply, params, expert_obs, expert_actions, conditions)
    fake = apply(params, policy_obs, policy_actions, policy_conditions, intention_major=True)
    real, fake = hook.logits(real, fake)
    expert_losses = jnp.sum(expert_weights * jax.nn.softplus(-real), -1)
    policy_losses = jax.nn.softplus(fake)
    expert_term, policy_term, term_metrics = hook.terms(
        apply, params, inputs, expert_losses, policy_losses
    )
    loss = expert_term + policy_term
    real_d = jnp.sum(expert_weights * jax.nn.sigmoid(real), -1)
    metrics = {
        "discriminator/loss": loss,
        "discriminator/expert_d": jnp.mean(real_d),
        "discriminator/policy_d": jnp.mean(jax.nn.sigmoid(fake)),
        **term_metrics,
    }
    penalty, penalty_metrics = hook.regulariser(apply, params, inputs)
    if penalty is not None:
        loss = loss + penalty
        metrics.update(penalty_metrics)
    return loss, metrics


def loss_batch(
    batch: NormalizedBatch,
    gamma: jax.Array,
    algorithm: Algorithm,
    read: Read | None = None,
    hook: LossHook | None = None,
) -> dict:
    """:func:`discriminator_loss`'s keyword inputs for ``batch``: its expert pairs weighted by
    ``gamma [N, K]`` under every condition, its samples under their own intention, each side
    read as ``read`` says (the paper's executed actions if None)."""
    k = batch.obs.shape[0]
    read = Read.of(batch) if read is None else read
    return dict(
        expert_obs=batch.expert_obs,
        expert_actions=read.experts,
        expert_weights=algorithm.expert_weights(gamma),
        conditions=algorithm.discriminator_conditions(k),
        policy_obs=batch.obs,
        policy_actions=read.samples,
        policy_conditions=algorithm.discriminator_condition(batch.own_intention(), k),
        hook=hook,
    )


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


def make_m_step(apply: Callable, optimizer: optax.GradientTransformation, config: MStepConfig):
    """``m_step(discriminator, batch, gamma, algorithm, read=None, hook=None) -> MStep``
    (Algorithm 1, M-step): the discriminator (a :class:`Learner`) learns the expert pairs of
    ``batch`` (a :class:`NormalizedBatch`), weighted over intentions by ``gamma [N, K]`` as
    ``algorithm`` says (eq. 19 or 22), against the policy samples under their own intention;
    ``config.steps`` full-batch steps. ``read`` (a :class:`Read`; None: the executed actions)
    is what the logit reads beside the observation, ``hook`` what a variant changes in the
    loss (:class:`LossHook`)."""

    def m_step(
        discriminator: Learner,
        batch: NormalizedBatch,
        gamma: jax.Array,
        algorithm: Algorithm,
        read: Read | None = None,
        hook: LossHook | None = None,
    ) -> MStep:
        k = batch.obs.shape[0]
        chex.assert_shape(gamma, (batch.expert_obs.shape[0], k))
        inputs = loss_batch(batch, gamma, algorithm, read=read, hook=hook)
        trained, metrics = discriminator_update(
            apply, optimizer, discriminator, config.steps, **inputs
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
    :func:`~emgail_jax.method.networks.conditioned_mlp`). ``executed`` holds what the logit
    reads beside the observation and ``log_policy [...]``, if given, is subtracted from it
    (a form's :class:`Read`).
    """
    condition = algorithm.discriminator_condition(intention, num_intentions)
    logit = apply(params, obs, executed, condition, intention_major=intention_major)
    if log_policy is not None:
        logit = logit - log_policy
    return algorithm.pseudo_reward(logit, own_log_posterior)
