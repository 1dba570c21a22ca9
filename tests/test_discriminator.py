"""The M-step loss (eq. 19 / 22) and training."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from emgail_jax.method.algorithms import make_algorithm
from emgail_jax.method.config import MStepConfig
from emgail_jax.method.discriminator import (
    discriminator_loss,
    discriminator_update,
    expert_logits,
    learned_reward,
    make_m_step,
)
from emgail_jax.method.networks import Discriminator
from emgail_jax.method.optim import Learner

LN3 = math.log(3.0)


def toy_apply(params, obs, actions, condition, intention_major=False):
    """f(s, a, c) = s_0 + a_0 + c . params: logits chosen by hand through the inputs."""
    return obs[..., 0] + actions[..., 0] + condition @ params


def log_sigmoid(x):
    return -np.log1p(np.exp(-np.asarray(x, np.float64)))


# condition 1 adds ln 3 to the logit
HAND_PARAMS = jnp.array([0.0, LN3])
HAND_BATCH = dict(
    # Expert pair 0: f = (0, ln 3) -> D = (1/2, 3/4); gamma = (1/2, 1/2).
    # Expert pair 1: f = (-ln 3, 0) -> D = (1/4, 1/2); gamma = (1, 0).
    expert_obs=jnp.array([[0.0], [-LN3]]),
    expert_actions=jnp.zeros((2, 1)),
    expert_weights=jnp.array([[0.5, 0.5], [1.0, 0.0]]),
    conditions=jnp.eye(2),
    # Policy samples, one per condition (intention-major [C, M, ...]):
    # under condition 0: f = -ln 3 -> -log(1 - 1/4) = log 4/3;
    # under condition 1: f = ln 3 -> -log(1 - 3/4) = log 4.
    policy_obs=jnp.array([[[-LN3]], [[0.0]]]),
    policy_actions=jnp.zeros((2, 1, 1)),
    policy_conditions=jnp.eye(2)[:, None, :],
)


def test_loss_hand_computed_values():
    loss, metrics = discriminator_loss(toy_apply, HAND_PARAMS, **HAND_BATCH)
    expert_term = ((0.5 * math.log(2) + 0.5 * math.log(4 / 3)) + math.log(4)) / 2
    policy_term = (math.log(4) + math.log(4 / 3)) / 2
    assert float(loss) == pytest.approx(expert_term + policy_term, rel=1e-6)
    assert float(metrics["discriminator/loss"]) == pytest.approx(float(loss))
    # E_gamma[D] on the expert pairs: (0.5 * 0.5 + 0.5 * 0.75, 0.25) -> mean 0.4375.
    assert float(metrics["discriminator/expert_d"]) == pytest.approx(0.4375, rel=1e-6)
    assert float(metrics["discriminator/policy_d"]) == pytest.approx(0.5, rel=1e-6)


@pytest.fixture(scope="module", params=[False, True], ids=["one-hot", "heads"])
def network_batch(request):
    """A real discriminator network (intention as a one-hot input, or one head per intention)
    and a random tiny batch with K = 3 intentions, policy samples intention-major [K, M]."""
    k, n, m = 3, 6, 3
    keys = jax.random.split(jax.random.PRNGKey(0), 6)
    net = Discriminator(hidden=(8,), heads=request.param)
    batch = dict(
        expert_obs=jax.random.normal(keys[0], (n, 4)),
        expert_actions=jax.random.normal(keys[1], (n, 2)),
        expert_weights=jax.nn.softmax(jax.random.normal(keys[2], (n, k))),
        conditions=jnp.eye(k),
        policy_obs=jax.random.normal(keys[3], (k, m, 4)),
        policy_actions=jax.random.normal(keys[4], (k, m, 2)),
        policy_conditions=jnp.broadcast_to(jnp.eye(k)[:, None, :], (k, m, k)),
    )
    params = net.init(
        keys[5], batch["policy_obs"], batch["policy_actions"], batch["policy_conditions"]
    )
    return net, params, batch


def test_expert_logits_score_every_pair_under_every_condition(network_batch):
    net, params, batch = network_batch
    logits = expert_logits(
        net.apply, params, batch["expert_obs"], batch["expert_actions"], batch["conditions"]
    )
    n, k = batch["expert_weights"].shape
    assert logits.shape == (n, k)
    for c in range(k):
        onehot = jnp.broadcast_to(jnp.eye(k)[c], (n, k))
        direct = net.apply(params, batch["expert_obs"], batch["expert_actions"], onehot)
        np.testing.assert_allclose(logits[:, c], direct, rtol=1e-5, atol=1e-6)


def test_loss_equals_written_out_formula(network_batch):
    net, params, batch = network_batch
    n, k = batch["expert_weights"].shape
    real = np.stack(
        [
            net.apply(
                params,
                batch["expert_obs"],
                batch["expert_actions"],
                jnp.broadcast_to(jnp.eye(k)[c], (n, k)),
            )
            for c in range(k)
        ],
        1,
    )
    fake = np.asarray(
        net.apply(params, batch["policy_obs"], batch["policy_actions"], batch["policy_conditions"])
    )
    gamma = np.asarray(batch["expert_weights"], np.float64)
    # -mean_n sum_k gamma_nk log sigma(f_nk) - mean_m log(1 - sigma(f_m))
    expected = -np.mean(np.sum(gamma * log_sigmoid(real), 1)) - np.mean(log_sigmoid(-fake))
    loss, _ = discriminator_loss(net.apply, params, **batch)
    assert float(loss) == pytest.approx(expected, rel=1e-5)
    jitted, _ = jax.jit(lambda p: discriminator_loss(net.apply, p, **batch))(params)
    assert float(jitted) == pytest.approx(float(loss), rel=1e-6)


def test_one_hot_gamma_reduces_to_per_intention_gail_losses(network_batch):
    net, params, batch = network_batch
    k = batch["conditions"].shape[0]
    # Two expert pairs per intention, three policy samples per intention.
    expert_labels = jnp.array([0, 1, 2, 2, 0, 1])
    one_hot = {**batch, "expert_weights": jax.nn.one_hot(expert_labels, k)}
    em_loss, _ = discriminator_loss(net.apply, params, **one_hot)
    # The intention-major fast path assumes all K intentions in order; intention i alone goes
    # through the general path (a head per row, selected by its one-hot condition).
    general_apply = lambda p, obs, act, cond, intention_major=False: net.apply(p, obs, act, cond)
    gail_losses = []
    for i in range(k):
        e, p = np.flatnonzero(expert_labels == i), slice(i, i + 1)
        # GAIL on intention i alone: D(s, a) := D(s, a, i), every pair weighted one.
        gail_loss, _ = discriminator_loss(
            general_apply,
            params,
            expert_obs=batch["expert_obs"][e],
            expert_actions=batch["expert_actions"][e],
            expert_weights=jnp.ones((len(e), 1)),
            conditions=jnp.eye(k)[i : i + 1],
            policy_obs=batch["policy_obs"][p],
            policy_actions=batch["policy_actions"][p],
            policy_conditions=batch["policy_conditions"][p],
        )
        gail_losses.append(float(gail_loss))
    # Equal counts per intention: the EM-GAIL loss is the mean of the K GAIL losses.
    assert float(em_loss) == pytest.approx(np.mean(gail_losses), rel=1e-5)


def test_loss_finite_at_extreme_logits():
    params = jnp.array([0.0])
    huge = jnp.array([[100.0], [-100.0]])
    loss, _ = discriminator_loss(
        toy_apply,
        params,
        expert_obs=huge,
        expert_actions=jnp.zeros((2, 1)),
        expert_weights=jnp.ones((2, 1)),
        conditions=jnp.ones((1, 1)),
        policy_obs=huge[None],
        policy_actions=jnp.zeros((1, 2, 1)),
        policy_conditions=jnp.ones((1, 2, 1)),
    )
    # Expert: softplus(-100) + softplus(100) ~ 100, halved; policy: the same.
    assert float(loss) == pytest.approx(100.0, rel=1e-4)


def test_update_reduces_loss_and_reports_first_step_metrics(network_batch):
    net, params, batch = network_batch
    optimizer = optax.adam(1e-2)
    update = jax.jit(lambda p: discriminator_update(net.apply, optimizer, p, 20, **batch))
    trained, metrics = update(Learner.create(params, optimizer))
    new_params = trained.params
    before, _ = discriminator_loss(net.apply, params, **batch)
    after, _ = discriminator_loss(net.apply, new_params, **batch)
    # The metrics describe the parameters before the update.
    assert float(metrics["discriminator/loss"]) == pytest.approx(float(before), rel=1e-5)
    assert float(after) < float(before) - 0.05


@pytest.mark.parametrize("algo", ["emgail", "infogail", "gail"])
def test_m_step_trains_on_the_algorithms_weights_and_conditions(algo, random_batch):
    """The M-step is discriminator_update on the batch with what the algorithm chooses: EM-GAIL
    weights each expert pair by gamma under every intention, the baselines by one."""
    m_step_case(algo, random_batch)


def m_step_case(algo, random_batch, hook_of=None, discriminator=Discriminator):
    """Checks the M-step of ``algo`` against discriminator_update; ``hook_of(batch, weights)
    -> (batch, loss hook)`` adds a variant's hook (None: the paper's loss). Returns the
    M-step's metrics."""
    k, m, n = 3, 4, 6
    algorithm = make_algorithm(algo)
    batch = random_batch(k, m, n, obs_dim=4, act_dim=2, seed=2)
    gamma = jax.nn.softmax(jax.random.normal(jax.random.PRNGKey(4), (n, k)))
    weights = gamma if algo == "emgail" else jnp.ones((n, 1))
    hook = None
    if hook_of is not None:
        batch, hook = hook_of(batch, weights)
    net = discriminator(hidden=(8,), heads=True)
    own = jnp.broadcast_to(jnp.arange(k)[:, None], (k, m))
    conditions = algorithm.discriminator_condition(own, k)
    params = net.init(jax.random.PRNGKey(3), batch.obs, batch.executed, conditions)
    optimizer = optax.adam(1e-2)
    start = Learner.create(params, optimizer)
    m_step = make_m_step(net.apply, optimizer, MStepConfig(steps=5))
    result = m_step(start, batch, gamma, algorithm, hook=hook)
    expected, expected_metrics = discriminator_update(
        net.apply,
        optimizer,
        start,
        5,
        expert_obs=batch.expert_obs,
        expert_actions=batch.expert_actions,
        expert_weights=weights,
        conditions=jnp.eye(k) if algo == "emgail" else jnp.zeros((1, 0)),
        policy_obs=batch.obs,
        policy_actions=batch.executed,
        policy_conditions=conditions,
        hook=hook,
    )
    for got, want in zip(
        jax.tree.leaves(result.discriminator), jax.tree.leaves(expected), strict=True
    ):
        np.testing.assert_allclose(got, want, rtol=1e-6)
    assert float(result.metrics["discriminator/loss"]) == pytest.approx(
        float(expected_metrics["discriminator/loss"]), rel=1e-6
    )
    return result.metrics


@pytest.mark.parametrize("algo", ["emgail", "infogail", "gail"])
def test_learned_reward_is_the_algorithms_pseudo_reward_of_the_own_condition(algo):
    k, m = 2, 3
    algorithm = make_algorithm(algo, info_weight=0.5)
    obs = jnp.arange(k * m * 1.0).reshape(k, m, 1) / 10
    executed = jnp.full((k, m, 1), 0.2)
    intention = jnp.broadcast_to(jnp.arange(k)[:, None], (k, m))
    own_log_posterior = jnp.full((k, m), -0.7)
    params = jnp.array([0.3, -0.4]) if algorithm.conditional_discriminator else jnp.zeros(0)
    reward = learned_reward(
        toy_apply,
        params,
        algorithm,
        k,
        obs=obs,
        executed=executed,
        intention=intention,
        own_log_posterior=own_log_posterior,
    )
    logit = obs[..., 0] + executed[..., 0]
    if algorithm.conditional_discriminator:
        logit = logit + params[intention]
    expected = jax.nn.softplus(logit) + (0.5 * -0.7 if algo == "infogail" else 0.0)
    np.testing.assert_allclose(reward, expected, rtol=1e-6)
