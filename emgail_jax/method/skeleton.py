"""The trainer skeleton that the IRL loop and plain RL both run, and its policy-side stages.

One iteration (:func:`make_update`):

1. collect: T steps of the ``[K, B]`` auto-resetting envs with the current policy (the IRL loop
   also runs its evaluation episodes here, see :mod:`emgail_jax.method.training`);
2. normalise: the rollout joins the running observation statistics;
3. reward: the stage that differs between trainers labels every sample with a reward ``[T, K,
   B]``: EM-GAIL's, Info/IntentionGAIL's or GAIL's E-step, M-step and learned reward
   (:mod:`~emgail_jax.method.training`), or the env's true reward or a frozen learned reward
   (:mod:`~emgail_jax.method.rl`);
4. improve: the B-step (:mod:`~emgail_jax.method.b_step`) on that reward;
5. evaluate (plain RL only): deterministic episodes of the improved policy.

A trainer's state is any pytree with the fields ``policy``, ``value``, ``normalizer``,
``env_state``, ``key`` and ``iteration``; the reward stage may replace others (the IRL loop's
discriminator, posterior, ...).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import struct

import envs
from emgail_jax.method import normalizer as obs_norm
from emgail_jax.method.b_step import BStep, PolicySamples, make_b_step
from emgail_jax.method.batches import LearningBatch
from emgail_jax.method.config import MethodConfig
from emgail_jax.method.gae import absorbing_value
from emgail_jax.method.networks import GaussianPolicy, ValueNet, policy_action
from emgail_jax.method.rollout import Policy, Transitions, rollout, steps_left, time_major
from emgail_jax.method.value import ValueLearner

# intentions [...] (int) -> the policy's and the value's intention input [..., C] (C may be 0)
Condition = Callable[[Any], jax.Array]


def unconditioned(intentions) -> jax.Array:
    """The empty condition of a policy that serves one intention (plain RL, GAIL)."""
    return jnp.zeros((*np.shape(intentions), 0))


def intention_rows(shape: tuple[int, ...]) -> np.ndarray:
    """``shape`` (int): the intention of every entry in the intention-major layout, where the
    leading axis is the intention (row k is k)."""
    if not shape:
        return np.zeros((), np.int32)
    rows = np.arange(shape[0]).reshape(-1, *(1,) * (len(shape) - 1))
    return np.broadcast_to(rows, shape)


@dataclass(frozen=True)
class PolicyStages:
    """The policy side of a trainer, written once: pi and V, how they are initialised and act,
    the rollout, and the B-step on a given reward."""

    policy: GaussianPolicy
    value: ValueNet
    value_optimizer: optax.GradientTransformation
    condition: Condition
    config: MethodConfig  # resolved for the env
    observation_size: int
    episode_length: int

    @classmethod
    def create(
        cls, policy: GaussianPolicy, value: ValueNet, condition: Condition, config, env: envs.Env
    ) -> PolicyStages:
        """The stages of ``policy`` and ``value`` on ``env``; ``config`` resolved for it."""
        optimizer = optax.adam(config.b_step.value_learning_rate)
        return cls(
            policy, value, optimizer, condition, config, env.observation_size, env.episode_length
        )

    @property
    def b_step(self) -> Callable:
        return make_b_step(
            self.policy.apply, self.value.apply, self.value_optimizer, self.config.b_step
        )

    def init(self, key_policy: jax.Array, key_value: jax.Array) -> tuple[Any, ValueLearner]:
        """Fresh policy parameters and a fresh value :class:`ValueLearner`."""
        obs = jnp.zeros((1, self.observation_size))
        condition = self.condition(intention_rows((1,)))
        value = self.value.init(key_value, obs, condition, jnp.zeros(1))
        policy = self.policy.init(key_policy, obs, condition)
        scaling = self.config.b_step.value_target_scaling
        return policy, ValueLearner.create(value, self.value_optimizer, scaling)

    def acting(self, params, normalizer: obs_norm.RunningStats, explore) -> Policy:
        """``policy(obs [K, ...], key) -> action``: row k acts as intention k (an unconditioned
        policy ignores the row). ``explore`` (True, False or a traced bool) adds the Gaussian
        noise; False takes the mean and needs no key."""

        def policy(obs, key):
            return policy_action(
                self.policy,
                params,
                normalizer,
                obs,
                self.condition(intention_rows(obs.shape[:-1])),
                obs_clip=self.config.networks.obs_clip,
                key=None if explore is False else key,
                explore=explore,
                intention_major=True,
            )

        return policy

    @property
    def records_next_obs(self) -> bool:
        """Whether the rollout records the observations its steps reach (AIRL's discriminator
        reads them)."""
        return self.config.m_step.form.airl

    def collect(
        self, env: envs.Env, policy: Policy, env_state: envs.State, key: jax.Array
    ) -> tuple[envs.State, Transitions]:
        """Step 1: ``rollout_length`` steps of the auto-resetting ``env`` from ``env_state``
        with ``policy`` (:func:`~emgail_jax.method.rollout.rollout`), the observations reached
        recorded where :attr:`records_next_obs`."""
        length = self.config.rollout.rollout_length
        return rollout(env, policy, env_state, key, length, next_obs=self.records_next_obs)

    def improve(
        self,
        state,
        batch: LearningBatch,
        normalizer: obs_norm.RunningStats,
        reward,
        key,
        absorbing_reward=None,
    ) -> BStep:
        """Step 4: the B-step of ``state``'s policy and value on ``reward [T, K, B]`` for
        ``batch``, its observations normalised with ``normalizer`` (the rollout's included).
        ``absorbing_reward [K]``: the reward of every step a row's episode has left after a
        termination (DAC's absorbing state); None: nothing follows an episode's end."""
        t, k, b = reward.shape
        rows = intention_rows((k, t * b))
        samples = PolicySamples.of(
            batch,
            lambda x: obs_norm.normalize(normalizer, x, self.config.networks.obs_clip),
            time_major(self.condition(rows), t),
            self.condition(intention_rows((k, b))),
        )
        end_values = None
        if absorbing_reward is not None:
            left = steps_left(batch.time, self.episode_length)  # 0 at a time limit
            end_values = absorbing_value(absorbing_reward[:, None], left, self.config.b_step.gamma)
        return self.b_step(state.policy, state.value, samples, reward, key, end_values)


@struct.dataclass
class Rewarded:
    """What a reward stage hands the B-step: the reward, and the state it changed."""

    reward: jax.Array  # [T, K, B]
    state: dict  # the trainer state's fields the stage replaces (none for plain RL)
    metrics: dict
    # [K] the reward of the absorbing state a termination leads to, per row (DAC); None: an
    # episode's end is worth 0 (the true reward, a run without absorbing states).
    absorbing_reward: jax.Array | None = None


# (state, key, *inputs) -> (end env state, transitions [T, K, B, ...], metrics)
Collect = Callable[..., tuple[envs.State, Transitions, dict]]
# (state, transitions, normalizer, *inputs) -> Rewarded
RewardStage = Callable[..., Rewarded]
# (improved state, key, *inputs) -> metrics
Evaluate = Callable[..., dict]


def make_update(
    stages: PolicyStages, collect: Collect, reward: RewardStage, evaluate: Evaluate | None = None
):
    """``update(state, *inputs) -> (state, metrics)``: one iteration of the skeleton (module
    docstring); ``inputs`` are the trainer's per-call arguments, handed to every stage."""

    def update(state, *inputs):
        # An evaluation after the update draws one key more (plain RL's layout of keys).
        keys = jax.random.split(state.key, 3 if evaluate is None else 4)
        key_next, key_collect, key_value = keys[:3]
        end, transitions, collected = collect(state, key_collect, *inputs)
        normalizer = obs_norm.update(state.normalizer, transitions.obs)
        rewarded = reward(state, transitions, normalizer, *inputs)
        batch = LearningBatch.of(transitions, end, stages.episode_length)
        improved = stages.improve(
            state, batch, normalizer, rewarded.reward, key_value, rewarded.absorbing_reward
        )
        new_state = state.replace(
            policy=improved.policy,
            value=improved.value,
            normalizer=normalizer,
            env_state=end,
            key=key_next,
            iteration=state.iteration + 1,
            **rewarded.state,
        )
        evaluated = {} if evaluate is None else evaluate(new_state, keys[3], *inputs)
        metrics = {**collected, **rewarded.metrics, **improved.metrics, **evaluated}
        return new_state, metrics

    return update
