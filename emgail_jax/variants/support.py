"""Negatives around the run's samples for the M-step (off by default: ``--set
discriminator_support_noise=S``).

The discriminator only ever sees the demonstrations and the policies' samples, so away from
both its logit, and with it the learned reward, is whatever the network extrapolates: nearly
flat on the driver, where a fresh agent that strays there never finds its way back
(see docs/defaults.md, ``discriminator_support_noise``). With a scale S, every M-step's negatives
also hold a copy of each of its samples moved by Gaussian noise of standard deviation S (in
the normalised observation's units, and the action's own), so that the discriminator says
"fake" around where the run has been and the reward falls with the distance to the data.
It plugs into the update as the M-step's further negatives (:class:`SupportNoise`).
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp

from emgail_jax.method.batches import NormalizedBatch
from emgail_jax.method.hooks import Negatives, Sampling
from emgail_jax.variants.extras import Extras, extras_of

# Folded into the iteration's key for the noise's own key: no other key of the run changes.
KEY_STREAM = 0x5E6


def with_support_negatives(negatives: NormalizedBatch, key: jax.Array, scale: float):
    """``negatives`` (``[K, M, ...]``) with a noisy copy of each of its samples appended
    (``[K, 2M, ...]``): observation and action each plus N(0, ``scale``^2) noise. A copy's
    transition never terminates: it brings no absorbing negative along."""
    extras = extras_of(negatives)
    if extras.successor is not None:
        raise ValueError("support negatives are built for GAIL's discriminator, not AIRL's")
    key_obs, key_action = jax.random.split(key)
    moved = lambda x, k: x + scale * jax.random.normal(k, x.shape)
    obs, executed = moved(negatives.obs, key_obs), moved(negatives.executed, key_action)
    terminal = None if extras.terminal is None else jnp.zeros_like(extras.terminal)
    return negatives.with_more_samples(obs, executed, Extras(terminal=terminal))


@dataclass(frozen=True)
class SupportNoise(Negatives):
    """The M-step's negatives with a noisy copy of each, of standard deviation ``scale``."""

    scale: float

    def __call__(self, carry, seen: NormalizedBatch, sampling: Sampling):
        key = jax.random.fold_in(sampling.key, KEY_STREAM)
        return carry, with_support_negatives(seen, key, self.scale)
