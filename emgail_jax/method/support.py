"""Negatives around the run's samples for the M-step (off by default: ``--set
discriminator_support_noise=S``).

The discriminator only ever sees the demonstrations and the policies' samples, so away from
both its logit, and with it the learned reward, is whatever the network extrapolates: nearly
flat on the driver, where a fresh agent that strays there never finds its way back
(docs/rewards-that-reoptimise.md, experiment 18). With a scale S, every M-step's negatives
also hold a copy of each of its samples moved by Gaussian noise of standard deviation S (in
the normalised observation's units, and the action's own), so that the discriminator says
"fake" around where the run has been and the reward falls with the distance to the data.

Every real input lies in a box: the normalised observation is clipped to ±``obs_clip`` and the
action is the executed one, clipped to the env's range. A fresh agent that spins a joint far
beyond the data sits on a face of that box, where unclipped copies never land. With
``discriminator_support_in_box`` the copies are clipped into the box too, so that the noise
that would leave it prices its faces instead.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from emgail_jax.method.batches import NormalizedBatch

# Folded into the iteration's key for the noise's own key: no other key of the run changes.
KEY_STREAM = 0x5E6


class InputBox(NamedTuple):
    """Where the discriminator's real inputs lie: normalised observations in ±``obs_clip``,
    executed actions in [``action_low``, ``action_high``]."""

    obs_clip: float
    action_low: float
    action_high: float


def with_support_negatives(
    negatives: NormalizedBatch, key: jax.Array, scale: float, box: InputBox | None = None
):
    """``negatives`` (``[K, M, ...]``) with a noisy copy of each of its samples appended
    (``[K, 2M, ...]``): observation and action each plus N(0, ``scale``^2) noise, clipped into
    ``box`` if given. A copy's transition never terminates: it brings no absorbing negative
    along."""
    if negatives.successor is not None:
        raise ValueError("support negatives are built for GAIL's discriminator, not AIRL's")
    key_obs, key_action = jax.random.split(key)
    moved = lambda x, k: x + scale * jax.random.normal(k, x.shape)
    obs, executed = moved(negatives.obs, key_obs), moved(negatives.executed, key_action)
    if box is not None:
        obs = jnp.clip(obs, -box.obs_clip, box.obs_clip)
        executed = jnp.clip(executed, box.action_low, box.action_high)
    terminal = None if negatives.terminal is None else jnp.zeros_like(negatives.terminal)
    return negatives.with_more_samples(obs, executed, terminal)
