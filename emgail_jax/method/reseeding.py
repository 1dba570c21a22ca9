"""Re-seeding an emptied intention: k-means' answer to an empty cluster, in the E-step.

The E-step can give every demonstration to one intention early; the other intention's
discriminator then has nothing to learn, its policy drifts, and nothing brings a
demonstration back (docs/defaults.md, `reseed`). k-means re-seeds an empty cluster from the
points the others explain worst. Here: an intention whose share of the demonstrations (the
sum of their responsibilities over the number of demonstrations) stays below half a
demonstration's share for ``patience`` E-steps takes over the worse-explained half of the
demonstrations of the intention holding most, and holds them for ``window`` E-steps (the
M-step's gamma and the mixture weights are the re-seeded ones; the posterior's own
responsibilities, which the metrics score, are not touched). Each intention is re-seeded at
most ``attempts`` times: one that empties again after that stays empty (``--intentions auto``
retires it).

"Explained worst" is the discriminator's word: the mean logit of a demonstration's pairs
under the condition of the intention holding it. The discriminator learns those pairs against
that intention's policy samples, so it scores high the demonstrations the policy does not
produce (Info/IntentionGAIL's single D(s, a): those no policy produces).

Nothing here changes a run in which no intention stays empty for ``patience`` E-steps: the
responsibilities pass through unchanged, bit for bit.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from flax import struct

from emgail_jax.method.batches import pairs_per_demonstration
from emgail_jax.method.choosing import kept_share


@struct.dataclass
class Reseeding:
    """The re-seeding rule's memory, per seed (part of the train state).

    Attributes:
      empty_for: ``[]`` consecutive E-steps in which an intention that may still be re-seeded
        held less than the threshold (not always the same one: a collapsed set of
        demonstrations can move whole from one intention to another).
      reseedings: ``[K]`` re-seedings of each intention so far.
      target: ``[]`` the intention being re-seeded, -1 when none.
      left: ``[]`` E-steps the taken demonstrations are still held for ``target``.
      taken: ``[E]`` the demonstrations handed to ``target``.
      donor: ``[]`` the intention they were taken from.
      split: ``[E]`` the demonstrations the donor held when they were taken (``taken`` among
        them): what Info/IntentionGAIL's posterior is taught, the taken ones as ``target``'s
        and the others as the donor's, so that it does not swing the donor's whole set over.
    """

    empty_for: jax.Array
    reseedings: jax.Array
    target: jax.Array
    left: jax.Array
    taken: jax.Array
    donor: jax.Array
    split: jax.Array

    @classmethod
    def create(cls, intentions: int, episodes: int) -> Reseeding:
        return cls(
            empty_for=jnp.int32(0),
            reseedings=jnp.zeros(intentions, jnp.int32),
            target=jnp.int32(-1),
            left=jnp.int32(0),
            taken=jnp.zeros(episodes, bool),
            donor=jnp.int32(-1),
            split=jnp.zeros(episodes, bool),
        )

    def taught_intentions(self) -> jax.Array:
        """``[E]`` the intention each demonstration of :attr:`split` is taught as."""
        return jnp.where(self.taken, jnp.maximum(self.target, 0), jnp.maximum(self.donor, 0))


@struct.dataclass
class ReseedingRule:
    """When to re-seed: after ``patience`` E-steps below the threshold; for ``window`` E-steps;
    at most ``attempts`` times per intention."""

    patience: int = struct.field(pytree_node=False)
    window: int = struct.field(pytree_node=False)
    attempts: int = struct.field(pytree_node=False)


def demonstration_responsibilities(
    gamma: jax.Array, episode: jax.Array, episodes: int
) -> jax.Array:
    """``[E, K]`` each demonstration's mean responsibility over its pairs (``gamma [N, K]``,
    ``episode [N]``); in the trajectory E-step, the one its pairs all share."""
    total = jax.ops.segment_sum(gamma, episode, num_segments=episodes)
    pairs = pairs_per_demonstration(episode, episodes)
    return total / jnp.maximum(pairs, 1.0)[:, None]


def demonstration_scores(pair_scores: jax.Array, episode: jax.Array, episodes: int) -> jax.Array:
    """``[E]`` the mean of ``pair_scores [N]`` over each demonstration's pairs."""
    return demonstration_responsibilities(pair_scores[:, None], episode, episodes)[:, 0]


def worse_half(scores: jax.Array, holder: jax.Array, donor: jax.Array) -> jax.Array:
    """``[E]`` bool: the half (rounded up) of the demonstrations ``holder [E] == donor`` with
    the highest ``scores [E]`` (the worst explained)."""
    mine = holder == donor
    ranked = jnp.where(mine, scores, -jnp.inf)
    rank = jnp.argsort(jnp.argsort(-ranked))  # 0: the worst explained
    return mine & (rank < (mine.sum() + 1) // 2)


def reseeding_step(
    memory: Reseeding,
    per_demonstration: jax.Array,
    scores: Callable[[jax.Array], jax.Array],
    rule: ReseedingRule,
) -> Reseeding:
    """The rule's memory after one E-step whose responsibilities per demonstration are
    ``per_demonstration [E, K]``. ``scores(holder [E]) -> [E]`` says how badly each
    demonstration is explained by the intention ``holder`` gives it (called only when a
    re-seeding starts, under ``lax.cond``)."""
    episodes = per_demonstration.shape[0]
    share = per_demonstration.mean(0)  # [K]
    empty = (share < kept_share(episodes)) & (memory.reseedings < rule.attempts)
    empty_for = jnp.where(jnp.any(empty), memory.empty_for + 1, 0)
    start = (memory.left == 0) & (empty_for >= rule.patience)

    def started() -> Reseeding:
        target = jnp.argmin(jnp.where(empty, share, jnp.inf)).astype(jnp.int32)
        holder = jnp.argmax(per_demonstration, -1)
        donor = jnp.argmax(share).astype(jnp.int32)
        return Reseeding(
            empty_for=jnp.int32(0),
            reseedings=memory.reseedings.at[target].add(1),
            target=target,
            left=jnp.int32(rule.window),
            taken=worse_half(scores(holder), holder, donor),
            donor=donor,
            split=holder == donor,
        )

    def going_on() -> Reseeding:
        return memory.replace(empty_for=empty_for)

    return jax.lax.cond(start, started, going_on)


def held_responsibilities(gamma: jax.Array, memory: Reseeding, episode: jax.Array) -> jax.Array:
    """``gamma [N, K]`` with the pairs of the demonstrations a re-seeding holds given wholly to
    its intention; unchanged (bit for bit) when none is held."""
    holding = (memory.left > 0) & memory.taken[episode]  # [N]
    one_hot = jax.nn.one_hot(memory.target, gamma.shape[-1], dtype=gamma.dtype)
    return jnp.where(holding[:, None], one_hot, gamma)


def count_down(memory: Reseeding) -> Reseeding:
    """One E-step of the window spent; the re-seeding ends when none is left."""
    left = jnp.maximum(memory.left - 1, 0)
    return memory.replace(left=left, target=jnp.where(left > 0, memory.target, -1))
