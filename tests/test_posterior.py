"""The E-step: the posterior's cross-entropy, its training and the responsibilities (eq. 18)."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from emgail_jax.method.batches import DemonstrationPairs
from emgail_jax.method.config import (
    EStepConfig,
    ResponsibilityMode,
    RewardFrom,
    SettingError,
)
from emgail_jax.method.networks import Posterior
from emgail_jax.method.optim import Learner
from emgail_jax.method.posterior import (
    expert_responsibilities,
    log_posterior,
    make_e_step,
    mixture_weights,
    posterior_loss,
    posterior_update,
    trajectory_responsibilities,
)

LN3 = math.log(3.0)
UNIFORM3 = jnp.full(3, 1 / 3)


def toy_apply(logits, obs, actions):
    """Ignores the inputs: the logits of every row are given directly as the 'parameters'."""
    del actions
    return logits[: obs.shape[0]]


def test_loss_hand_computed_cross_entropy():
    # Row 0: logits (0, ln 3) -> P = (1/4, 3/4), label 1 -> -log 3/4, predicted 1 (right).
    # Row 1: logits (ln 3, 0) -> P = (3/4, 1/4), label 1 -> -log 1/4, predicted 0 (wrong).
    logits = jnp.array([[0.0, LN3], [LN3, 0.0]])
    loss, metrics = posterior_loss(
        toy_apply, logits, jnp.zeros((2, 1)), jnp.zeros((2, 1)), jnp.array([1, 1])
    )
    expected = (-math.log(0.75) - math.log(0.25)) / 2
    assert float(loss) == pytest.approx(expected, rel=1e-6)
    assert float(metrics["posterior/loss"]) == pytest.approx(expected, rel=1e-6)
    assert float(metrics["posterior/policy_accuracy"]) == 0.5


def test_loss_equals_cross_entropy_of_network():
    k = 3
    net = Posterior(num_intentions=k, hidden=(8,))
    keys = jax.random.split(jax.random.PRNGKey(0), 4)
    obs = jax.random.normal(keys[0], (7, 4))
    actions = jax.random.normal(keys[1], (7, 2))
    labels = jax.random.randint(keys[2], (7,), 0, k)
    params = net.init(keys[3], obs, actions)
    logits = np.asarray(net.apply(params, obs, actions), np.float64)
    log_p = logits - np.log(np.exp(logits).sum(1, keepdims=True))
    expected = -np.mean(log_p[np.arange(7), np.asarray(labels)])
    loss, _ = posterior_loss(net.apply, params, obs, actions, labels)
    assert float(loss) == pytest.approx(expected, rel=1e-5)


def pair_mode(logits, episode=None, episodes=1, mode="pair"):
    n = logits.shape[0]
    episode = jnp.zeros(n, jnp.int32) if episode is None else episode
    zeros = jnp.zeros((n, 1))
    return expert_responsibilities(
        toy_apply,
        logits,
        zeros,
        zeros,
        episode=episode,
        episodes=episodes,
        mode=ResponsibilityMode(mode),
    )


def test_responsibilities_are_the_posterior_probabilities():
    logits = jnp.array([[0.0, LN3], [LN3, 0.0], [0.0, 0.1]])
    result = pair_mode(logits)
    np.testing.assert_allclose(
        result.gamma, [[0.25, 0.75], [0.75, 0.25], [0.475021, 0.524979]], rtol=1e-5
    )
    np.testing.assert_array_equal(result.pair_labels, [1, 0, 1])
    np.testing.assert_array_equal(result.trajectory_labels, [1, 0, 1])


def test_unknown_mode_is_refused_where_the_option_is_read():
    with pytest.raises(SettingError, match="one of trajectory, trajectory-centered, pair, labels"):
        EStepConfig(responsibilities="episode")
    assert EStepConfig(responsibilities="pair").responsibilities is ResponsibilityMode.PAIR


def test_labels_mode_is_the_one_hot_labels_and_keeps_the_posterior_pair_labels():
    logits = jnp.array([[0.0, LN3], [LN3, 0.0], [0.0, 0.1]])
    zeros = jnp.zeros((3, 1))
    episode = jnp.zeros(3, jnp.int32)
    labels = jnp.array([0, 0, 1])
    result = expert_responsibilities(
        toy_apply,
        logits,
        zeros,
        zeros,
        episode=episode,
        episodes=1,
        mode=ResponsibilityMode.LABELS,
        labels=labels,
    )
    np.testing.assert_array_equal(result.gamma, [[1, 0], [1, 0], [0, 1]])
    np.testing.assert_array_equal(result.pair_labels, [1, 0, 1])  # eq. 29: the posterior's
    np.testing.assert_array_equal(result.trajectory_labels, labels)
    with pytest.raises(ValueError, match="hidden labels"):
        pair_mode(logits, mode="labels")


@pytest.fixture(scope="module")
def separable_problem():
    """Three well separated clusters of (obs, action) pairs, one per intention."""
    k, per = 3, 20
    rng = np.random.default_rng(0)
    centres = np.array([[3.0, 0.0, 0.0], [-3.0, 3.0, 0.0], [0.0, -3.0, 3.0]])
    labels = np.repeat(np.arange(k), per)
    pairs = centres[labels] + 0.5 * rng.normal(size=(k * per, 3))
    obs = jnp.asarray(pairs[:, :2], jnp.float32)
    actions = jnp.asarray(pairs[:, 2:], jnp.float32)
    net = Posterior(num_intentions=k, hidden=(16,))
    params = net.init(jax.random.PRNGKey(1), obs, actions)
    return net, params, obs, actions, jnp.asarray(labels)


def test_update_reduces_loss_on_separable_problem(separable_problem):
    net, params, obs, actions, labels = separable_problem
    optimizer = optax.adam(1e-2)
    update = jax.jit(
        lambda p: posterior_update(net.apply, optimizer, p, obs, actions, labels, steps=100)
    )
    trained, metrics = update(Learner.create(params, optimizer))
    new_params = trained.params
    before, _ = posterior_loss(net.apply, params, obs, actions, labels)
    after, after_metrics = posterior_loss(net.apply, new_params, obs, actions, labels)
    # Metrics come from the first step, i.e. describe the parameters before the update.
    assert float(metrics["posterior/loss"]) == pytest.approx(float(before), rel=1e-5)
    assert float(after) < 0.5 * float(before)
    assert float(after_metrics["posterior/policy_accuracy"]) == 1.0
    gamma = jnp.exp(log_posterior(net.apply, new_params, obs, actions))
    assert gamma.shape == (60, 3)
    np.testing.assert_allclose(gamma.sum(-1), 1.0, rtol=1e-5)
    np.testing.assert_array_equal(jnp.argmax(gamma, -1), labels)


def test_trajectory_responsibilities_hand_computed():
    """Episode 0 = pairs 0, 1, 2 with P = (3/4, 1/4), (1/4, 3/4) and (1/2, 1/2): the product is
    symmetric, so gamma = (1/2, 1/2). Episode 1 = pairs 3, 4, both (3/4, 1/4): the product
    (9/16, 1/16) normalises to (9/10, 1/10), which both pairs take."""
    logits = jnp.array([[LN3, 0.0], [0.0, LN3], [0.0, 0.0], [LN3, 0.0], [LN3, 0.0]])
    episode = jnp.array([0, 0, 0, 1, 1])
    gamma = trajectory_responsibilities(jax.nn.log_softmax(logits), episode, 2, centered=False)
    expected = [[0.5, 0.5]] * 3 + [[0.9, 0.1]] * 2
    np.testing.assert_allclose(gamma, expected, rtol=1e-6)
    # In trajectory mode gamma is the episode's; the pair labels stay each pair's own argmax.
    result = pair_mode(logits, episode, 2, mode="trajectory")
    np.testing.assert_allclose(result.gamma, expected, rtol=1e-6)
    np.testing.assert_array_equal(result.pair_labels, [0, 1, 0, 0, 0])
    np.testing.assert_array_equal(result.trajectory_labels, [0, 0, 0, 0, 0])


def test_trajectory_responsibilities_let_the_majority_of_an_episode_decide():
    """A demonstration whose pairs mostly point to intention 1 gives every one of its pairs,
    also those the per-pair posterior got wrong, to intention 1; and it stays finite where the
    per-pair probabilities underflow."""
    rng = np.random.default_rng(0)
    pair_logits = np.where(rng.random((100, 1)) < 0.8, [-2.0, 2.0], [2.0, -2.0])
    logits = jnp.asarray(np.concatenate([pair_logits, [[-200.0, 200.0]]]), jnp.float32)
    episode = jnp.zeros(101, jnp.int32)
    per_pair = pair_mode(logits).gamma
    assert np.mean(np.argmax(per_pair, -1) == 1) < 0.9
    gamma = trajectory_responsibilities(jax.nn.log_softmax(logits), episode, 1, centered=False)
    assert np.all(np.isfinite(gamma))
    np.testing.assert_allclose(gamma, np.tile([0.0, 1.0], (101, 1)), atol=1e-6)


def test_centered_trajectory_responsibilities_hand_computed():
    """The episodes of the hand-computed case above, centred: the summed log-posteriors are
    (a, a) for episode 0 and (2 ln 3/4, 2 ln 1/4) for episode 1; minus their mean over the two
    episodes, episode 0 leans ln 3 towards intention 1 and episode 1 ln 3 towards intention 0:
    gamma (1/4, 3/4) and (3/4, 1/4). The two demonstrations go to different intentions."""
    logits = jnp.array([[LN3, 0.0], [0.0, LN3], [0.0, 0.0], [LN3, 0.0], [LN3, 0.0]])
    episode = jnp.array([0, 0, 0, 1, 1])
    gamma = trajectory_responsibilities(jax.nn.log_softmax(logits), episode, 2, centered=True)
    expected = [[0.25, 0.75]] * 3 + [[0.75, 0.25]] * 2
    np.testing.assert_allclose(gamma, expected, rtol=1e-5)
    np.testing.assert_allclose(
        pair_mode(logits, episode, 2, mode="trajectory-centered").gamma, expected, rtol=1e-5
    )


def test_centering_cancels_a_lean_common_to_every_pair():
    """A posterior that leans to intention 0 on every pair (0.62 / 0.38 on one demonstration's
    100 pairs, 0.58 / 0.42 on the other's): the uncentred product sends both demonstrations to
    intention 0; centred, they go where they differ, one to each intention."""
    p = np.repeat([[0.62, 0.38], [0.58, 0.42]], 100, axis=0)
    log_p = jnp.log(jnp.asarray(p, jnp.float32))
    episode = jnp.repeat(jnp.arange(2), 100)
    raw = trajectory_responsibilities(log_p, episode, 2, centered=False)
    np.testing.assert_array_equal(np.argmax(raw, -1), np.zeros(200))
    centered = trajectory_responsibilities(log_p, episode, 2, centered=True)
    np.testing.assert_array_equal(np.argmax(centered, -1), np.repeat([0, 1], 100))


def _expert(n, episodes):
    episode = np.repeat(np.arange(episodes), n // episodes).astype(np.int32)
    return DemonstrationPairs(
        observations=np.zeros((n, 2), np.float32),
        actions=np.zeros((n, 1), np.float32),
        episode=episode,
        labels=np.full(n, -1, np.int32),
        expert_returns=np.zeros(3, np.float32),
        random_returns=np.zeros(3, np.float32),
        episodes=episodes,
    )


def test_e_step_without_a_posterior_is_uniform_with_zero_log_posterior(random_batch):
    """GAIL's E-step: every pair belongs to every intention alike, and no reward term."""
    e_step = make_e_step(None, optax.adam(1e-3), EStepConfig())
    result = e_step(None, random_batch(3, 4, 6), _expert(6, 2), UNIFORM3)
    np.testing.assert_array_equal(result.gamma, np.full((6, 3), 1 / 3, np.float32))
    np.testing.assert_array_equal(result.own_log_posterior, np.zeros((3, 4)))
    assert result.posterior is None and result.responsibilities is None


def _posterior_and_batch(random_batch, k, m, n):
    """A small posterior network, its optimiser, a random batch and the fresh learner."""
    net = Posterior(num_intentions=k, hidden=(8,))
    optimizer = optax.adam(1e-2)
    batch = random_batch(k, m, n)
    start = Learner.create(
        net.init(jax.random.PRNGKey(1), batch.obs[0], batch.executed[0]), optimizer
    )
    return net, optimizer, batch, start


@pytest.mark.parametrize("reward_from", ["updated", "previous"])
def test_e_step_trains_on_the_policy_samples_and_scores_their_own_intention(
    reward_from, random_batch
):
    k, m, n = 3, 5, 6
    net, optimizer, batch, start = _posterior_and_batch(random_batch, k, m, n)
    config = EStepConfig(steps=7, responsibilities="pair")
    e_step = make_e_step(net.apply, optimizer, config, reward_from=RewardFrom(reward_from))
    result = e_step(start, batch, _expert(n, 2), UNIFORM3)
    # The same training, written out: the samples labelled by the row they came from.
    labels = np.repeat(np.arange(k), m)
    flat = lambda x: x.reshape(k * m, -1)
    trained, _ = posterior_update(
        net.apply, optimizer, start, flat(batch.obs), flat(batch.executed), labels, steps=7
    )
    np.testing.assert_allclose(
        result.posterior.params["params"]["MLP_0"]["Dense_0"]["kernel"],
        trained.params["params"]["MLP_0"]["Dense_0"]["kernel"],
        rtol=1e-6,
    )
    gamma = jnp.exp(
        log_posterior(net.apply, trained.params, batch.expert_obs, batch.expert_actions)
    )
    np.testing.assert_allclose(result.gamma, gamma, rtol=1e-5)
    scoring = trained if reward_from == "updated" else start
    log_p = log_posterior(net.apply, scoring.params, batch.obs, batch.executed)  # [K, M, K]
    own = np.stack([log_p[i, :, i] for i in range(k)])
    np.testing.assert_allclose(result.own_log_posterior, own, rtol=1e-5)
    np.testing.assert_array_equal(result.weights, UNIFORM3)  # the uniform prior passes through
    assert "posterior/intention_weights" not in result.metrics


# ---- the mixture prior (demonstrations in unequal shares) ----------------------------------


def test_mixture_weights_are_the_mean_responsibilities_floored():
    gamma = jnp.array([[0.9, 0.1, 0.0], [0.7, 0.3, 0.0], [0.2, 0.8, 0.0], [1.0, 0.0, 0.0]])
    weights = mixture_weights(gamma)
    np.testing.assert_allclose(weights.sum(), 1.0, rtol=1e-6)
    assert float(weights[2]) > 0  # a weight at 0 could never recover
    np.testing.assert_allclose(weights[:2] / weights[:2].sum(), [0.7, 0.3], rtol=1e-3)


def test_kept_only_relabels_to_the_most_likely_kept_intention():
    """Two demonstrations of two pairs; intention 1 retired: its pairs and its demonstration go
    to the next most likely intention, pair by pair and demonstration by demonstration."""
    p = jnp.array([[0.6, 0.3, 0.1], [0.3, 0.5, 0.2], [0.2, 0.7, 0.1], [0.2, 0.5, 0.3]])
    episode = jnp.array([0, 0, 1, 1])
    apply = lambda logits, obs, act: logits
    result = expert_responsibilities(
        apply, jnp.log(p), p, p, episode=episode, episodes=2, mode=ResponsibilityMode.TRAJECTORY
    )
    np.testing.assert_array_equal(result.pair_labels, [0, 1, 1, 1])  # demonstration 0: 0.18 for 0
    np.testing.assert_array_equal(result.trajectory_labels, [0, 0, 1, 1])
    kept = result.kept_only(jnp.array([True, False, True]))
    np.testing.assert_array_equal(kept.pair_labels, [0, 0, 0, 2])
    # Demonstration 1: 0.2 * 0.2 = 0.04 for intention 0 against 0.1 * 0.3 = 0.03 for 2.
    np.testing.assert_array_equal(kept.trajectory_labels, [0, 0, 0, 0])
    np.testing.assert_array_equal(kept.gamma, result.gamma)
    everything = result.kept_only(jnp.ones(3, bool))
    np.testing.assert_array_equal(everything.pair_labels, result.pair_labels)
    np.testing.assert_array_equal(everything.trajectory_labels, result.trajectory_labels)


@pytest.mark.parametrize("mode", ["pair", "trajectory"])
def test_the_prior_reweighs_the_posterior(mode):
    """gamma_i is proportional to w_i P(i | s, a) (per pair), or to w_i prod_t P(i | s_t, a_t)
    (per demonstration); a uniform w changes nothing."""
    p = jnp.array([[0.6, 0.4], [0.5, 0.5], [0.3, 0.7], [0.55, 0.45]])
    episode, w = jnp.array([0, 0, 1, 1]), jnp.array([0.2, 0.8])
    gamma = lambda weights: (
        expert_responsibilities(
            lambda logits, obs, act: logits,
            jnp.log(p),
            p,
            p,
            episode=episode,
            episodes=2,
            mode=ResponsibilityMode(mode),
            weights=weights,
        ).gamma
    )
    if mode == "pair":
        expected = w * p / (w * p).sum(-1, keepdims=True)
    else:
        evidence = w * jnp.stack([p[:2].prod(0), p[2:].prod(0)])
        expected = (evidence / evidence.sum(-1, keepdims=True))[episode]
    np.testing.assert_allclose(gamma(w), expected, rtol=1e-5)
    np.testing.assert_allclose(gamma(jnp.full(2, 0.5)), gamma(None), rtol=1e-6)


def test_e_step_with_the_mixture_prior_reestimates_the_weights(random_batch):
    k, m, n = 3, 5, 6
    net, optimizer, batch, start = _posterior_and_batch(random_batch, k, m, n)
    config = EStepConfig(steps=3, responsibilities="pair", prior="mixture")
    prior = jnp.array([0.6, 0.3, 0.1])
    result = make_e_step(net.apply, optimizer, config)(start, batch, _expert(n, 2), prior)
    log_p = log_posterior(
        net.apply, result.posterior.params, batch.expert_obs, batch.expert_actions
    )
    np.testing.assert_allclose(result.gamma, jax.nn.softmax(log_p + jnp.log(prior)), rtol=1e-5)
    np.testing.assert_allclose(result.weights, mixture_weights(result.gamma), rtol=1e-6)
    np.testing.assert_allclose(result.metrics["posterior/intention_weights"], result.weights)


def test_the_pair_e_step_has_no_trajectory_evidence_to_weigh():
    logits = jnp.array([[0.0, LN3], [LN3, 0.0]])
    with pytest.raises(ValueError, match="the pair E-step has no trajectory evidence"):
        expert_responsibilities(
            toy_apply,
            logits,
            jnp.zeros((2, 1)),
            jnp.zeros((2, 1)),
            episode=jnp.zeros(2, jnp.int32),
            episodes=1,
            mode=ResponsibilityMode.PAIR,
            evidence_weight=jnp.ones(1),
        )
