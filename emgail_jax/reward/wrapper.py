"""An env of this package that pays a learned reward in place of its own.

>>> env = LearnedRewardEnv(envs.make("driver", intentions=2), load_reward(RUN), intention=0)
>>> state = env.step(env.reset(key), action)   # state.reward[0]: learned intention 0's reward

Any RL that reads ``State.reward`` then trains on the learned reward, a termination paid as the
check paid its fresh agents (:meth:`~emgail_jax.reward.load.LearnedReward.termination`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

import envs
from emgail_jax.method.config import BStepConfig
from emgail_jax.method.gae import absorbing_value

# The steps taken since the episode began, kept in ``State.info``: what a termination's steps
# left are counted from.
STEPS = "learned_reward_steps"


class LearnedRewardEnv(envs.Wrapper):
    """``env`` whose ``State.reward [K]`` pays learned intention ``intention``'s reward
    ``reward(obs, action, intention)`` of the transition in place of the env's own (None:
    every intention k its learned intention k's; the others keep the env's); ``reward`` a
    :class:`~emgail_jax.reward.load.LearnedReward` or any function of that signature. Where the step
    ends the episode before the time limit with ``m`` steps left, the reward adds
    ``reward.termination(intention) * sum_{j=1..m} gamma^j``: what the check's TRPO
    bootstraps for the absorbing state a fall leads to. Give ``gamma``, your RL's discount
    (default the package's, see docs/defaults.md, `gamma`); ``gamma=1`` pays every step
    left alike. Wrap the bare env: the time limit and resets outside (as
    ``envs.wrap_for_training`` puts them)."""

    def __init__(self, env: envs.Env, reward, intention: int | None = None, gamma=None):
        super().__init__(env)
        if intention is not None and not 0 <= intention < env.num_intentions:
            raise envs.EnvError(
                f"intention {intention}: the env has intentions 0..{env.num_intentions - 1}"
            )
        self.reward = reward
        self.intention = intention
        self.gamma = BStepConfig().gamma if gamma is None else float(gamma)

    def reset(self, key: jax.Array) -> envs.State:
        state = self.env.reset(key)
        return state.replace(info={**state.info, STEPS: jnp.zeros((), jnp.int32)})

    def step(self, state: envs.State, action: jax.Array) -> envs.State:
        next_state = self.env.step(state, action)
        k = self.num_intentions
        rows = jnp.arange(k) if self.intention is None else jnp.array([self.intention])
        obs = jnp.broadcast_to(state.obs, (len(rows), *state.obs.shape))
        actions = jnp.broadcast_to(action, (len(rows), *jnp.shape(action)))
        paid = self.reward(obs, actions, rows)
        steps = state.info[STEPS]
        left = self.episode_length - 1 - steps
        ended = next_state.done * (left > 0)  # a termination, not the time limit
        termination = getattr(self.reward, "termination", None)  # a plain function: none
        if termination is not None:
            fall = self.gamma * absorbing_value(termination(rows), left, self.gamma)
            paid = paid + ended * fall
        reward = next_state.reward.at[rows].set(paid.astype(next_state.reward.dtype))
        # An env that resets itself starts counting anew.
        counted = jnp.where(next_state.done > 0, 0, steps + 1).astype(jnp.int32)
        return next_state.replace(reward=reward, info={**next_state.info, STEPS: counted})

    def program_key(self):
        return (type(self), self.intention, self.gamma, id(self.reward), self.env.program_key())
