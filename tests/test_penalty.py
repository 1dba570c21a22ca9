"""The discriminator's gradient penalty (``discriminator_gradient_penalty``), a regulariser of
the M-step's loss."""

import jax
import jax.numpy as jnp
import optax
import pytest
from test_discriminator import LN3, network_batch, toy_apply  # noqa: F401 (a fixture)

from emgail_jax.method.discriminator import LossInputs, discriminator_loss, discriminator_update
from emgail_jax.method.optim import Learner
from emgail_jax.variants.penalty import GradientPenalty, input_gradient_norms


def test_gradient_penalty_hand_computed_on_a_linear_logit():
    """toy_apply's logit has slope 1 in s_0 and in a_0: a squared input-gradient norm of 2 on
    every expert pair (under every condition, weights summing to one) and policy sample."""
    batch = dict(
        expert_obs=jnp.array([[0.3, 1.0], [-2.0, 0.5]]),
        expert_actions=jnp.zeros((2, 1)),
        expert_weights=jnp.array([[0.25, 0.75], [1.0, 0.0]]),
        conditions=jnp.eye(2),
        policy_obs=jnp.ones((2, 3, 2)),
        policy_actions=jnp.zeros((2, 3, 1)),
        policy_conditions=jnp.broadcast_to(jnp.eye(2)[:, None], (2, 3, 2)),
    )
    params = jnp.array([0.0, LN3])
    assert float(input_gradient_norms(toy_apply, params, LossInputs(**batch))) == pytest.approx(2.0)
    plain, metrics = discriminator_loss(toy_apply, params, **batch)
    penalised, penalised_metrics = discriminator_loss(
        toy_apply, params, **batch, hook=GradientPenalty(0.5)
    )
    assert float(penalised) == pytest.approx(float(plain) + 1.0)
    assert "discriminator/gradient_norm" not in metrics
    assert float(penalised_metrics["discriminator/gradient_norm"]) == pytest.approx(2.0)


def test_gradient_penalty_flattens_the_trained_logit(network_batch):  # noqa: F811
    net, params, batch = network_batch
    optimizer = optax.adam(1e-2)
    norms = {}
    for weight in (0.0, 1.0):
        hook = GradientPenalty(weight) if weight else None
        fit = lambda p, hook=hook: discriminator_update(
            net.apply, optimizer, p, 100, **batch, hook=hook
        )
        trained, _ = jax.jit(fit)(Learner.create(params, optimizer))
        norms[weight] = float(input_gradient_norms(net.apply, trained.params, LossInputs(**batch)))
    assert norms[1.0] < 0.5 * norms[0.0]
