"""The B-step (paper Alg. 1): improve the policy on a given reward with TRPO.

Shared by the three IRL algorithms (reward: the pseudo-reward), the expert trainer (the true
reward) and the re-optimisation check (a frozen learned reward): GAE on the rollout, advantages
standardised per intention, one TRPO step of the policy on all samples, and a refit of the value
baseline.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import chex
import jax
import optax
from flax import struct

from emgail_jax.method.batches import LearningBatch
from emgail_jax.method.config import BStepConfig
from emgail_jax.method.gae import generalized_advantages
from emgail_jax.method.networks import action_distribution
from emgail_jax.method.rollout import intention_major, time_major
from emgail_jax.method.trpo import trpo_step
from emgail_jax.method.value import ValueLearner, fit_value


@struct.dataclass
class PolicySamples:
    """A rollout as the policy and the value function see it (observations normalised)."""

    obs: jax.Array  # [T, K, B, D]
    action: jax.Array  # [T, K, B, A]
    condition: jax.Array  # [T, K, B, C] the policy's intention input (C may be 0)
    time: jax.Array  # [T, K, B] t / episode_length
    done: jax.Array  # [T, K, B]
    last_obs: jax.Array  # [K, B, D] the state after the rollout, for the bootstrap value
    last_condition: jax.Array  # [K, B, C]
    last_time: jax.Array  # [K, B]

    @classmethod
    def of(
        cls,
        batch: LearningBatch,
        normalize: Callable[[jax.Array], jax.Array],
        condition: jax.Array,
        last_condition: jax.Array,
    ) -> PolicySamples:
        """A rollout as the B-step reads it, in the IRL loop and in plain RL alike: the
        observations ``normalize``d, and the policy's intention inputs ``condition [T, K, B, C]``
        and ``last_condition [K, B, C]``."""
        return cls(
            obs=normalize(batch.obs),
            action=batch.action,
            condition=condition,
            time=batch.time,
            done=batch.done,
            last_obs=normalize(batch.last_obs),
            last_condition=last_condition,
            last_time=batch.last_time,
        )


@struct.dataclass
class BStep:
    """What the B-step hands on."""

    policy: Any  # the policy's parameters (TRPO keeps no optimiser state)
    value: ValueLearner
    metrics: dict


def make_b_step(
    policy_apply: Callable,
    value_apply: Callable,
    value_optimizer: optax.GradientTransformation,
    config: BStepConfig,
):
    """``b_step(policy, value, samples, reward, key, end_values=None) -> BStep``: one policy
    improvement of the policy parameters ``policy`` on ``reward [T, K, B]`` for ``samples`` (a
    :class:`PolicySamples`), and a refit of the value baseline ``value`` (a
    :class:`~emgail_jax.method.value.ValueLearner`).
    ``end_values [T, K, B]``: V of the state an episode ends in (GAE's; None: 0).

    The networks see the samples grouped by intention (``[K, T * B]``, see
    :func:`~emgail_jax.method.rollout.intention_major`), GAE sees them in time order.
    """

    def b_step(
        policy: Any,
        value: ValueLearner,
        samples: PolicySamples,
        reward: jax.Array,
        key: jax.Array,
        end_values: jax.Array | None = None,
    ) -> BStep:
        chex.assert_equal_shape((reward, samples.time, samples.done))
        chex.assert_equal_shape_prefix((samples.obs, samples.action, samples.condition), 3)
        t = reward.shape[0]
        obs, action, condition, time = map(
            intention_major, (samples.obs, samples.action, samples.condition, samples.time)
        )
        predict = lambda *inputs: value.values(
            value_apply(value.params, *inputs, intention_major=True)
        )
        values = time_major(predict(obs, condition, time), t)
        bootstrap = predict(samples.last_obs, samples.last_condition, samples.last_time)
        advantages, returns = generalized_advantages(
            reward,
            values,
            samples.done,
            bootstrap,
            config.gamma,
            config.gae_lambda,
            end_values=end_values,
        )
        # Each intention's advantages are standardised on their own, so that no intention's
        # reward scale dominates a shared policy update.
        advantages = intention_major(advantages)  # [K, T * B]
        mean = advantages.mean(1, keepdims=True)
        std = advantages.std(1, keepdims=True)
        advantages = (advantages - mean) / (std + 1e-8)

        def distribution(params):
            return action_distribution(*policy_apply(params, obs, condition, intention_major=True))

        policy, policy_metrics = trpo_step(distribution, policy, action, advantages, config.trpo)
        value_predict = lambda params, *inputs: value_apply(params, *inputs, intention_major=True)
        value, targets = value.fitting_targets(intention_major(returns))
        value, value_metrics = fit_value(
            value_predict,
            value_optimizer,
            value,
            (obs, condition, time),
            targets,
            key,
            epochs=config.value_epochs,
            minibatches=config.value_minibatches,
        )
        return BStep(policy, value, {**policy_metrics, **value_metrics})

    return b_step
