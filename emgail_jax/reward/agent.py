"""A fresh agent trained on an env's reward: the check's TRPO (:mod:`emgail_jax.method.rl`), one
policy, from scratch.

>>> env = LearnedRewardEnv(envs.make("driver", intentions=2), load_reward(RUN), intention=0)
>>> agent = train_agent(env, intention=0, iterations=100)
>>> agent.returns      # [K] its true returns, the env's own rewards
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp

import envs
from emgail_jax.method.config import BStepConfig, MethodConfig
from emgail_jax.method.rl import intention_chunk, make_rl_train
from emgail_jax.method.rollout import episode_returns


class Agent(NamedTuple):
    """A trained policy, ``policy(obs [..., D]) -> action`` (its mean action, jittable), its
    trainer's state, and ``returns [K]``: its mean return under every intention's true
    reward over the deterministic episodes it was scored on."""

    policy: Callable[[jax.Array], jax.Array]
    state: object
    returns: jax.Array


def train_agent(
    env: envs.Env,
    intention: int = 0,
    iterations: int = 100,
    *,
    gamma: float | None = None,
    gae_lambda: float | None = None,
    seed: int = 0,
    episodes: int = 5,
) -> Agent:
    """A policy trained from scratch with TRPO for ``iterations`` on ``env``'s reward of
    ``intention`` (a :class:`~emgail_jax.reward.wrapper.LearnedRewardEnv`'s: the learned
    one), with the package's defaults (docs/defaults.md), ``gamma`` and ``gae_lambda`` where
    given (default the env's own ``gamma`` if it pays a termination by one); scored under the
    true rewards of ``env.unwrapped`` on ``episodes`` deterministic episodes."""
    defaults = BStepConfig()
    b_step = defaults.replace(
        gamma=getattr(env, "gamma", defaults.gamma) if gamma is None else gamma,
        gae_lambda=defaults.gae_lambda if gae_lambda is None else gae_lambda,
    )
    trainer = make_rl_train(MethodConfig(b_step=b_step), env, eval_episodes=episodes)
    key_train, key_score = jax.random.split(jax.random.PRNGKey(seed))
    states = jax.vmap(trainer.init)(key_train[None])
    chunk = intention_chunk(trainer, jnp.array([intention]))
    states, _ = chunk(states, jnp.zeros(iterations, bool))
    state = jax.tree.map(lambda x: x[0], states)
    act = trainer.policy(state)
    policy = lambda obs: act(obs, None)
    score_env = envs.EpisodeWrapper(env.unwrapped)
    returns = jax.jit(lambda key: episode_returns(score_env, act, key, 1, episodes)[0])
    return Agent(policy, state, returns(key_score))
