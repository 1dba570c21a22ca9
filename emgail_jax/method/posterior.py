"""The E-step (paper eq. 16/18): the posterior network P(i | s, a; phi) and the responsibilities.

P is trained by maximum likelihood on the policy's own samples, whose intention is known because
the policy of that intention generated them; the responsibilities of the expert pairs are then
gamma(i | s, a) = P(i | s, a). Info/IntentionGAIL trains the same network the same way (eq. 21).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import chex
import jax
import jax.numpy as jnp
import optax
from flax import struct

from emgail_jax.method.batches import DemonstrationPairs, NormalizedBatch
from emgail_jax.method.config import EStepConfig, ResponsibilityMode, RewardFrom
from emgail_jax.method.optim import Learner, minimize


def posterior_loss(
    apply: Callable,
    params,
    obs: jax.Array,
    actions: jax.Array,
    intentions: jax.Array,
    weights: jax.Array | None = None,
):
    """Cross-entropy of ``P(. | obs [M, D], actions [M, A])`` against ``intentions [M]``; with
    ``weights [M]``, their weighted mean (and the accuracy's)."""
    logits = apply(params, obs, actions)
    cross_entropy = optax.softmax_cross_entropy_with_integer_labels(logits, intentions)
    correct = jnp.argmax(logits, -1) == intentions
    if weights is None:
        loss, accuracy = cross_entropy.mean(), jnp.mean(correct)
    else:
        loss = jnp.sum(weights * cross_entropy) / jnp.sum(weights)
        accuracy = jnp.sum(weights * correct) / jnp.sum(weights)
    return loss, {"posterior/loss": loss, "posterior/policy_accuracy": accuracy}


def posterior_update(
    apply: Callable,
    optimizer: optax.GradientTransformation,
    posterior: Learner,
    obs: jax.Array,
    actions: jax.Array,
    intentions: jax.Array,
    *,
    steps: int,
    weights: jax.Array | None = None,
) -> tuple[Learner, dict]:
    """E-step training: ``steps`` full-batch steps on the policy samples (labels known), each
    weighted by ``weights`` (None: equally)."""
    loss = lambda p: posterior_loss(apply, p, obs, actions, intentions, weights)
    return minimize(loss, optimizer, posterior, steps)


@struct.dataclass
class Lesson:
    """Demonstration pairs the posterior learns beside the policy samples while a re-seeding
    holds them for an intention (emgail_jax.method.reseeding): Info/IntentionGAIL's
    discriminator ignores gamma, and its reward's log P(i | s, a) is how a re-seeding reaches
    its policies."""

    active: jax.Array  # [] bool: whether any pair is held
    intentions: jax.Array  # [N] the intention each pair is taught as
    weights: jax.Array  # [N] 1 for the held pairs, 0 for the others


def log_posterior(apply: Callable, params, obs: jax.Array, actions: jax.Array) -> jax.Array:
    """``[..., K]`` log P(i | s, a) of (normalised) ``obs [..., D]`` and ``actions [..., A]``."""
    return jax.nn.log_softmax(apply(params, obs, actions), axis=-1)


def trajectory_responsibilities(
    log_p: jax.Array,
    episode: jax.Array,
    episodes: int,
    centered: bool = False,
    log_prior: jax.Array | None = None,
    evidence_weight: jax.Array | None = None,
) -> jax.Array:
    """gamma of every expert pair from its whole demonstration: ``[N, K]``.

    A demonstration has one intention. Treating its pairs as independent given the intention,
    with a uniform prior, the posterior of the intention of episode e is proportional to
    ``prod_t P(i | s_t, a_t)`` over its pairs; every pair takes the posterior of its episode.
    ``centered`` first subtracts, for every intention, the mean over the demonstrations of
    their summed ``log P(i | .)``: a lean the posterior network has on every pair (an untrained
    one always has some) then cancels instead of growing with the episode length and sending
    every demonstration to one intention, and each demonstration goes where it differs from the
    others. An option, not the default (see docs/defaults.md, ``responsibilities``).

    ``evidence_weight`` weighs each demonstration's summed log-posterior before the centring
    and the prior: ``softmax_i(beta_e sum_t log P(i | s_t, a_t) + log w_i)`` (a variant's
    evidence hook, :mod:`emgail_jax.method.hooks`).

    Args:
      log_p: ``[N, K]`` log P(i | s, a) of the expert pairs.
      episode: ``[N]`` index of each pair's episode, in ``[0, episodes)``.
      log_prior: ``[K]`` log w_i of the mixture prior; None for the uniform prior.
      evidence_weight: ``[E]`` the weight of each demonstration's evidence; None: 1.
    """
    per_episode = jax.ops.segment_sum(log_p, episode, num_segments=episodes)  # [E, K]
    if evidence_weight is not None:
        per_episode = evidence_weight[:, None] * per_episode
    if centered:
        per_episode = per_episode - per_episode.mean(0, keepdims=True)
    if log_prior is not None:
        per_episode = per_episode + log_prior
    return jax.nn.softmax(per_episode, axis=-1)[episode]


@struct.dataclass
class Responsibilities:
    """What the E-step concludes about the expert pairs, in one place for training, evaluation
    and the saved-run API.

    Attributes:
      gamma: ``[N, K]`` the weights of the M-step: ``P(i | s, a)`` of each pair (eq. 18), or,
        with ``mode="trajectory"``, the posterior of the pair's whole demonstration (its
        evidence weighed by a variant's evidence hook, if any).
      pair_labels: ``[N]`` ``argmax_i P(i | s, a)`` of each pair: the clustering the paper's
        accuracy (eq. 29) scores, in either mode.
      trajectory_labels: ``[N]`` ``argmax_i gamma``: the labels the M-step acts on; equal to
        ``pair_labels`` in pair mode.
      pair_scores: ``[N, K]`` log w_i P(i | s, a) (up to a constant per pair), whose argmax
        the pair labels are.
    """

    gamma: jax.Array
    pair_labels: jax.Array
    trajectory_labels: jax.Array
    pair_scores: jax.Array

    def kept_only(self, in_use: jax.Array) -> Responsibilities:
        """The labels when only the intentions ``in_use [K]`` are kept (``--intentions
        auto``): each pair, and each demonstration, goes to its most likely kept intention."""
        pair_labels = jnp.argmax(jnp.where(in_use, self.pair_scores, -jnp.inf), -1)
        trajectory_labels = jnp.argmax(jnp.where(in_use, self.gamma, -1.0), -1)
        return self.replace(pair_labels=pair_labels, trajectory_labels=trajectory_labels)


def expert_responsibilities(
    apply: Callable,
    params,
    obs: jax.Array,
    actions: jax.Array,
    *,
    episode: jax.Array,
    episodes: int,
    mode: ResponsibilityMode,
    labels: jax.Array | None = None,
    weights: jax.Array | None = None,
    evidence_weight: jax.Array | None = None,
) -> Responsibilities:
    """The E-step's responsibilities of the expert pairs ``obs [N, D]`` (normalised),
    ``actions [N, A]`` (executed) under the posterior ``params``; ``mode`` is per pair
    (eq. 18), per demonstration (see :func:`trajectory_responsibilities`) or the oracle: the
    hidden ``labels [N]`` themselves, an oracle E-step that bounds what any E-step can give
    (not the paper's method; the pair labels are still the posterior's, for eq. 29).

    ``weights [K]``, the mixture prior w_i (None: uniform), reweigh the posterior, which was
    trained on policy samples in equal shares: gamma_i is proportional to w_i P(i | s, a)
    (per pair, or per demonstration with the product over its pairs), and so are the pair
    labels.

    ``evidence_weight [E]`` (per demonstration modes only; None: 1) weighs each
    demonstration's evidence (see :func:`trajectory_responsibilities`); the pair labels are
    untouched."""
    if evidence_weight is not None and not mode.per_demonstration:
        raise ValueError(f"the {mode.value} E-step has no trajectory evidence to weigh")
    log_p = log_posterior(apply, params, obs, actions)
    log_prior = None if weights is None else jnp.log(weights)
    log_joint = log_p if log_prior is None else log_p + log_prior  # log w_i P(i | s, a) + c
    pair_labels = jnp.argmax(log_joint, -1)
    if mode.oracle:
        if labels is None:
            raise ValueError("the labels E-step needs demonstrations with hidden labels")
        gamma = jax.nn.one_hot(labels, log_p.shape[-1])
        return Responsibilities(gamma, pair_labels, labels, log_joint)
    if mode.per_demonstration:
        gamma = trajectory_responsibilities(
            log_p, episode, episodes, mode.centered, log_prior, evidence_weight
        )
        return Responsibilities(gamma, pair_labels, jnp.argmax(gamma, -1), log_joint)
    gamma = jnp.exp(log_p) if log_prior is None else jax.nn.softmax(log_joint, -1)
    return Responsibilities(gamma, pair_labels, pair_labels, log_joint)


@struct.dataclass
class EStep:
    """What the E-step hands on."""

    posterior: Learner | None  # None without a posterior (GAIL)
    responsibilities: Responsibilities | None  # None without a posterior
    gamma: jax.Array  # [N, K] the M-step's weights of the expert pairs
    own_log_posterior: jax.Array  # [K, M] log P(i | s, a) of each sample's own intention
    weights: jax.Array  # [K] the mixture prior for the next E-step (1/K under the uniform prior)
    metrics: dict


# A floor for the mixture weights: an intention whose weight reached 0 (log 0) could never
# take a demonstration back.
MIN_WEIGHT = 1e-3


def mixture_weights(gamma: jax.Array) -> jax.Array:
    """``[K]`` EM's update of a mixture's weights: each intention's mean responsibility over
    the demonstration pairs ``gamma [N, K]``, floored at :data:`MIN_WEIGHT`."""
    weights = jnp.maximum(gamma.mean(0), MIN_WEIGHT)
    return weights / weights.sum()


def make_e_step(
    apply: Callable,
    optimizer: optax.GradientTransformation,
    config: EStepConfig,
    *,
    reward_from: RewardFrom = RewardFrom.UPDATED,
    evidence: Callable | None = None,
):
    """``e_step(posterior, batch, demos, weights, lesson=None, iteration=None) -> EStep``
    (Algorithm 1, E-step).

    The posterior ``posterior`` (a :class:`Learner`, or None for GAIL) learns P(i | s, a) on
    the policy samples of ``batch`` (a :class:`NormalizedBatch`), each labelled with the
    intention whose policy made it (eq. 16); gamma is then the posterior of the expert pairs
    in ``config.responsibilities``' mode (eq. 18, or per demonstration). Info/IntentionGAIL's
    reward term, the samples' own log-posterior, comes from the updated posterior or the
    previous one (``reward_from``). With the mixture prior (``config.prior``) gamma also
    weighs each intention by ``weights [K]``, and the E-step re-estimates them from gamma (EM
    for a mixture's weights); under the uniform prior they pass through unchanged.
    ``evidence(iteration, demos) -> [E] or None`` (a variant's hook,
    :mod:`emgail_jax.method.hooks`; None: none) weighs each demonstration's evidence at
    ``iteration`` (``[]`` int32, the updates done before this E-step:
    ``TrainState.iteration``). Without a posterior: uniform gamma, zero log-posterior.
    """
    mixture = config.prior.estimated

    def e_step(
        posterior: Learner | None,
        batch: NormalizedBatch,
        demos: DemonstrationPairs,
        weights: jax.Array,
        lesson: Lesson | None = None,
        iteration: jax.Array | None = None,
    ) -> EStep:
        k, m = batch.obs.shape[:2]
        own_intention = batch.own_intention()
        if posterior is None:
            uniform = jnp.full((demos.episode.shape[0], k), 1.0 / k)
            return EStep(None, None, uniform, jnp.zeros((k, m)), weights, {})
        flat = lambda x: x.reshape(k * m, -1)
        obs, actions = flat(batch.obs), flat(batch.executed)
        intentions = own_intention.reshape(-1)
        train = lambda learner, obs, actions, intentions, weights=None: posterior_update(
            apply,
            optimizer,
            learner,
            obs,
            actions,
            intentions,
            steps=config.steps,
            weights=weights,
        )
        trained, metrics = train(posterior, obs, actions, intentions)
        if lesson is not None:
            # More steps after the usual ones rather than other ones: a run without a
            # re-seeding computes exactly what it did before the option existed.
            taught = lambda: train(
                trained,
                jnp.concatenate([obs, batch.expert_obs]),
                jnp.concatenate([actions, batch.expert_actions]),
                jnp.concatenate([intentions, lesson.intentions]),
                jnp.concatenate([jnp.ones(k * m), lesson.weights]),
            )[0]
            trained = jax.lax.cond(lesson.active, taught, lambda: trained)
        responsibilities = expert_responsibilities(
            apply,
            trained.params,
            batch.expert_obs,
            batch.expert_actions,
            episode=demos.episode,
            episodes=demos.episodes,
            mode=config.responsibilities,
            labels=demos.labels if demos.has_labels else None,
            weights=weights if mixture else None,
            evidence_weight=None if evidence is None else evidence(iteration, demos),
        )
        if mixture:
            weights = mixture_weights(responsibilities.gamma)
            metrics = {**metrics, "posterior/intention_weights": weights}
        rewarding = reward_from.choose(updated=trained, previous=posterior)
        own = own_log_posterior(apply, rewarding.params, batch.obs, batch.executed, own_intention)
        chex.assert_shape(responsibilities.gamma, (demos.episode.shape[0], k))
        gamma = responsibilities.gamma
        return EStep(trained, responsibilities, gamma, own, weights, metrics)

    return e_step


def own_log_posterior(
    apply: Callable, params: Any, obs: jax.Array, actions: jax.Array, intention: jax.Array
) -> jax.Array:
    """``[...]`` log P(intention | s, a) of ``obs [..., D]``, ``actions [..., A]`` and
    ``intention [...]``: the term Info/IntentionGAIL's reward adds (eq. 23)."""
    log_p = log_posterior(apply, params, obs, actions)
    return jnp.take_along_axis(log_p, intention[..., None], -1)[..., 0]
