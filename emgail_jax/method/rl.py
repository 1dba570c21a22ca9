"""Reinforcement learning of one policy per intention on a given reward, with TRPO.

Trains the experts (on the true reward of their intention, :mod:`emgail_jax.experts`) and
re-optimises a learned reward to check it is a reward (the paper's ERD, §5.2). One trainer
learns one unconditioned policy from B auto-resetting envs; callers ``vmap`` it over the
intentions (and seeds):

    trainer = make_rl_train(config, env, reward_fn)
    states = jax.vmap(trainer.init)(keys)                              # [K] independent policies
    states, metrics = jax.vmap(trainer.update)(states, jnp.arange(K))  # intention k trains k

or, over seeds and in compiled chunks (host side),
``seed_runner.intention_runner(trainer, jnp.arange(K), seeds)``.

A learned reward takes its parameters as ``reward_data`` (an argument of the compiled program,
not constants in it), so that the rewards of several run seeds share one program
(:func:`seeds_chunk`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from flax import struct

import envs
from emgail_jax.method import normalizer as obs_norm
from emgail_jax.method.config import MethodConfig
from emgail_jax.method.networks import GaussianPolicy, ValueNet
from emgail_jax.method.optim import Learner
from emgail_jax.method.rollout import batch_reset, episode_returns, steps_left, terminations
from emgail_jax.method.skeleton import PolicyStages, Rewarded, make_update, unconditioned

# (obs [T, 1, B, D] raw, action [T, 1, B, A], true_reward [T, 1, B, K], intention [],
#  reward_data: the reward's parameters, any pytree or None) -> [T, 1, B]
RewardFn = Callable[[jax.Array, jax.Array, jax.Array, jax.Array, Any], jax.Array]
# (intention [], reward_data) -> [] the learned reward of the absorbing state (DAC)
AbsorbingRewardFn = Callable[[jax.Array, Any], jax.Array]


def true_reward(obs, action, reward, intention, reward_data=None):
    """The env's own reward of the intention being trained (for the experts)."""
    return jnp.take(reward, intention, axis=-1)


def reward_per_step(rewards, transitions, episode_length: int, absorbed=None) -> jax.Array:
    """``[]`` the reward per step ``rewards [T, 1, B]`` paid the samples ``transitions``; with
    ``absorbed [1]`` (the absorbing state's reward) a termination is paid it for every step
    left to the time limit, those steps counted too, as the B-step bootstraps it: a policy
    that falls earns what falling is worth."""
    if absorbed is None:
        return rewards.mean()
    left = terminations(transitions, episode_length) * steps_left(transitions.time, episode_length)
    return (rewards.sum() + absorbed[0] * left.sum()) / (rewards.size + left.sum())


@struct.dataclass
class RLState:
    policy: Any  # the policy's parameters
    value: Learner
    normalizer: obs_norm.RunningStats
    env_state: envs.State  # [1, B]
    key: jax.Array
    iteration: jax.Array


def make_rl_train(
    config: MethodConfig,
    env: envs.Env,
    reward_fn: RewardFn = true_reward,
    eval_episodes: int = 5,
    absorbing_reward: AbsorbingRewardFn | None = None,
):
    """Builds ``init(key) -> RLState``, ``update(state, intention, reward_data=None,
    evaluating=True) -> (state, metrics)`` and ``policy(state, deterministic) -> (obs, key) ->
    action``: the trainer skeleton (:mod:`~emgail_jax.method.skeleton`) with ``reward_fn`` as its
    reward stage; an update ``evaluating`` scores the new policy on ``eval_episodes``
    deterministic episodes (NaN returns otherwise; the keys and the training are the same
    either way). With
    ``absorbing_reward`` (a learned reward of a run with absorbing states), a termination is
    worth that reward for every step left to the time limit, as in the run's B-step."""
    config = config.resolved(env)
    train_env = envs.wrap_for_training(env)
    eval_env = envs.EpisodeWrapper(env)
    policy_net = GaussianPolicy(
        env.action_size, config.networks.hidden, config.networks.init_log_std
    )
    stages = PolicyStages.create(
        policy_net, ValueNet(config.networks.hidden), unconditioned, config, env
    )

    def init(key: jax.Array) -> RLState:
        key_policy, key_value, key_env, key_next = jax.random.split(key, 4)
        policy, value = stages.init(key_policy, key_value)
        return RLState(
            policy=policy,
            value=value,
            normalizer=obs_norm.RunningStats.create(env.observation_size),
            env_state=batch_reset(train_env, key_env, (1, config.rollout.num_envs)),
            key=key_next,
            iteration=jnp.zeros((), jnp.int32),
        )

    def collect(state: RLState, key, intention, reward_data, evaluating):
        behaviour = stages.acting(state.policy, state.normalizer, explore=True)
        return (*stages.collect(train_env, behaviour, state.env_state, key), {})

    def reward(state: RLState, batch, normalizer, intention, reward_data, evaluating) -> Rewarded:
        rewards = reward_fn(batch.obs, batch.action, batch.true_reward, intention, reward_data)
        absorbed = None
        if absorbing_reward is not None:
            absorbed = absorbing_reward(intention, reward_data)[None]  # [1]: the one row
        earned = reward_per_step(rewards, batch, env.episode_length, absorbed)
        return Rewarded(rewards, {}, {"train/reward": earned}, absorbed)

    # Fresh episodes of the improved policy, not the IRL loop's evaluation phases: the experts
    # and the baselines' cached numbers were made with these keys.
    def evaluate(state: RLState, key, intention, reward_data, evaluating) -> dict:
        def scored():  # [K] under every true intention
            greedy = stages.acting(state.policy, state.normalizer, explore=False)
            return episode_returns(eval_env, greedy, key, 1, eval_episodes)[0]

        not_scored = lambda: jnp.full(env.num_intentions, jnp.nan, jnp.float32)
        returns = jax.lax.cond(evaluating, scored, not_scored)
        return {"eval/returns": returns, "eval/own_return": jnp.take(returns, intention)}

    iteration = make_update(stages, collect, reward, evaluate)

    def update(
        state: RLState, intention: jax.Array, reward_data=None, evaluating=True
    ) -> tuple[RLState, dict]:
        return iteration(state, intention, reward_data, jnp.asarray(evaluating))

    def policy(state: RLState, deterministic: bool = True):
        """The trained policy as ``(obs [..., D], key) -> action``."""
        return stages.acting(state.policy, state.normalizer, explore=not deterministic)

    return RLTrainer(init, update, policy)


class RLTrainer(NamedTuple):
    init: Callable[[jax.Array], RLState]
    update: Callable[..., tuple[RLState, dict]]
    policy: Callable[..., Callable]


def intention_chunk(trainer: RLTrainer, intentions: jax.Array) -> Callable:
    """One seed's ``chunk(states [I], evaluating [L]) -> (states, metrics [L, I, ...])``,
    jitted: ``L`` iterations of one policy per entry of ``intentions [I]`` (vmapped), iteration
    ``l`` scored on evaluation episodes where ``evaluating[l]``, for callers that hold one
    seed's states themselves (experiments/rl_floor.py)."""

    def chunk(states, evaluating):
        update = jax.vmap(trainer.update, (0, 0, None, None))
        return jax.lax.scan(lambda s, e: update(s, intentions, None, e), states, evaluating)

    return jax.jit(chunk)


def seeds_chunk(trainer: RLTrainer, intentions: jax.Array) -> Callable:
    """``chunk(states [S, I], evaluating [L], reward_data [S, ...]) -> (states, metrics [L, S,
    I, ...])``, jitted: :func:`intention_chunk` for ``S`` rewards at once, reward ``s`` (its
    parameters ``reward_data[s]``, shared by its ``I`` policies) training the row ``s`` of
    policies (re-optimising every seed of a run, :mod:`emgail_jax.reoptimize`)."""

    def chunk(states, evaluating, reward_data):
        one_reward = lambda s, data, e: jax.vmap(trainer.update, (0, 0, None, None))(
            s, intentions, data, e
        )
        step = lambda s, e: jax.vmap(one_reward, (0, 0, None))(s, reward_data, e)
        return jax.lax.scan(step, states, evaluating)

    return jax.jit(chunk)
