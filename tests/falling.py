"""A toy env that falls, and a toy learned reward, for the tests of the learned reward's env
wrapper and its fresh agents: every number they pay is known in closed form."""

import jax.numpy as jnp

from emgail_jax.reward import LearnedReward
from envs.core import Env, State

LENGTH = 10
FALLS_AT = 3


class Falling(Env):
    """Two intentions paid 1 and 2 a step; the episode ends after FALLS_AT steps."""

    name = "falling"
    intention_names = ("a", "b")
    terminates = True
    observation_size = property(lambda self: 2)
    action_size = property(lambda self: 1)
    episode_length = property(lambda self: LENGTH)

    def reset(self, key):
        zero = jnp.zeros(())
        return State(physics=jnp.zeros((), jnp.int32), obs=jnp.zeros(2), reward=jnp.zeros(2),
                     done=zero)  # fmt: skip

    def step(self, state, action):
        count = state.physics + 1
        return state.replace(
            physics=count,
            obs=state.obs + jnp.concatenate([action, action]),
            reward=jnp.array([1.0, 2.0]),
            done=(count >= FALLS_AT).astype(jnp.float32),
        )


def toy_reward(termination=(0.5, -1.0)):
    return LearnedReward(
        parameters={"w": jnp.array(2.0)},
        termination_values=jnp.array(termination),
        function=lambda p, obs, action, i: p["w"] * obs.sum(-1) + action.sum(-1) + i,
        run="x",
        seed=0,
        source="refit",
        form="log-d",
    )
