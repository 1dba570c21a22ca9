"""What EM-GAIL, Info/IntentionGAIL and GAIL each choose (conditions, weights, reward), and
Theorem 2 of the paper as a property of the pseudo-rewards (eq. 25 / 26)."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from emgail_jax.method.algorithms import imitation_reward, make_algorithm
from emgail_jax.method.config import NAMES, RewardForm
from emgail_jax.method.discriminator import discriminator_loss

LOG2 = math.log(2.0)


def shared_pair_log_posterior(shared: int, k: int, intention: int = 0) -> jax.Array:
    """log P(intention | s, a) at a pair shared by the first ``shared`` of ``k`` intentions: the
    optimal posterior is uniform over them and zero elsewhere."""
    logits = jnp.where(jnp.arange(k) < shared, 0.0, -1e9)
    return jax.nn.log_softmax(logits)[intention]


THEOREM2_CASES = [
    (k, shared, lam) for k in (1, 2, 3, 4) for shared in range(1, k + 1) for lam in (0.1, 1.0, 2.5)
]


@pytest.mark.parametrize(("k", "shared", "lam"), THEOREM2_CASES)
def test_theorem2_multi_intention_reward_error(k, shared, lam):
    logit = jnp.array(0.0)  # D = 1/2 at global optimality
    log_posterior = shared_pair_log_posterior(shared, k)
    assert float(log_posterior) == pytest.approx(math.log(1.0 / shared), abs=1e-6)
    log_alone = shared_pair_log_posterior(1, k)  # the same pair, not shared (|I| = 1)

    emgail = make_algorithm("emgail")
    info = make_algorithm("infogail", info_weight=lam)
    gail = make_algorithm("gail")

    # EM-GAIL: R = -log(1 - 1/2) = log 2 whatever |I|, so ER = 0 (eq. 25).
    reward = float(emgail.pseudo_reward(logit, log_posterior))
    assert reward == pytest.approx(LOG2, rel=1e-6)
    assert float(emgail.pseudo_reward(logit, log_alone)) - reward == pytest.approx(0.0, abs=1e-6)

    # Info/IntentionGAIL: R = log 2 + lambda log(1 / |I|), so ER = lambda log |I| (eq. 26).
    reward = float(info.pseudo_reward(logit, log_posterior))
    assert reward == pytest.approx(LOG2 + lam * math.log(1.0 / shared), rel=1e-6, abs=1e-6)
    error = float(info.pseudo_reward(logit, log_alone)) - reward
    assert error == pytest.approx(lam * math.log(shared), rel=1e-6, abs=1e-6)
    if shared > 1:
        assert error > 0

    # GAIL has no posterior term.
    assert float(gail.pseudo_reward(logit, log_posterior)) == pytest.approx(LOG2, rel=1e-6)


def test_pseudo_reward_batched_over_samples():
    logits = jnp.array([-1.0, 0.0, 2.0])
    log_posterior = jnp.log(jnp.array([0.5, 0.25, 1.0]))
    softplus = np.log1p(np.exp(np.asarray(logits)))
    np.testing.assert_allclose(
        make_algorithm("emgail").pseudo_reward(logits, log_posterior), softplus, rtol=1e-5
    )
    np.testing.assert_allclose(
        make_algorithm("infogail", info_weight=0.5).pseudo_reward(logits, log_posterior),
        softplus + 0.5 * np.log([0.5, 0.25, 1.0]),
        rtol=1e-5,
        atol=1e-6,
    )


def test_make_algorithm_flags():
    emgail, info, gail = (make_algorithm(n) for n in NAMES)
    assert (
        emgail.conditional_policy,
        emgail.learns_posterior,
        emgail.conditional_discriminator,
    ) == (
        True,
        True,
        True,
    )
    assert (info.conditional_policy, info.learns_posterior, info.conditional_discriminator) == (
        True,
        True,
        False,
    )
    assert (gail.conditional_policy, gail.learns_posterior, gail.conditional_discriminator) == (
        False,
        False,
        False,
    )
    assert emgail.info_weight == 0.0 and gail.info_weight == 0.0
    assert make_algorithm("infogail", info_weight=0.3).info_weight == 0.3


def test_unknown_algorithm_is_rejected():
    with pytest.raises(ValueError, match="unknown algorithm 'ppo'"):
        make_algorithm("ppo")


def test_emgail_conditions_and_weights():
    k = 3
    emgail = make_algorithm("emgail")
    gamma = jax.nn.softmax(jax.random.normal(jax.random.PRNGKey(0), (5, k)))
    np.testing.assert_array_equal(emgail.discriminator_conditions(k), np.eye(k))
    np.testing.assert_array_equal(emgail.expert_weights(gamma), gamma)
    intentions = jnp.array([[0, 2], [1, 1]])
    np.testing.assert_array_equal(
        emgail.policy_condition(intentions, k), np.eye(k)[np.asarray(intentions)]
    )
    np.testing.assert_array_equal(
        emgail.discriminator_condition(intentions, k), np.eye(k)[np.asarray(intentions)]
    )


@pytest.mark.parametrize("name", ["gail", "infogail"])
def test_unconditioned_discriminator_conditions_and_weights(name):
    k = 3
    algorithm = make_algorithm(name)
    gamma = jax.nn.softmax(jax.random.normal(jax.random.PRNGKey(1), (5, k)))
    assert algorithm.discriminator_conditions(k).shape == (1, 0)
    np.testing.assert_array_equal(algorithm.expert_weights(gamma), np.ones((5, 1)))
    assert algorithm.discriminator_condition(jnp.array([0, 2, 1]), k).shape == (3, 0)
    policy_condition = algorithm.policy_condition(jnp.array([0, 2, 1]), k)
    if name == "gail":
        assert policy_condition.shape == (3, 0)
    else:
        np.testing.assert_array_equal(policy_condition, np.eye(k)[[0, 2, 1]])


def _linear_discriminator(params, obs, actions, condition, intention_major=False):
    """f = w . [s, a] + v . c (the condition part vanishes for an empty condition)."""
    x = jnp.concatenate([obs, actions], -1)
    return x @ params["w"] + condition @ params["v"][: condition.shape[-1]]


@pytest.mark.parametrize("name", ["gail", "infogail"])
def test_baseline_m_step_is_the_gail_loss(name):
    """With the baselines' conditions and weights the M-step loss is eq. 22:
    -mean log D(s, a) on expert pairs - mean log(1 - D(s, a)) on policy samples."""
    k = 3
    algorithm = make_algorithm(name)
    keys = jax.random.split(jax.random.PRNGKey(2), 5)
    params = {"w": jax.random.normal(keys[0], (3,)), "v": jnp.zeros(k)}
    expert_obs, policy_obs = (jax.random.normal(key, (4, 2)) for key in keys[1:3])
    expert_act, policy_act = (jax.random.normal(key, (4, 1)) for key in keys[3:5])
    gamma = jnp.full((4, k), 1.0 / k)
    loss, _ = discriminator_loss(
        _linear_discriminator,
        params,
        expert_obs=expert_obs,
        expert_actions=expert_act,
        expert_weights=algorithm.expert_weights(gamma),
        conditions=algorithm.discriminator_conditions(k),
        policy_obs=policy_obs[None],
        policy_actions=policy_act[None],
        policy_conditions=algorithm.discriminator_condition(jnp.array([[0, 1, 2, 0]]), k),
    )
    f_real = np.asarray(jnp.concatenate([expert_obs, expert_act], -1) @ params["w"], np.float64)
    f_fake = np.asarray(jnp.concatenate([policy_obs, policy_act], -1) @ params["w"], np.float64)
    expected = np.mean(np.log1p(np.exp(-f_real))) + np.mean(np.log1p(np.exp(f_fake)))
    assert float(loss) == pytest.approx(expected, rel=1e-5)


def test_emgail_with_one_intention_is_gail():
    """Corollary 1: with |I| = 1 the responsibilities are one and EM-GAIL's loss and reward are
    GAIL's (the single one-hot condition is a constant input)."""
    emgail, gail = make_algorithm("emgail"), make_algorithm("gail")
    gamma = jax.nn.softmax(jnp.zeros((4, 1)))
    np.testing.assert_array_equal(emgail.expert_weights(gamma), gail.expert_weights(gamma))
    logits = jnp.array([-2.0, 0.0, 3.0])
    np.testing.assert_allclose(
        emgail.pseudo_reward(logits, jnp.zeros(3)), gail.pseudo_reward(logits, jnp.zeros(3))
    )


def test_logit_reward_form_is_the_logit_and_keeps_the_info_term():
    logits = jnp.array([-1.0, 0.0, 2.0])
    log_posterior = jnp.log(jnp.array([0.5, 0.25, 1.0]))
    np.testing.assert_array_equal(
        make_algorithm("gail", reward_form="logit").pseudo_reward(logits, log_posterior), logits
    )
    np.testing.assert_allclose(
        make_algorithm("infogail", 0.5, "logit").pseudo_reward(logits, log_posterior),
        logits + 0.5 * np.log([0.5, 0.25, 1.0]),
        rtol=1e-6,
    )
    # log D - log(1 - D): the GAIL reward minus -log D, negative where D < 1/2.
    gail = make_algorithm("emgail").pseudo_reward(logits, log_posterior)
    np.testing.assert_allclose(gail - jax.nn.softplus(-logits), logits, rtol=1e-5, atol=1e-6)


def test_imitation_reward_is_minus_log_one_minus_d():
    logits = np.array([-3.0, -0.5, 0.0, 0.7, 4.0])
    expected = -np.log(1.0 - 1.0 / (1.0 + np.exp(-logits)))
    np.testing.assert_allclose(imitation_reward(jnp.asarray(logits)), expected, rtol=1e-5)
    assert float(imitation_reward(jnp.array(0.0))) == pytest.approx(math.log(2.0))


def test_the_logit_form_is_the_logit_and_the_gail_form_its_softplus():
    logit = jnp.array([-1.0, 2.0])
    assert imitation_reward(logit, RewardForm.LOGIT).tolist() == logit.tolist()
    assert imitation_reward(logit, "gail").tolist() == pytest.approx([0.3132617, 2.1269280])


def test_the_log_d_form_is_log_d_never_positive_and_finite():
    logits = np.array([-100.0, -3.0, 0.0, 2.0, 100.0])
    reward = imitation_reward(jnp.asarray(logits), RewardForm.LOG_D)
    expected = np.log(1.0 / (1.0 + np.exp(-logits[1:4])))
    np.testing.assert_allclose(reward[1:4], expected, rtol=1e-5)
    assert float(reward[0]) == pytest.approx(-100.0) and -1e-30 < float(reward[-1]) <= 0.0
    grad = jax.vmap(jax.grad(lambda f: imitation_reward(f, "log-d")))(jnp.asarray(logits))
    assert np.all(np.isfinite(grad)) and np.all(np.asarray(grad) >= 0.0)


def test_imitation_reward_finite_at_extreme_logits():
    reward = imitation_reward(jnp.array([-100.0, 100.0]))
    grad = jax.vmap(jax.grad(imitation_reward))(jnp.array([-100.0, 100.0]))
    assert np.all(np.isfinite(reward)) and np.all(np.isfinite(grad))
    assert 0.0 <= float(reward[0]) < 1e-30  # D ~ 0: no reward
    assert float(reward[1]) == pytest.approx(100.0)  # D ~ 1: -log(1 - D) ~ f
    # The naive formula overflows in float32 where the softplus form does not.
    with np.errstate(divide="ignore"):
        naive = -np.log(1.0 - 1.0 / (1.0 + np.exp(np.float32(-100.0))))
    assert not np.isfinite(naive)
