"""The hooks of a run's config (:func:`hooks_for`): each variant the config turns on, in its
place of :class:`~emgail_jax.method.hooks.Hooks`, and the paper's method elsewhere."""

from __future__ import annotations

from dataclasses import dataclass

import envs
from emgail_jax.method import training
from emgail_jax.method.algorithms import Algorithm
from emgail_jax.method.batches import NormalizedBatch
from emgail_jax.method.config import MethodConfig
from emgail_jax.method.discriminator import LossHook, LossInputs, Read
from emgail_jax.method.hooks import Form, Hooks, Negatives, Sampling, Termination
from emgail_jax.variants.absorbing import AbsorbedSamples, Absorbing, IndicatorForm
from emgail_jax.variants.airl import AirlForm, LogitOffsets
from emgail_jax.variants.penalty import GradientPenalty
from emgail_jax.variants.replay import Replayed
from emgail_jax.variants.support import SupportNoise
from emgail_jax.variants.tempering import evidence_of


@dataclass(frozen=True)
class Chained(Negatives):
    """Several variants' further negatives, each on the batch the previous one made; the carry
    is the tuple of theirs."""

    parts: tuple[Negatives, ...]

    def init(self, config: MethodConfig, env: envs.Env, key) -> tuple:
        return tuple(part.init(config, env, key) for part in self.parts)

    def __call__(self, carry: tuple, seen: NormalizedBatch, sampling: Sampling):
        carries = []
        for part, own in zip(self.parts, carry, strict=True):
            own, seen = part(own, seen, sampling)
            carries.append(own)
        return tuple(carries), seen


UNCHANGED = LossHook()


@dataclass(frozen=True)
class Combined(LossHook):
    """The loss hooks of several variants, each in its own part of the loss: the logits' (a
    form's offsets), the terms' (absorbing samples) and the regulariser's."""

    logits_from: LossHook = UNCHANGED
    terms_from: LossHook = UNCHANGED
    regulariser_from: LossHook = UNCHANGED

    def logits(self, real, fake):
        return self.logits_from.logits(real, fake)

    def terms(self, apply, params, inputs: LossInputs, expert_losses, policy_losses):
        return self.terms_from.terms(apply, params, inputs, expert_losses, policy_losses)

    def regulariser(self, apply, params, inputs: LossInputs):
        return self.regulariser_from.regulariser(apply, params, inputs)


@dataclass(frozen=True)
class VariantLoss:
    """The M-step's loss hook of ``config`` (``(batch, read, gamma, algorithm) -> LossHook``):
    a form's offsets, absorbing samples and the gradient penalty, as the config asks."""

    absorbing: bool
    penalty: float

    def __call__(self, batch: NormalizedBatch, read: Read, gamma, algorithm: Algorithm):
        parts = {}
        if read.offsets is not None:
            parts["logits_from"] = LogitOffsets(read.offsets, read.expert_offsets)
        if self.absorbing:
            parts["terms_from"] = AbsorbedSamples.of(batch, algorithm.expert_weights(gamma))
        if self.penalty:
            parts["regulariser_from"] = GradientPenalty(self.penalty)
        return Combined(**parts)


def form_of(config: MethodConfig) -> Form:
    if config.m_step.form.airl:
        return AirlForm()
    return IndicatorForm() if config.reward.absorbing_state else Form()


def negatives_of(config: MethodConfig, form: Form) -> Negatives:
    parts = []
    if config.m_step.replay:
        reread = form.densities if isinstance(form, AirlForm) else None
        parts.append(Replayed(config.m_step.replay, reread))
    if config.m_step.support_noise:
        parts.append(SupportNoise(config.m_step.support_noise))
    if not parts:
        return Negatives()
    return parts[0] if len(parts) == 1 else Chained(tuple(parts))


def hooks_for(config: MethodConfig) -> Hooks:
    """The hooks of the variants ``config`` turns on (the paper's method where it turns none)."""
    form = form_of(config)
    absorbing, penalty = config.reward.absorbing_state, config.m_step.gradient_penalty
    uses_loss = absorbing or penalty or isinstance(form, AirlForm)
    return Hooks(
        form=form,
        negatives=negatives_of(config, form),
        loss=VariantLoss(absorbing, penalty) if uses_loss else None,
        termination=Absorbing() if absorbing else Termination(),
        evidence=evidence_of(config.e_step),
    )


def make_train(config: MethodConfig, env: envs.Env) -> training.Trainer:
    """The update of ``config`` with its variants (:func:`~emgail_jax.method.training.make_train`
    with :func:`hooks_for` them)."""
    return training.make_train(config, env, hooks_for(config))
