"""Tempering the trajectory E-step's evidence early (``--set trajectory_temper_iterations=N``;
0, untempered, by default).

A trajectory E-step multiplies the posterior over a demonstration's pairs: early on, a lean
of the untrained posterior then grows into certainty and can send every demonstration to one
intention. Tempered, each demonstration's summed log-posterior is weighed by beta, as soft as
one pair's at first and rising to 1 at iteration N (see docs/defaults.md,
``trajectory_temper_iterations``). It plugs into the update as the evidence hook
(:func:`evidence_of`).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp

from emgail_jax.method.batches import DemonstrationPairs, pairs_per_demonstration
from emgail_jax.method.config import EStepConfig


def evidence_temper(iteration: jax.Array, ramp_iterations: int, pairs: jax.Array) -> jax.Array:
    """``[E]`` beta_e, the weight of demonstration e's summed log-posterior in the tempered
    trajectory E-step (``trajectory_temper_iterations``): ``1 / L_e`` at iteration 0, where
    ``L_e`` is its number of pairs (the mean of its pairs' log-posteriors: as soft as one
    pair), rising linearly to 1 at iteration ``ramp_iterations`` and 1 from there on.

    Args:
      iteration: ``[]`` int, the updates done before this E-step (``TrainState.iteration``:
        0 in the first update); a Python int works too.
      ramp_iterations: N >= 1, the iteration from which beta is 1 (a Python int).
      pairs: ``[E]`` float, each demonstration's number of pairs ``L_e`` (>= 1).
    """
    progress = jnp.clip(iteration / ramp_iterations, 0.0, 1.0)
    # Written as 1 - (1 - 1/L)(1 - progress), not 1/L + (1 - 1/L) progress: beta is then
    # exactly 1 from iteration N on, and the E-step today's to the bit.
    return 1.0 - (1.0 - 1.0 / pairs) * (1.0 - progress)


def tempered_evidence(
    config: EStepConfig, iteration: jax.Array, demos: DemonstrationPairs
) -> jax.Array | None:
    """``[E]`` beta of each demonstration in the E-step of ``iteration`` (``[]`` int, the
    updates done before it) under ``config.trajectory_temper_iterations``
    (:func:`evidence_temper`); None when that is 0, the untempered E-step, which then computes
    nothing more."""
    ramp = config.trajectory_temper_iterations
    if not ramp:
        return None
    return evidence_temper(iteration, ramp, pairs_per_demonstration(demos.episode, demos.episodes))


def evidence_of(config: EStepConfig) -> Callable | None:
    """The evidence hook ``(iteration, demos) -> [E]`` of ``config`` (None: untempered)."""
    if not config.trajectory_temper_iterations:
        return None

    def evidence(iteration: jax.Array | None, demos: DemonstrationPairs) -> jax.Array:
        if iteration is None:
            raise ValueError("the tempered trajectory E-step needs the iteration")
        return tempered_evidence(config, iteration, demos)

    return evidence
