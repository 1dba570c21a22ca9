"""The data the steps of one update hand each other, with their shapes.

K intentions, B envs per intention, T steps per rollout, M = T * B samples per intention,
N demonstration pairs, D observation and A action dimensions.
"""

from __future__ import annotations

from typing import Any

import chex
import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

import envs
from emgail_jax.method import normalizer as obs_norm
from emgail_jax.method.demonstrations import Demonstrations
from emgail_jax.method.rollout import Transitions


@struct.dataclass
class DemonstrationPairs:
    """The demonstrations, plus the references ERD is normalised with."""

    observations: jax.Array  # [N, D] raw
    actions: jax.Array  # [N, A] executed (clipped to the env's range)
    episode: jax.Array  # [N] index of each pair's demonstration (episode)
    labels: jax.Array  # [N] hidden intention labels, -1 when unknown
    expert_returns: jax.Array  # [K true] NaN when unknown
    random_returns: jax.Array  # [K true]
    # The raw observation each pair reached (the next pair's, at a demonstration's end its
    # final observation); None where the demonstrations store no final observations.
    next_observations: jax.Array | None = None  # [N, D]
    episodes: int = struct.field(pytree_node=False, default=1)  # demonstrations (episodes)
    has_labels: bool = struct.field(pytree_node=False, default=False)

    @property
    def true_intentions(self) -> int:
        """K of the demonstrations: at most the learned K (``--intentions auto`` learns more)."""
        return self.random_returns.shape[0]

    @classmethod
    def create(
        cls, demos: Demonstrations, random_returns: np.ndarray, k: int
    ) -> DemonstrationPairs:
        n = len(demos)
        labels = demos.intentions if demos.intentions is not None else np.full(n, -1)
        returns = demos.expert_returns
        returns = np.full(k, np.nan) if returns is None else returns
        episode = demos.episode.astype(np.int32)
        return cls(
            observations=np.asarray(demos.observations, np.float32),
            actions=np.asarray(demos.actions, np.float32),
            episode=episode,
            labels=np.asarray(labels, np.int32),
            expert_returns=np.asarray(returns, np.float32),
            random_returns=np.asarray(random_returns, np.float32),
            next_observations=demos.next_observations(),
            episodes=int(episode.max()) + 1,
            has_labels=demos.intentions is not None,
        )

    def terminations(self, episode_length: int) -> jax.Array:
        """``[N]`` 1.0 on the last pair of every demonstration shorter than ``episode_length``:
        one the env ended. A demonstration records no termination flag; the shipped files and
        the Minari datasets written here end early only where the env did (``experts``'
        replay check, ``minari_datasets.write``)."""
        last = jnp.append(self.episode[1:] != self.episode[:-1], True)
        length = pairs_per_demonstration(self.episode, self.episodes)
        return jnp.where(last & (length[self.episode] < episode_length), 1.0, 0.0)


def pairs_per_demonstration(episode: jax.Array, episodes: int) -> jax.Array:
    """``[E]`` float: how many pairs each demonstration has (``episode [N]``: the index of each
    pair's demonstration, in ``[0, episodes)``)."""
    return jax.ops.segment_sum(jnp.ones(episode.shape), episode, num_segments=episodes)


@struct.dataclass
class LearningBatch:
    """A rollout as the learning steps read it: the transitions, and the state after them (for
    the value baseline's bootstrap)."""

    obs: jax.Array  # [T, K, B, D] raw
    action: jax.Array  # [T, K, B, A] raw samples
    time: jax.Array  # [T, K, B]
    done: jax.Array  # [T, K, B]
    last_obs: jax.Array  # [K, B, D] raw
    last_time: jax.Array  # [K, B]

    @classmethod
    def of(cls, batch: Transitions, end: envs.State, episode_length: int) -> LearningBatch:
        return cls(
            obs=batch.obs,
            action=batch.action,
            time=batch.time,
            done=batch.done,
            last_obs=end.obs,
            last_time=end.info["steps"] / episode_length,
        )


@struct.dataclass
class NormalizedBatch:
    """A rollout and the demonstrations as the posterior and the discriminator see them:
    observations normalised with statistics that include the rollout, and the actions the env
    executed (clipped to its range) on both sides."""

    normalizer: obs_norm.RunningStats  # including the rollout
    obs: jax.Array  # [K, M, D] the samples, grouped by intention
    executed: jax.Array  # [K, M, A] their actions as executed (clipped)
    expert_obs: jax.Array  # [N, D]
    expert_actions: jax.Array  # [N, A] executed
    # What the variants attach (:mod:`emgail_jax.variants`), a pytree of theirs with
    # ``appended(more)`` and ``check(batch)``; None in the paper's method.
    extra: Any = None

    def own_intention(self) -> jax.Array:
        """``[K, M]``: the intention whose policy made each sample (row k is k)."""
        k, m = self.obs.shape[:2]
        return jnp.broadcast_to(jnp.arange(k)[:, None], (k, m))

    def check(self) -> NormalizedBatch:
        """Asserts the documented shapes (at trace time); returns ``self``."""
        chex.assert_rank(
            (self.obs, self.executed, self.expert_obs, self.expert_actions), (3, 3, 2, 2)
        )
        chex.assert_equal_shape_prefix((self.obs, self.executed), 2)
        chex.assert_equal_shape_prefix((self.expert_obs, self.expert_actions), 1)
        chex.assert_equal_shape_suffix((self.obs, self.expert_obs), 1)
        chex.assert_equal_shape_suffix((self.executed, self.expert_actions), 1)
        if self.extra is not None:
            self.extra.check(self)
        return self

    def with_more_samples(self, obs: jax.Array, executed: jax.Array, extra=None) -> NormalizedBatch:
        """This batch with further samples ``obs [K, m, D]``, ``executed [K, m, A]`` after its
        own under each intention (``[K, M + m, ...]``), and what the variants attach of them
        (``extra``, where the batch has theirs): the M-step's further negatives."""
        both = lambda own, more: jnp.concatenate([own, more], axis=1)
        return self.replace(
            obs=both(self.obs, obs),
            executed=both(self.executed, executed),
            extra=None if self.extra is None else self.extra.appended(extra),
        )
