"""A replay of past policies' samples for the M-step (off by default: ``--set
discriminator_replay=R``).

During training the discriminator only tells the demonstrations from the *latest* policy, so
where earlier policies went (and where a fresh learner may go) its reward is whatever it last
was there. With a replay, every M-step's negatives are the iteration's own samples and as many
again drawn uniformly from the last R iterations' (the current one included), so the
discriminator keeps saying "fake" where the run's policies have been. One ring buffer serves
EM-GAIL, GAIL and Info/IntentionGAIL alike: it holds each sample under the intention whose
policy made it, as the M-step scores them.
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

    @classmethod
    def create(cls, size: int, k: int, m: int, obs_size: int, action_size: int, key) -> Replay:
        return cls(
            obs=jnp.zeros((size, k, m, obs_size)),
            executed=jnp.zeros((size, k, m, action_size)),
            pushed=jnp.zeros((), jnp.int32),
            key=key,
        )

    def push(self, obs: jax.Array, executed: jax.Array) -> Replay:
        """With one iteration's samples ``obs [K, M, D]`` (raw), ``executed [K, M, A]`` in the
        oldest slot."""
        slot = self.pushed % self.obs.shape[0]
        return self.replace(
            obs=self.obs.at[slot].set(obs),
            executed=self.executed.at[slot].set(executed),
            pushed=self.pushed + 1,
        )

    def draw(self, count: int) -> tuple[Replay, jax.Array, jax.Array]:
        """``(replay, obs [K, count, D], executed [K, count, A])``: per intention, ``count``
        samples drawn uniformly (with replacement) from the slots filled so far."""
        size, k, m = self.obs.shape[:3]
        key, key_draw = jax.random.split(self.key)
        filled = jnp.minimum(self.pushed, size)
        index = jax.random.randint(key_draw, (k, count), 0, filled * m)  # [K, count]
        per_intention = lambda x: jnp.swapaxes(x, 0, 1).reshape(k, size * m, -1)
        take = lambda x: jnp.take_along_axis(per_intention(x), index[..., None], axis=1)
        return self.replace(key=key), take(self.obs), take(self.executed)


def with_replay(
    replay: Replay, seen: NormalizedBatch, raw_obs: jax.Array, normalize: Callable
) -> tuple[Replay, NormalizedBatch]:
    """The replay with ``seen``'s samples (raw ``raw_obs [K, M, D]``) pushed, and ``seen`` with
    as many samples again drawn from it appended to its own (``[K, 2M, ...]``, normalised by
    ``normalize``): the M-step's negatives."""
    replay = replay.push(raw_obs, seen.executed)
    replay, obs, executed = replay.draw(raw_obs.shape[1])
    both = lambda own, drawn: jnp.concatenate([own, drawn], axis=1)
    return replay, seen.replace(
        obs=both(seen.obs, normalize(obs)), executed=both(seen.executed, executed)
    )
