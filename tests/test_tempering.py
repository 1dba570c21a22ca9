"""Tempering the trajectory E-step's evidence early (``trajectory_temper_iterations``): the
evidence hook's beta, and the E-step it gives."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_posterior import UNIFORM3, _expert, _posterior_and_batch

from emgail_jax.method.batches import DemonstrationPairs
from emgail_jax.method.config import EStepConfig, ResponsibilityMode
from emgail_jax.method.posterior import (
    expert_responsibilities,
    log_posterior,
    make_e_step,
    trajectory_responsibilities,
)
from emgail_jax.method.reseeding import demonstration_responsibilities
from emgail_jax.variants.tempering import evidence_of, evidence_temper, tempered_evidence


@pytest.mark.parametrize("jitted", [False, True])
def test_the_temper_rises_from_one_pair_to_the_whole_demonstration(jitted):
    """N = 10, demonstrations of 50 and 4 pairs: beta = 1/L at iteration 0 (0.02, 0.25),
    halfway at 5 (1 - 0.98/2 = 0.51, 1 - 0.75/2 = 0.625), exactly 1 at 10 and at 20."""
    temper = lambda iteration: evidence_temper(iteration, 10, jnp.array([50.0, 4.0]))
    if jitted:
        temper = jax.jit(temper)
    at = lambda iteration: np.asarray(temper(jnp.int32(iteration)))
    np.testing.assert_allclose(at(0), [0.02, 0.25], rtol=1e-6)
    np.testing.assert_allclose(at(5), [0.51, 0.625], rtol=1e-6)
    np.testing.assert_array_equal(at(10), [1.0, 1.0])
    np.testing.assert_array_equal(at(20), [1.0, 1.0])


def _three_demonstrations():
    """Random log-posteriors of 3 intentions on demonstrations of 4, 4 and 2 pairs."""
    logits = jax.random.normal(jax.random.PRNGKey(3), (10, 3)) * 2.0
    return jax.nn.log_softmax(logits), jnp.array([0, 0, 0, 0, 1, 1, 1, 1, 2, 2]), 3


def _tempered(iteration, mode="trajectory", weights=None, ramp=10):
    log_p, episode, episodes = _three_demonstrations()
    zeros = jnp.zeros((episode.shape[0], 1))
    demos = DemonstrationPairs(
        observations=zeros,
        actions=zeros,
        episode=episode,
        labels=jnp.full(episode.shape, -1),
        expert_returns=jnp.zeros(3),
        random_returns=jnp.zeros(3),
        episodes=episodes,
    )
    config = EStepConfig(responsibilities=mode, trajectory_temper_iterations=ramp)
    return expert_responsibilities(
        lambda log_p, obs, actions: log_p,
        log_p,
        zeros,
        zeros,
        episode=episode,
        episodes=episodes,
        mode=ResponsibilityMode(mode),
        weights=weights,
        evidence_weight=tempered_evidence(config, jnp.int32(iteration), demos),
    )


@pytest.mark.parametrize("mode", ["trajectory", "trajectory-centered"])
@pytest.mark.parametrize("weights", [None, jnp.array([0.5, 0.3, 0.2])])
def test_at_beta_one_the_tempered_e_step_is_the_plain_one_to_the_bit(mode, weights):
    log_p, episode, episodes = _three_demonstrations()
    plain = trajectory_responsibilities(
        log_p,
        episode,
        episodes,
        mode == "trajectory-centered",
        None if weights is None else jnp.log(weights),
    )
    for iteration in (10, 20):
        tempered = _tempered(iteration, mode, weights)
        np.testing.assert_array_equal(tempered.gamma, plain)
        np.testing.assert_array_equal(tempered.trajectory_labels, jnp.argmax(plain, -1))


@pytest.mark.parametrize("weights", [None, jnp.array([0.5, 0.3, 0.2])])
def test_at_iteration_0_a_demonstration_weighs_as_the_mean_of_its_pairs(weights):
    """softmax_i(mean_t log P(i | s_t, a_t) [+ log w_i]) per demonstration, whatever its
    length (4, 4 and 2 pairs here); the pair labels (eq. 29) are each pair's own argmax."""
    log_p, episode, episodes = _three_demonstrations()
    pairs = jax.ops.segment_sum(jnp.ones(episode.shape), episode, episodes)
    mean = jax.ops.segment_sum(log_p, episode, episodes) / pairs[:, None]
    log_prior = 0.0 if weights is None else jnp.log(weights)
    expected = jax.nn.softmax(mean + log_prior, -1)
    result = _tempered(0, weights=weights)
    np.testing.assert_allclose(result.gamma, expected[episode], rtol=1e-5)
    np.testing.assert_array_equal(result.pair_labels, jnp.argmax(log_p + log_prior, -1))
    # What the re-seeding reads, each demonstration's mean gamma over its pairs, is the same.
    np.testing.assert_allclose(
        demonstration_responsibilities(result.gamma, episode, episodes), expected, rtol=1e-5
    )
    centered = _tempered(0, "trajectory-centered", weights)
    expected = jax.nn.softmax(mean - mean.mean(0) + log_prior, -1)
    np.testing.assert_allclose(centered.gamma, expected[episode], rtol=1e-5)


def test_tempering_only_softens():
    """Halfway through the ramp gamma lies between iteration 0's and the plain E-step's: the
    demonstrations' most likely intentions are the same, less certain early."""
    certainty = lambda iteration: np.asarray(_tempered(iteration).gamma).max(-1)
    assert np.all(certainty(0) < certainty(5)) and np.all(certainty(5) < certainty(10))
    np.testing.assert_array_equal(_tempered(0).trajectory_labels, _tempered(10).trajectory_labels)


@pytest.mark.parametrize("jitted", [False, True])
def test_the_e_step_untempered_is_todays_to_the_bit(jitted, random_batch):
    """``trajectory_temper_iterations=0``: the E-step's output, given an iteration or not, is
    exactly the plain trajectory posterior of the trained network; with N = 10 at iteration 10
    it is that again, and at iteration 0 it differs."""
    k, m, n = 3, 5, 6
    net, optimizer, batch, start = _posterior_and_batch(random_batch, k, m, n)
    expert = _expert(n, 2)

    def e_step(ramp, iteration=None):
        config = EStepConfig(steps=3, trajectory_temper_iterations=ramp)
        step = make_e_step(net.apply, optimizer, config, evidence=evidence_of(config))
        call = lambda iteration: step(start, batch, expert, UNIFORM3, iteration=iteration)
        return (jax.jit(call) if jitted else call)(iteration)

    today = e_step(0)
    log_p = log_posterior(net.apply, today.posterior.params, batch.expert_obs, batch.expert_actions)
    plain = trajectory_responsibilities(log_p, jnp.asarray(expert.episode), 2)
    if not jitted:
        np.testing.assert_array_equal(today.gamma, plain)
    for other in (e_step(0, jnp.int32(0)), e_step(10, jnp.int32(10))):
        for got, want in zip(jax.tree.leaves(other), jax.tree.leaves(today), strict=True):
            np.testing.assert_array_equal(got, want)
    assert not np.array_equal(e_step(10, jnp.int32(0)).gamma, today.gamma)
    with pytest.raises(ValueError, match="needs the iteration"):
        e_step(10)
