"""Running observation normaliser (mean/variance over every observation seen, clipped output)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct


@struct.dataclass
class RunningStats:
    """Mean and variance of all observations seen so far, per dimension ``[D]``."""

    mean: jax.Array
    var: jax.Array
    count: jax.Array  # [] number of observations seen

    @classmethod
    def create(cls, dim: int) -> RunningStats:
        return cls(mean=jnp.zeros(dim), var=jnp.ones(dim), count=jnp.zeros(()))


def update(stats: RunningStats, batch: jax.Array) -> RunningStats:
    """Merges a batch ``[..., D]`` into the statistics (Chan et al.'s parallel update)."""
    batch = batch.reshape(-1, stats.mean.shape[-1])
    n = batch.shape[0]
    batch_mean = batch.mean(0)
    batch_var = batch.var(0)
    total = stats.count + n
    delta = batch_mean - stats.mean
    mean = stats.mean + delta * n / total
    # Sum of squared deviations of both parts plus the between-part correction.
    m2 = stats.var * stats.count + batch_var * n + delta**2 * stats.count * n / total
    return RunningStats(mean=mean, var=m2 / total, count=total)


def normalize(stats: RunningStats, x: jax.Array, clip: float = 5.0) -> jax.Array:
    """``(x - mean) / std`` clipped to ``[-clip, clip]``; works on any leading batch shape."""
    return jnp.clip((x - stats.mean) / jnp.sqrt(stats.var + 1e-8), -clip, clip)
