"""Episode-length and auto-reset wrappers (pure, unbatched, like the envs they wrap)."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from envs.core import Env, State


class Wrapper(Env):
    """Delegates everything to the wrapped env; subclasses override ``reset``/``step``."""

    def __init__(self, env: Env):
        self.env = env

    name = property(lambda self: self.env.name)
    intention_names = property(lambda self: self.env.intention_names)
    num_intentions = property(lambda self: self.env.num_intentions)
    max_intentions = property(lambda self: self.env.max_intentions)
    observation_size = property(lambda self: self.env.observation_size)
    action_size = property(lambda self: self.env.action_size)
    episode_length = property(lambda self: self.env.episode_length)
    action_low = property(lambda self: self.env.action_low)
    action_high = property(lambda self: self.env.action_high)

    def reset(self, key: jax.Array) -> State:
        return self.env.reset(key)

    def step(self, state: State, action: jax.Array) -> State:
        return self.env.step(state, action)

    def options(self):
        return self.env.options()

    def program_key(self):
        return (type(self), self.episode_length, self.env.program_key())

    def trace(self, state: State):
        return self.env.trace(state)

    @property
    def unwrapped(self) -> Env:
        return self.env.unwrapped

    def __getattr__(self, name):
        # Env-specific extras (an expert, path geometry, ...) stay reachable through wrappers.
        if name == "env":
            raise AttributeError(name)
        return getattr(self.env, name)


class EpisodeWrapper(Wrapper):
    """Counts steps in ``info['steps']`` and ends the episode after ``episode_length`` steps.

    ``info['truncation']`` is 1.0 when the time limit, not the env, ended the episode.
    """

    def __init__(self, env: Env, episode_length: int | None = None):
        super().__init__(env)
        self._episode_length = int(episode_length or env.episode_length)

    episode_length = property(lambda self: self._episode_length)

    def reset(self, key: jax.Array) -> State:
        state = self.env.reset(key)
        info = {**state.info, "steps": jnp.zeros((), jnp.int32), "truncation": jnp.zeros(())}
        return state.replace(info=info)

    def step(self, state: State, action: jax.Array) -> State:
        steps = state.info["steps"] + 1
        next_state = self.env.step(state, action)
        out_of_time = (steps >= self._episode_length).astype(jnp.float32)
        truncation = out_of_time * (1.0 - next_state.done)
        done = jnp.maximum(next_state.done, out_of_time)
        info = {**next_state.info, "steps": steps, "truncation": truncation}
        return next_state.replace(done=done, info=info)


class AutoResetWrapper(Wrapper):
    """Starts a new episode once the current one is done.

    The initial state of the next episode is drawn in advance and kept in
    ``info['next_start']``: resetting on every step (to select the fresh state where an episode
    ended) would cost a full physics forward pass per step with MJX. :meth:`refresh` draws a
    new one; the rollout calls it once per rollout, so with rollouts of one episode every
    episode starts from its own random state (an env that ends twice within one rollout starts
    twice from the same state).

    The state returned after the last step of an episode is the first state of the next one,
    except for ``reward`` and ``done``, which still describe the transition just made.
    """

    def reset(self, key: jax.Array) -> State:
        key_now, key_next = jax.random.split(key)
        state = self.env.reset(key_now)
        return self.refresh(state, key_next)

    def refresh(self, state: State, key: jax.Array) -> State:
        """Draws the initial state of the next episode."""
        return state.replace(info={**state.info, "next_start": self.env.reset(key)})

    def step(self, state: State, action: jax.Array) -> State:
        return self.step_and_observe(state, action)[0]

    def step_and_observe(self, state: State, action: jax.Array) -> tuple[State, jax.Array]:
        """:meth:`step`, and the observation the transition reached: at an episode's end the
        last one of that episode, which the state returned already replaced (AIRL's s' at a
        time limit)."""
        next_state = self.env.step(state, action)
        start = next_state.info["next_start"]
        start = start.replace(info={**start.info, "next_start": start})
        done = next_state.done.astype(bool)
        merged = jax.tree.map(lambda a, b: jnp.where(done, a, b), start, next_state)
        return merged.replace(reward=next_state.reward, done=next_state.done), next_state.obs


def wrap_for_training(env: Env, episode_length: int | None = None) -> Env:
    """The env as the learner and the expert trainer use it: time limit, then auto-reset."""
    return AutoResetWrapper(EpisodeWrapper(env, episode_length))
