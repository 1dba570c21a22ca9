"""AIRL's discriminator (``discriminator_form=airl``): the successor f reads, the current
policy's log-densities, and the logit and reward f - log pi they give, jitted and not."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from emgail_jax.method.algorithms import make_algorithm
from emgail_jax.method.config import RewardForm
from emgail_jax.method.discriminator import Read, discriminator_loss, expert_scores, learned_reward
from emgail_jax.method.networks import AIRLDiscriminator, GaussianPolicy
from emgail_jax.variants.airl import (
    LogitOffsets,
    expert_log_densities,
    own_log_densities,
    successor,
    with_log_densities,
)

K, M, N, D, A = 2, 3, 4, 2, 1


def _maybe_jit(fn, jit):
    return jax.jit(fn) if jit else fn


def _gaussian_log_density(action, mean, log_std):
    z = (action - mean) / np.exp(log_std)
    return np.sum(-0.5 * z**2 - log_std - 0.5 * np.log(2 * np.pi), -1)


@pytest.fixture(scope="module")
def policy():
    net = GaussianPolicy(A, (8,), init_log_std=-0.5, heads=True)
    params = net.init(jax.random.PRNGKey(1), jnp.zeros((1, D)), jnp.eye(K)[:1])
    return net, params


def test_successor_is_the_next_observation_and_whether_the_episode_goes_on():
    next_obs = jnp.array([[1.0, 2.0], [3.0, 4.0]])
    np.testing.assert_array_equal(
        successor(next_obs, jnp.array([0.0, 1.0])), [[1.0, 2.0, 1.0], [3.0, 4.0, 0.0]]
    )


@pytest.mark.parametrize("jit", [False, True])
def test_log_densities_are_the_current_policys_under_each_condition(policy, jit):
    net, params = policy
    keys = jax.random.split(jax.random.PRNGKey(2), 4)
    obs, executed = jax.random.normal(keys[0], (K, M, D)), jax.random.normal(keys[1], (K, M, A))
    own = jnp.broadcast_to(jnp.eye(K)[:, None, :], (K, M, K))
    got = _maybe_jit(lambda p: own_log_densities(net.apply, p, obs, executed, own), jit)(params)
    mean, log_std = net.apply(params, obs, own)
    np.testing.assert_allclose(got, _gaussian_log_density(executed, mean, log_std), rtol=1e-5)

    expert_obs, expert_actions = (
        jax.random.normal(keys[2], (N, D)),
        jax.random.normal(keys[3], (N, A)),
    )
    every = _maybe_jit(
        lambda p: expert_log_densities(net.apply, p, expert_obs, expert_actions, jnp.eye(K)), jit
    )(params)
    assert every.shape == (N, K)
    for i in range(K):
        mean, log_std = net.apply(params, expert_obs, jnp.broadcast_to(jnp.eye(K)[i], (N, K)))
        np.testing.assert_allclose(
            every[:, i], _gaussian_log_density(expert_actions, mean, log_std), rtol=1e-5
        )


def test_log_densities_pass_no_gradient_to_the_policy(policy):
    net, params = policy
    obs, executed = jnp.ones((N, D)), jnp.ones((N, A))
    total = lambda p: expert_log_densities(net.apply, p, obs, executed, jnp.eye(K)).sum()
    assert all(float(jnp.abs(g).max()) == 0.0 for g in jax.tree.leaves(jax.grad(total)(params)))


@pytest.mark.parametrize("algo", ["emgail", "gail"])
def test_with_log_densities_conditions_the_policy_as_the_discriminator(random_batch, algo):
    """EM-GAIL: each sample under its own intention, each expert pair under all K; GAIL: its
    one policy, one condition."""
    heads = algo == "emgail"
    net = GaussianPolicy(A, (8,), heads=heads)
    algorithm = make_algorithm(algo)
    condition = algorithm.policy_condition(jnp.zeros(1, int), K)
    params = net.init(jax.random.PRNGKey(3), jnp.zeros((1, D)), condition)
    batch = random_batch(k=K, m=M, n=N, obs_dim=D, act_dim=A)
    densities = with_log_densities(batch, net.apply, params, algorithm)
    c = K if heads else 1
    extras = densities.extra
    assert extras.log_policy.shape == (K, M)
    assert extras.expert_log_policy.shape == (N, c)
    rows = algorithm.policy_condition(batch.own_intention(), K)
    mean, log_std = net.apply(params, batch.obs, rows, intention_major=True)
    np.testing.assert_allclose(
        extras.log_policy, _gaussian_log_density(batch.executed, mean, log_std), rtol=1e-5
    )


def _toy_apply(params, obs, follows, condition, intention_major=False):
    """A stand-in f: s_0 + s'_0 + c . params."""
    return obs[..., 0] + follows[..., 0] + condition @ params


@pytest.mark.parametrize("jit", [False, True])
def test_loss_logit_is_f_minus_log_pi(random_batch, jit):
    """The loss with log-density offsets is the loss of the logits f - log pi written out."""
    batch = random_batch(k=K, m=M, n=N, obs_dim=D, act_dim=D + 1)
    keys = jax.random.split(jax.random.PRNGKey(4), 2)
    expert_log_pi = jax.random.normal(keys[0], (N, K))
    policy_log_pi = jax.random.normal(keys[1], (K, M))
    weights = jax.nn.softmax(jax.random.normal(keys[0], (N, K)))
    params = jnp.array([0.3, -0.2])
    own = jnp.broadcast_to(jnp.eye(K)[:, None, :], (K, M, K))
    loss_of = lambda p: discriminator_loss(
        _toy_apply,
        p,
        expert_obs=batch.expert_obs,
        expert_actions=batch.expert_actions,
        expert_weights=weights,
        conditions=jnp.eye(K),
        policy_obs=batch.obs,
        policy_actions=batch.executed,
        policy_conditions=own,
        hook=LogitOffsets(offsets=policy_log_pi, expert_offsets=expert_log_pi),
    )
    loss, _ = _maybe_jit(loss_of, jit)(params)
    f_real = (batch.expert_obs[:, 0] + batch.expert_actions[:, 0])[:, None] + params[None]
    f_fake = batch.obs[..., 0] + batch.executed[..., 0] + params[:, None]
    real, fake = f_real - expert_log_pi, f_fake - policy_log_pi
    expected = np.mean(np.sum(weights * np.logaddexp(0, -real), -1)) + np.mean(
        np.logaddexp(0, fake)
    )
    assert float(loss) == pytest.approx(float(expected), rel=1e-5)
    read = Read(batch.executed, batch.expert_actions, policy_log_pi, expert_log_pi)
    np.testing.assert_allclose(
        expert_scores(_toy_apply, params, batch.expert_obs, read, jnp.eye(K)), real, rtol=1e-5
    )


@pytest.mark.parametrize("jit", [False, True])
def test_reward_is_the_logit_f_minus_log_pi(jit):
    """AIRL's B-step reward log D - log(1 - D) = f - log pi (the logit form)."""
    algorithm = make_algorithm("emgail", reward_form=RewardForm.LOGIT)
    net = AIRLDiscriminator((8,), heads=True, discount=0.9)
    obs = jax.random.normal(jax.random.PRNGKey(5), (K, M, D))
    follows = successor(obs[..., ::-1], jnp.zeros((K, M)))
    log_pi = jax.random.normal(jax.random.PRNGKey(6), (K, M))
    own = jnp.broadcast_to(jnp.eye(K)[:, None, :], (K, M, K))
    params = net.init(jax.random.PRNGKey(7), obs[0, :1], follows[0, :1], jnp.eye(K)[:1])
    reward = _maybe_jit(
        lambda p: learned_reward(
            net.apply,
            p,
            algorithm,
            K,
            obs=obs,
            executed=follows,
            intention=jnp.broadcast_to(jnp.arange(K)[:, None], (K, M)),
            own_log_posterior=jnp.zeros((K, M)),
            intention_major=True,
            log_policy=log_pi,
        ),
        jit,
    )(params)
    f = net.apply(params, obs, follows, own, intention_major=True)
    np.testing.assert_allclose(reward, f - log_pi, rtol=1e-5, atol=1e-6)


def test_the_form_reads_successors_and_offsets_where_the_paper_reads_actions(random_batch):
    from emgail_jax.method.hooks import Form
    from emgail_jax.variants.airl import AirlForm
    from emgail_jax.variants.extras import attached

    batch = random_batch(k=3, m=4, n=6, obs_dim=2)
    assert Form().read(batch) == Read(batch.executed, batch.expert_actions)
    airl = attached(
        batch,
        successor=np.ones((3, 4, 3)),
        expert_successor=np.ones((6, 3)),
        log_policy=np.zeros((3, 4)),
        expert_log_policy=np.zeros((6, 3)),
    )
    assert airl.check() is airl
    extras = airl.extra
    assert AirlForm().read(airl) == Read(
        extras.successor, extras.expert_successor, extras.log_policy, extras.expert_log_policy
    )
