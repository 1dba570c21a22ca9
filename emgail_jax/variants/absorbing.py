"""Absorbing states (DAC, Kostrikov et al. 2019; ``--set absorbing_state=true``, off by default).

A termination leads to the absorbing state, one pair (normalised observation and action zeros,
the absorbing indicator 1: :class:`~emgail_jax.method.networks.Discriminator` with
``absorbing``) that the discriminator learns like any other: one absorbing sample per policy
transition that terminated, as a negative, and per demonstration that ended in one, as a
positive. One sample per termination, as DAC's replay holds one: the horizon it lasts enters
the B-step's value (:func:`~emgail_jax.method.gae.absorbing_value`), not D's loss, where a
policy that falls early would otherwise put most of the negatives' weight on that one pair.

It plugs into the update as a discriminator form (:class:`IndicatorForm`: f reads the
indicator, the batch carries the termination flags), a loss hook (:class:`AbsorbedSamples`)
and a termination hook (:class:`Absorbing`: the absorbing state's learned reward).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import jax
import jax.numpy as jnp

import envs
from emgail_jax.method.algorithms import Algorithm
from emgail_jax.method.batches import NormalizedBatch
from emgail_jax.method.config import MethodConfig
from emgail_jax.method.discriminator import LossHook, LossInputs
from emgail_jax.method.hooks import Form, Sampling, Termination
from emgail_jax.method.networks import Discriminator
from emgail_jax.method.rollout import intention_major, terminations
from emgail_jax.variants.extras import attached, extras_of


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


def with_absorbing(losses: jax.Array, absorbing_losses: jax.Array, counts: jax.Array):
    """The mean loss over ``losses`` (one per sample) and ``counts [C]`` absorbing samples
    whose losses are ``absorbing_losses [C]``."""
    return (losses.sum() + jnp.sum(counts * absorbing_losses)) / (losses.size + counts.sum())


@dataclass(frozen=True)
class AbsorbedSamples(LossHook):
    """The absorbing pair in the discriminator loss: as a real sample weighted ``expert [C]``
    under each condition (the summed weights of the demonstrations that ended in a
    termination), and as a fake one, ``policy [rows]`` samples under each row's condition (its
    terminations); each counts as one sample more in its term's mean."""

    expert: jax.Array
    policy: jax.Array

    @classmethod
    def of(cls, batch: NormalizedBatch, expert_weights: jax.Array) -> AbsorbedSamples:
        """The absorbing samples of ``batch``'s terminations, the expert pairs weighted
        ``expert_weights [N, C]``."""
        extras = extras_of(batch)
        return cls(extras.expert_terminal @ expert_weights, extras.terminal.sum(1))

    def terms(self, apply: Callable, params, inputs: LossInputs, expert_losses, policy_losses):
        sizes = (inputs.policy_obs.shape[-1], inputs.policy_actions.shape[-1])
        real = absorbing_logits(apply, params, inputs.conditions, *sizes)
        fake = absorbing_logits(apply, params, inputs.policy_conditions[:, 0], *sizes)
        expert_term = with_absorbing(expert_losses, jax.nn.softplus(-real), self.expert)
        policy_term = with_absorbing(policy_losses, jax.nn.softplus(fake), self.policy)
        return (
            expert_term,
            policy_term,
            {"discriminator/absorbing_d": jnp.mean(jax.nn.sigmoid(fake))},
        )


class IndicatorForm(Form):
    """The paper's discriminator with the absorbing indicator as one input more, its batch
    carrying the termination flags of the samples and of the demonstrations."""

    def network(self, config: MethodConfig) -> Discriminator:
        shape = config.networks
        return Discriminator(shape.hidden, shape.intention_input.heads, absorbing=True)

    def observed(self, batch: NormalizedBatch, sampling: Sampling) -> NormalizedBatch:
        length = sampling.env.episode_length
        return attached(
            batch,
            terminal=intention_major(terminations(sampling.transitions, length)),
            expert_terminal=sampling.demos.terminations(length),
        ).check()


def absorbing_reward(
    apply: Callable,
    params,
    algorithm: Algorithm,
    num_intentions: int,
    obs_size: int,
    action_size: int,
) -> jax.Array:
    """``[K]`` the learned reward of the absorbing state under each intention, as
    :func:`~emgail_jax.method.discriminator.learned_reward` scores a pair;
    Info/IntentionGAIL's lambda log P(i | s, a) taken at 1/K, since the absorbing state tells
    no intention from another."""
    intentions = jnp.arange(num_intentions)
    conditions = algorithm.discriminator_condition(intentions, num_intentions)  # [K, c]
    logits = absorbing_logits(apply, params, conditions, obs_size, action_size)
    return algorithm.pseudo_reward(logits, jnp.full(num_intentions, -jnp.log(num_intentions)))


class Absorbing(Termination):
    """A termination leads to the absorbing state, whose learned reward every step left to the
    time limit earns."""

    def reward(self, apply: Callable, params, algorithm: Algorithm, env: envs.Env):
        sizes = (env.num_intentions, env.observation_size, env.action_size)
        reward = absorbing_reward(apply, params, algorithm, *sizes)
        return reward, {"train/absorbing_reward": reward.mean()}
