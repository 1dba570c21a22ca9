"""Expert demonstrations in memory: the labelled (observation, action) pairs, their pure
transforms, and their generation from an expert policy (files: ``host/demonstration_files.py``)."""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

import envs


@dataclasses.dataclass(frozen=True)
class Demonstrations:
    observations: np.ndarray
    actions: np.ndarray
    episode_starts: np.ndarray
    intentions: np.ndarray | None = None
    expert_returns: np.ndarray | None = None
    # What a Minari dataset holds beside the pairs (training reads neither): each pair's true
    # reward under its own intention [N], and the observation after each demonstration's last
    # action [E, obs_dim].
    rewards: np.ndarray | None = None
    final_observations: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.observations)

    @property
    def episode(self) -> np.ndarray:
        """``[N]`` the index of each pair's demonstration (episode), pairs before the first
        episode start counted in the first."""
        return np.maximum(np.cumsum(self.episode_starts) - 1, 0)

    @property
    def episodes(self) -> int:
        """E, the number of demonstrations (episodes)."""
        return int(self.episode[-1]) + 1 if len(self) else 0

    @property
    def step_in_episode(self) -> np.ndarray:
        """``[N]`` each pair's step within its demonstration."""
        return np.arange(len(self)) - np.flatnonzero(self.episode_starts)[self.episode]

    def next_observations(self) -> np.ndarray | None:
        """``[N, obs_dim]`` float32: the observation each pair reached, the next pair's within a
        demonstration and its final observation after its last pair; None without final
        observations (the shipped files and :func:`generate` store them, from a one-step
        :func:`replay` for the files)."""
        if self.final_observations is None:
            return None
        following = np.append(self.observations[1:], self.observations[-1:], 0)
        last = np.append(self.episode[1:] != self.episode[:-1], True)
        finals = self.final_observations[self.episode]
        return np.where(last[:, None], finals, following).astype(np.float32)

    @property
    def num_intentions(self) -> int | None:
        if self.intentions is not None:
            return int(self.intentions.max()) + 1
        if self.expert_returns is not None:
            return len(self.expert_returns)
        return None


def _pairs_where(demos: Demonstrations, keep: np.ndarray) -> Demonstrations:
    """The labelled pairs where ``keep [N]`` is True, in order (whole episodes for the
    episode starts and the final observations to stay right); the expert returns unchanged."""
    finals = demos.final_observations
    return dataclasses.replace(
        demos,
        observations=demos.observations[keep],
        actions=demos.actions[keep],
        episode_starts=demos.episode_starts[keep],
        intentions=demos.intentions[keep],
        rewards=None if demos.rewards is None else demos.rewards[keep],
        final_observations=None if finals is None else finals[np.unique(demos.episode[keep])],
    )


def mean_episode_return(rewards: np.ndarray, episode_starts: np.ndarray) -> np.float32:
    """The mean over the demonstrations of their summed ``rewards [N]``, in float32, summed as
    :func:`generate` sums its expert returns (a file's returns read back are the same bits)."""
    bounds = [*np.flatnonzero(episode_starts), len(rewards)]
    rewards = np.asarray(rewards, np.float32)
    sums = np.array([rewards[a:b].sum() for a, b in itertools.pairwise(bounds)], np.float32)
    return sums.mean()


def first_intentions(demos: Demonstrations, k: int) -> Demonstrations:
    """The pairs of the first ``k`` intentions (labels required)."""
    if demos.intentions is None:
        return demos
    keep = demos.intentions < k
    returns = demos.expert_returns[:k] if demos.expert_returns is not None else None
    return dataclasses.replace(_pairs_where(demos, keep), expert_returns=returns)


def first_episodes(demos: Demonstrations, episodes: Sequence[int]) -> Demonstrations:
    """The pairs of the first ``episodes[i]`` demonstrations (episodes) of every intention i
    (labels required): a set in unequal shares made from a balanced one."""
    if demos.intentions is None:
        raise ValueError("keeping episodes per intention needs labelled demonstrations")
    episode = np.cumsum(demos.episode_starts) - 1
    keep = np.zeros(len(demos), bool)
    for intention, count in enumerate(episodes):
        own = np.unique(episode[demos.intentions == intention])
        if count > len(own):
            raise ValueError(f"intention {intention} has {len(own)} episodes, not {count}")
        keep |= np.isin(episode, own[:count])
    return _pairs_where(demos, keep)


def executed_actions(demos: Demonstrations, env: envs.Env) -> Demonstrations:
    """The demonstrations with their actions clipped to ``env``'s action range: the actions the
    env executed, which is what the discriminator and the posterior compare with the policy's
    (clipped) samples. A file may hold raw actions outside the range; they are clipped here."""
    actions = np.clip(demos.actions, env.action_low, env.action_high).astype(np.float32)
    return dataclasses.replace(demos, actions=actions)


Expert = Callable[[envs.State, jax.Array, jax.Array], jax.Array]


def generate(env: envs.Env, expert: Expert, episodes: int, key: jax.Array) -> Demonstrations:
    """Rolls ``expert(state, intention, key) -> action`` for ``episodes`` episodes of every
    intention of ``env`` and returns the labelled pairs (with the actions the env executed,
    i.e. clipped to its range), each expert's mean true return, each pair's own reward and
    each episode's final observation.

    Pairs after an episode terminated early are dropped. Deterministic for a given ``key``.
    """
    k = env.num_intentions
    limited = envs.EpisodeWrapper(env)
    intention = jnp.broadcast_to(jnp.arange(k)[:, None], (k, episodes))

    @jax.jit
    def roll(key):
        key_reset, key_steps = jax.random.split(key)
        states = jax.vmap(jax.vmap(limited.reset))(jax.random.split(key_reset, (k, episodes)))
        act = jax.vmap(jax.vmap(expert))
        step = jax.vmap(jax.vmap(limited.step))

        def body(carry, step_key):
            state, alive = carry
            action = limited.clip_action(
                act(state, intention, jax.random.split(step_key, (k, episodes)))
            )
            next_state = step(state, action)
            out = (state.obs, action, next_state.reward, alive, next_state.obs)
            return (next_state, alive * (1.0 - next_state.done)), out

        alive = jnp.ones((k, episodes))
        _, steps = jax.lax.scan(
            body, (states, alive), jax.random.split(key_steps, env.episode_length)
        )
        return steps

    # Episode-major order: intention, episode, time.
    obs, actions, rewards, alive, next_obs = (
        np.moveaxis(x, 0, 2)
        for x in jax.device_get(roll(key))  # [K, E, T, ...]
    )
    keep = alive.astype(bool)
    starts = np.zeros_like(keep)
    starts[..., 0] = True
    labels = np.broadcast_to(np.arange(k)[:, None, None], keep.shape)
    own_reward = np.take_along_axis(rewards, labels[..., None], -1)[..., 0]
    expert_returns = np.where(keep, own_reward, 0.0).sum(-1).mean(-1)
    last_step = keep.sum(-1, keepdims=True) - 1  # [K, E, 1]
    finals = np.take_along_axis(next_obs, last_step[..., None], 2)[:, :, 0]  # [K, E, obs_dim]
    return Demonstrations(
        observations=obs[keep].astype(np.float32),
        actions=actions[keep].astype(np.float32),
        episode_starts=starts[keep],
        intentions=labels[keep].astype(np.int32),
        expert_returns=np.asarray(expert_returns, np.float32),
        rewards=own_reward[keep].astype(np.float32),
        final_observations=finals.reshape(-1, finals.shape[-1]).astype(np.float32),
    )


@dataclasses.dataclass(frozen=True)
class Replay:
    """Every pair of a set of demonstrations stepped once from the state its observation stands
    for (:func:`replay`)."""

    next_observations: np.ndarray  # [N, obs_dim]
    rewards: np.ndarray  # [N, K] every intention's reward of the step
    done: np.ndarray  # [N] bool, the env ended the episode with the step


def replay(env: envs.Env, demos: Demonstrations) -> Replay:
    """Replays every demonstration pair by pair in the MJX env ``env`` (``MjxEnv.replay``: one
    step from each pair's observation with its action), the demonstrations padded to its
    episode length and vmapped."""
    length = env.episode_length
    bounds = [*np.flatnonzero(demos.episode_starts), len(demos)]
    if max(b - a for a, b in itertools.pairwise(bounds)) > length:
        raise ValueError(f"a demonstration is longer than {env.name}'s episodes ({length} steps)")
    # Each pair's place in the padded [E, T] grid; the padding repeats pair 0 and is dropped.
    rows = np.zeros((demos.episodes, length), int)
    for episode, (a, b) in enumerate(itertools.pairwise(bounds)):
        rows[episode, : b - a] = np.arange(a, b)
    steps = jnp.asarray(np.diff(bounds))
    pairs = jnp.asarray(demos.observations[rows]), jnp.asarray(demos.actions[rows])
    next_obs, rewards, done = jax.device_get(jax.jit(jax.vmap(env.replay))(*pairs, steps))
    pair = demos.episode, demos.step_in_episode
    return Replay(
        next_observations=next_obs[pair], rewards=rewards[pair], done=done[pair].astype(bool)
    )
