"""Absorbing states (``absorbing_state``): the absorbing pair in the M-step's loss, its learned
reward, and the termination flags the batch carries."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_discriminator import HAND_BATCH, HAND_PARAMS, LN3, m_step_case, toy_apply

from emgail_jax.method.algorithms import make_algorithm
from emgail_jax.method.discriminator import discriminator_loss
from emgail_jax.method.networks import Discriminator
from emgail_jax.variants.absorbing import AbsorbedSamples, absorbing_reward
from emgail_jax.variants.extras import attached


def toy_absorbing_apply(params, obs, actions, condition, intention_major=False, absorbed=None):
    """``toy_apply`` whose absorbing indicator adds ln 3 to the logit (0 for real pairs)."""
    return toy_apply(params, obs, actions, condition) + LN3 * (
        0.0 if absorbed is None else absorbed
    )


@pytest.mark.parametrize("jit", [False, True])
def test_absorbing_pairs_hand_computed_one_sample_per_termination(jit):
    """The hand batch with absorbing pairs: the indicator adds ln 3, so the absorbing logit
    is (ln 3, 2 ln 3) under the two conditions (D = 3/4, 9/10). One demonstration ended in a
    termination with gamma (1/2, 1/2): one real sample more; row 0's policy terminated twice:
    two fake samples more, none in row 1."""
    hook = AbsorbedSamples(expert=jnp.array([0.5, 0.5]), policy=jnp.array([2.0, 0.0]))
    loss_of = lambda p: discriminator_loss(toy_absorbing_apply, p, **HAND_BATCH, hook=hook)
    loss, metrics = (jax.jit(loss_of) if jit else loss_of)(HAND_PARAMS)
    # -log D of the absorbing pair: log 4/3, log 10/9; -log(1 - D) under row 0: log 4.
    real = 0.5 * math.log(2) + 0.5 * math.log(4 / 3) + math.log(4)
    expert_term = (real + 0.5 * math.log(4 / 3) + 0.5 * math.log(10 / 9)) / 3
    policy_term = (math.log(4 / 3) + math.log(4) + 2 * math.log(4)) / 4
    assert float(loss) == pytest.approx(expert_term + policy_term, rel=1e-6)
    assert float(metrics["discriminator/absorbing_d"]) == pytest.approx(0.825, rel=1e-6)
    assert float(metrics["discriminator/policy_d"]) == pytest.approx(0.5, rel=1e-6)
    # No termination on either side: the loss without absorbing pairs, to the bit.
    none = AbsorbedSamples(expert=jnp.zeros(2), policy=jnp.zeros(2))
    without, _ = discriminator_loss(toy_absorbing_apply, HAND_PARAMS, **HAND_BATCH, hook=none)
    plain, plain_metrics = discriminator_loss(toy_apply, HAND_PARAMS, **HAND_BATCH)
    assert float(without) == pytest.approx(float(plain), rel=1e-7)
    assert "discriminator/absorbing_d" not in plain_metrics


@pytest.mark.parametrize("algo", ["emgail", "infogail", "gail"])
def test_absorbing_reward_is_the_pseudo_reward_of_the_absorbing_pair(algo):
    k = 2
    algorithm = make_algorithm(algo, info_weight=0.5)
    params = jnp.array([0.3, -0.4]) if algorithm.conditional_discriminator else jnp.zeros(0)
    reward = absorbing_reward(toy_absorbing_apply, params, algorithm, k, 3, 2)
    # Observation and action zeros, indicator 1: f = ln 3 (+ the condition's parameter).
    logit = LN3 + (params if algorithm.conditional_discriminator else jnp.zeros(k))
    info = 0.5 * math.log(1 / k) if algo == "infogail" else 0.0  # a uniform posterior
    np.testing.assert_allclose(reward, jax.nn.softplus(logit) + info, rtol=1e-6)


@pytest.mark.parametrize("algo", ["emgail", "gail"])
def test_the_m_step_counts_one_absorbing_sample_per_termination(algo, random_batch):
    """With termination flags, the absorbing pair is real with the summed weights of the
    demonstrations that ended in a termination, and fake once for each terminated policy
    transition."""

    def flagged(batch, weights):
        terminal = jnp.zeros((3, 4)).at[0, 1].set(1.0).at[0, 3].set(1.0).at[2, 0].set(1.0)
        expert_terminal = jnp.zeros(6).at[2].set(1.0).at[5].set(1.0)
        batch = attached(batch, terminal=terminal, expert_terminal=expert_terminal)
        hook = AbsorbedSamples.of(batch, weights)
        np.testing.assert_allclose(hook.expert, weights[2] + weights[5])
        np.testing.assert_array_equal(hook.policy, [2.0, 0.0, 1.0])
        return batch, hook

    absorbing = lambda **kwargs: Discriminator(**kwargs, absorbing=True)
    metrics = m_step_case(algo, random_batch, flagged, absorbing)
    assert "discriminator/absorbing_d" in metrics
