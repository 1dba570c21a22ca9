"""A replay of past policies' samples for the M-step (off by default: ``--set
discriminator_replay=R``).

During training the discriminator only tells the demonstrations from the *latest* policy, so
where earlier policies went (and where a fresh learner may go) its reward is whatever it last
was there. With a replay, every M-step's negatives are the iteration's own samples and as many
again drawn uniformly from the last R iterations' (the current one included), so the
discriminator keeps saying "fake" where the run's policies have been. One ring buffer serves
EM-GAIL, GAIL and Info/IntentionGAIL alike: it holds each sample under the intention whose
policy made it, as the M-step scores them. With AIRL's discriminator it holds each sample's
successor too (s' and whether the episode went on), not its log pi, which the M-step
recomputes under the current policy (:mod:`emgail_jax.method.airl`).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from flax import struct

from emgail_jax.method.batches import NormalizedBatch


@struct.dataclass
class Replay:
    """The last R iterations' policy samples, raw (normalised when drawn, with the statistics
    of the moment), ring-ordered: iteration n went to slot n mod R."""

    obs: jax.Array  # [R, K, M, D] raw observations
    executed: jax.Array  # [R, K, M, A] executed (clipped) actions
    pushed: jax.Array  # [] int32, iterations pushed so far
    key: jax.Array  # the draws' own key: no other key of the run changes with a replay
    # With absorbing states only (None otherwise): 1.0 where a sample's transition terminated
    # its episode, so that a drawn termination brings its absorbing negative along.
    terminal: jax.Array | None = None  # [R, K, M]
    # With AIRL's discriminator only (None otherwise): each sample's successor, its next
    # observation raw (:func:`~emgail_jax.method.airl.successor`).
    successor: jax.Array | None = None  # [R, K, M, D + 1]

    @classmethod
    def create(
        cls,
        size: int,
        k: int,
        m: int,
        obs_size: int,
        action_size: int,
        key,
        absorbing=False,
        successors=False,
    ) -> Replay:
        return cls(
            obs=jnp.zeros((size, k, m, obs_size)),
            executed=jnp.zeros((size, k, m, action_size)),
            pushed=jnp.zeros((), jnp.int32),
            key=key,
            terminal=jnp.zeros((size, k, m)) if absorbing else None,
            successor=jnp.zeros((size, k, m, obs_size + 1)) if successors else None,
        )

    def push(self, obs: jax.Array, executed: jax.Array, terminal=None, successor=None) -> Replay:
        """With one iteration's samples ``obs [K, M, D]`` (raw), ``executed [K, M, A]`` (and,
        with absorbing states, ``terminal [K, M]``; with AIRL's discriminator, ``successor [K,
        M, D + 1]``, raw) in the oldest slot."""
        slot = self.pushed % self.obs.shape[0]
        into = lambda ring, x: None if x is None else ring.at[slot].set(x)
        return self.replace(
            obs=self.obs.at[slot].set(obs),
            executed=self.executed.at[slot].set(executed),
            pushed=self.pushed + 1,
            terminal=into(self.terminal, terminal),
            successor=into(self.successor, successor),
        )

    def draw(self, count: int) -> tuple:
        """``(replay, obs [K, count, D], executed [K, count, A], terminal [K, count] or None,
        successor [K, count, D + 1] or None)``: per intention, ``count`` samples drawn
        uniformly (with replacement) from the slots filled so far."""
        size, k, m = self.obs.shape[:3]
        key, key_draw = jax.random.split(self.key)
        filled = jnp.minimum(self.pushed, size)
        index = jax.random.randint(key_draw, (k, count), 0, filled * m)  # [K, count]
        per_intention = lambda x: jnp.swapaxes(x, 0, 1).reshape(k, size * m, -1)
        take = lambda x: jnp.take_along_axis(per_intention(x), index[..., None], axis=1)
        terminal = None if self.terminal is None else take(self.terminal)[..., 0]
        successor = None if self.successor is None else take(self.successor)
        return self.replace(key=key), take(self.obs), take(self.executed), terminal, successor


def with_replay(
    replay: Replay,
    seen: NormalizedBatch,
    raw_obs: jax.Array,
    normalize: Callable,
    raw_successor: jax.Array | None = None,
) -> tuple[Replay, NormalizedBatch]:
    """The replay with ``seen``'s samples (raw ``raw_obs [K, M, D]``; with AIRL's
    discriminator their successors ``raw_successor [K, M, D + 1]``, raw) pushed, and ``seen``
    with as many samples again drawn from it appended to its own (``[K, 2M, ...]``,
    normalised by ``normalize``; their termination flags and successors too, where kept): the
    M-step's negatives (AIRL's log pi: the caller recomputes it on them)."""
    replay = replay.push(raw_obs, seen.executed, seen.terminal, raw_successor)
    replay, obs, executed, terminal, successor = replay.draw(raw_obs.shape[1])
    if successor is not None:
        successor = jnp.concatenate([normalize(successor[..., :-1]), successor[..., -1:]], -1)
    return replay, seen.with_more_samples(normalize(obs), executed, terminal, successor)
