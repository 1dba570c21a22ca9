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
recomputes under the current policy (:mod:`emgail_jax.variants.airl`). It plugs into the
update as the M-step's further negatives (:class:`Replayed`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import jax
import jax.numpy as jnp
from flax import struct

from emgail_jax.method.batches import NormalizedBatch
from emgail_jax.method.config import MethodConfig
from emgail_jax.method.hooks import Negatives, Sampling
from emgail_jax.method.rollout import intention_major
from emgail_jax.variants.airl import successors
from emgail_jax.variants.extras import Extras, extras_of


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
    # observation raw (:func:`~emgail_jax.variants.airl.successor`).
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
        *,
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
    replay = replay.push(raw_obs, seen.executed, extras_of(seen).terminal, raw_successor)
    replay, obs, executed, terminal, successor = replay.draw(raw_obs.shape[1])
    if successor is not None:
        successor = jnp.concatenate([normalize(successor[..., :-1]), successor[..., -1:]], -1)
    more = Extras(terminal=terminal, successor=successor)
    return replay, seen.with_more_samples(normalize(obs), executed, more)


@dataclass(frozen=True)
class Replayed(Negatives):
    """The M-step's negatives with as many samples again drawn from a replay of the last
    ``size`` iterations' (module docstring). ``reread``: what the form recomputes on the
    grown batch (AIRL's log pi; None: nothing)."""

    size: int
    reread: Callable[[NormalizedBatch, Sampling], NormalizedBatch] | None = None

    def init(self, config: MethodConfig, env, key: jax.Array) -> Replay:
        """An empty replay, its key folded from the seed's ``key`` so that no other key of
        the run changes."""
        rollout = config.rollout
        samples = rollout.num_envs * rollout.rollout_length  # per intention and iteration
        extras = (config.reward.absorbing_state, config.m_step.form.airl)
        return Replay.create(
            self.size,
            env.num_intentions,
            samples,
            env.observation_size,
            env.action_size,
            jax.random.fold_in(key, 1),
            absorbing=extras[0],
            successors=extras[1],
        )

    def __call__(self, carry: Replay, seen: NormalizedBatch, sampling: Sampling):
        raw = intention_major(sampling.transitions.obs)
        raw_successors = None
        if extras_of(seen).successor is not None:
            raw_successors = successors(sampling.transitions, sampling.env)
        replay, negatives = with_replay(carry, seen, raw, sampling.normalize, raw_successors)
        if self.reread is not None:
            negatives = self.reread(negatives, sampling)
        return replay, negatives
