"""Where research variants plug into the update, and the paper's method as their default.

The update (:mod:`emgail_jax.method.training`) is Algorithm 1 of the paper. A variant changes it
at one of five named places, each a field of :class:`Hooks`; the defaults here are the paper's,
and :mod:`emgail_jax.variants` builds the hooks a run's config asks for
(``variants.hooks_for(config)``). The method never imports the variants.

- ``form``: what the discriminator is and what its logit reads beside the observation;
- ``negatives``: further negatives for the M-step beside the rollout's samples, with a carry
  of their own in the train state;
- ``loss``: what a variant adds to the discriminator loss (a :class:`LossHook`, see
  :mod:`emgail_jax.method.discriminator`);
- ``termination``: what an episode's end is worth to the B-step under the learned reward;
- ``evidence``: a weight of each demonstration's evidence in a trajectory E-step.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import jax
from flax import linen as nn

import envs
from emgail_jax.method.algorithms import Algorithm
from emgail_jax.method.batches import DemonstrationPairs, NormalizedBatch
from emgail_jax.method.config import MethodConfig
from emgail_jax.method.discriminator import LossHook, Read
from emgail_jax.method.networks import Discriminator
from emgail_jax.method.rollout import Transitions


@dataclass(frozen=True)
class Sampling:
    """What a hook may read of the iteration besides the normalised batch: the rollout
    ``transitions [T, K, B, ...]`` (raw), its ``env``, the run's ``demos``, the observation
    ``normalize``r of the batch, the ``policy`` (``(apply, params)``) that made the rollout,
    the run's ``algorithm``, and the iteration's ``key`` (the train state's, before its
    split)."""

    transitions: Transitions
    demos: DemonstrationPairs
    env: envs.Env
    normalize: Callable[[jax.Array], jax.Array]
    policy: tuple[Callable, Any]
    algorithm: Algorithm
    key: jax.Array


class Form:
    """The paper's discriminator: the logit f(s, a, i) of D = sigmoid(f), reading each pair's
    executed action."""

    def network(self, config: MethodConfig) -> nn.Module:
        shape = config.networks
        return Discriminator(shape.hidden, shape.intention_input.heads)

    def init_input(self, obs: jax.Array, action: jax.Array) -> jax.Array:
        """What f reads beside ``obs [1, D]`` when the network is initialised."""
        return action

    def observed(self, batch: NormalizedBatch, sampling: Sampling) -> NormalizedBatch:
        """``batch`` with what the form reads of the rollout and the demonstrations attached
        (``batch.extra``); the paper's reads nothing more."""
        return batch

    def read(self, batch: NormalizedBatch) -> Read:
        return Read.of(batch)


class Negatives:
    """Further negatives for the M-step (the paper's: none; this base adds none)."""

    def init(self, config: MethodConfig, env: envs.Env, key: jax.Array) -> Any:
        """The carry a run starts with (in ``TrainState.negatives``), from the seed's key."""
        return None

    def __call__(self, carry, seen: NormalizedBatch, sampling: Sampling):
        """``(carry, negatives)``: the M-step's batch, ``seen``'s samples and any more."""
        return carry, seen


class Termination:
    """What follows an episode's end under the learned reward (the paper's: nothing)."""

    def reward(self, apply: Callable, params, algorithm: Algorithm, env: envs.Env):
        """``([K] or None, metrics)``: the B-step's reward of every step after a termination
        under each intention (None: an episode's end is worth 0)."""
        return None, {}


# (batch, read, gamma [N, K], algorithm) -> LossHook: what a variant changes in the M-step's
# loss (None: nothing)
LossOf = Callable[[NormalizedBatch, Read, jax.Array, Algorithm], LossHook]
# (iteration [] int, demos) -> [E] the weight of each demonstration's evidence (None: 1)
Evidence = Callable[[jax.Array | None, DemonstrationPairs], jax.Array | None]


# The paper's hooks, which change nothing.
PAPER_FORM, NO_NEGATIVES, NO_TERMINATION = Form(), Negatives(), Termination()


@dataclass(frozen=True)
class Hooks:
    """The five places a variant changes the update (module docstring); the defaults are the
    paper's method."""

    form: Form = PAPER_FORM
    negatives: Negatives = NO_NEGATIVES
    loss: LossOf | None = None
    termination: Termination = NO_TERMINATION
    evidence: Evidence | None = None


PAPER = Hooks()
