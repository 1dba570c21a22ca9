"""What the variants attach to a :class:`~emgail_jax.method.batches.NormalizedBatch` (its
``extra``): termination flags (absorbing states) and, for AIRL's discriminator, successors and
log-densities. K intentions, M samples per intention, N demonstration pairs, D observation
dimensions, C discriminator conditions."""

from __future__ import annotations

import chex
import jax
import jax.numpy as jnp
from flax import struct

from emgail_jax.method.batches import NormalizedBatch


@struct.dataclass
class Extras:
    # With absorbing states only (None otherwise): 1.0 where a sample's transition, or a
    # demonstration's last pair, ended its episode before the time limit.
    terminal: jax.Array | None = None  # [K, M]
    expert_terminal: jax.Array | None = None  # [N]
    # With AIRL's discriminator only (None otherwise, :mod:`emgail_jax.variants.airl`): what f
    # reads after each pair (its successor), and log pi of the executed actions under the
    # current policy, a sample's under its own intention, an expert pair's under every
    # discriminator condition.
    successor: jax.Array | None = None  # [K, M, D + 1]
    expert_successor: jax.Array | None = None  # [N, D + 1]
    log_policy: jax.Array | None = None  # [K, M]
    expert_log_policy: jax.Array | None = None  # [N, C]

    def appended(self, more: Extras | None) -> Extras:
        """These extras with ``more``'s per-sample ones after them, where these keep them
        (``[K, M + m, ...]``). The log-densities are dropped: the form recomputes them on the
        grown batch."""
        more = more or Extras()
        both = lambda own, extra: None if own is None else jnp.concatenate([own, extra], axis=1)
        return self.replace(
            terminal=both(self.terminal, more.terminal),
            successor=both(self.successor, more.successor),
            log_policy=None,
        )

    def check(self, batch: NormalizedBatch) -> None:
        """Asserts the documented shapes against ``batch``'s (at trace time)."""
        if self.terminal is not None:
            chex.assert_shape(self.terminal, batch.obs.shape[:2])
            chex.assert_shape(self.expert_terminal, batch.expert_obs.shape[:1])
        if self.successor is not None:
            follows = batch.obs.shape[-1] + 1
            chex.assert_shape(self.successor, (*batch.obs.shape[:2], follows))
            chex.assert_shape(self.expert_successor, (batch.expert_obs.shape[0], follows))


def extras_of(batch: NormalizedBatch) -> Extras:
    """``batch``'s extras (none attached: all None)."""
    return Extras() if batch.extra is None else batch.extra


def attached(batch: NormalizedBatch, **fields) -> NormalizedBatch:
    """``batch`` with ``fields`` of :class:`Extras` attached to what it holds."""
    return batch.replace(extra=extras_of(batch).replace(**fields))


def more_samples(batch: NormalizedBatch, obs, executed, terminal=None) -> NormalizedBatch:
    """``batch`` with further samples ``obs [K, m, D]``, ``executed [K, m, A]`` and their
    termination flags ``terminal [K, m]`` (where ``batch`` keeps them) after its own."""
    return batch.with_more_samples(obs, executed, Extras(terminal=terminal))
