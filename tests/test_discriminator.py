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
    absorbing_reward,
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


def toy_absorbing_apply(params, obs, actions, condition, intention_major=False, absorbed=None):
    """``toy_apply`` whose absorbing indicator adds ln 3 to the logit (0 for real pairs)."""
    return toy_apply(params, obs, actions, condition) + LN3 * (
        0.0 if absorbed is None else absorbed
    )


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


@pytest.mark.parametrize("absorbing", [False, True])
@pytest.mark.parametrize("algo", ["emgail", "infogail", "gail"])
def test_m_step_trains_on_the_algorithms_weights_and_conditions(algo, absorbing, random_batch):
    """The M-step is discriminator_update on the batch with what the algorithm chooses: EM-GAIL
    weights each expert pair by gamma under every intention, the baselines by one. With
    termination flags, the absorbing pair is real with the summed weights of the demonstrations
    that ended in a termination, and fake once for each terminated policy transition."""
    k, m, n = 3, 4, 6
    algorithm = make_algorithm(algo)
    batch = random_batch(k, m, n, obs_dim=4, act_dim=2, seed=2)
    gamma = jax.nn.softmax(jax.random.normal(jax.random.PRNGKey(4), (n, k)))
    weights = gamma if algo == "emgail" else jnp.ones((n, 1))
    absorbed = {}
    if absorbing:
        terminal = jnp.zeros((k, m)).at[0, 1].set(1.0).at[0, 3].set(1.0).at[2, 0].set(1.0)
        expert_terminal = jnp.zeros(n).at[2].set(1.0).at[5].set(1.0)
        batch = batch.replace(terminal=terminal, expert_terminal=expert_terminal)
        absorbed = dict(
            expert_absorbed=weights[2] + weights[5], policy_absorbed=jnp.array([2.0, 0.0, 1.0])
        )
    net = Discriminator(hidden=(8,), heads=True, absorbing=absorbing)
    own = jnp.broadcast_to(jnp.arange(k)[:, None], (k, m))
    conditions = algorithm.discriminator_condition(own, k)
    params = net.init(jax.random.PRNGKey(3), batch.obs, batch.executed, conditions)
    optimizer = optax.adam(1e-2)
    start = Learner.create(params, optimizer)
    result = make_m_step(net.apply, optimizer, MStepConfig(steps=5))(start, batch, gamma, algorithm)
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
        **absorbed,
    )
    for got, want in zip(
        jax.tree.leaves(result.discriminator), jax.tree.leaves(expected), strict=True
    ):
        np.testing.assert_allclose(got, want, rtol=1e-6)
    assert float(result.metrics["discriminator/loss"]) == pytest.approx(
        float(expected_metrics["discriminator/loss"]), rel=1e-6
    )
    assert ("discriminator/absorbing_d" in result.metrics) == absorbing


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


def test_gradient_penalty_hand_computed_on_a_linear_logit():
    """toy_apply's logit has slope 1 in s_0 and in a_0: a squared input-gradient norm of 2 on
    every expert pair (under every condition, weights summing to one) and policy sample."""
    from emgail_jax.method.discriminator import input_gradient_norms

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
    assert float(input_gradient_norms(toy_apply, params, **batch)) == pytest.approx(2.0)
    plain, metrics = discriminator_loss(toy_apply, params, **batch)
    penalised, penalised_metrics = discriminator_loss(
        toy_apply, params, **batch, gradient_penalty=0.5
    )
    assert float(penalised) == pytest.approx(float(plain) + 1.0)
    assert "discriminator/gradient_norm" not in metrics
    assert float(penalised_metrics["discriminator/gradient_norm"]) == pytest.approx(2.0)


@pytest.mark.parametrize("jit", [False, True])
def test_a_delayed_gradient_penalty_weighs_nothing_before_its_iteration(jit):
    from emgail_jax.method.config import MStepConfig
    from emgail_jax.method.discriminator import gradient_penalty_at

    delayed = MStepConfig(gradient_penalty=10.0, gradient_penalty_from=3)
    weight_at = lambda i: gradient_penalty_at(delayed, i)
    weights = [float((jax.jit(weight_at) if jit else weight_at)(jnp.int32(i))) for i in range(5)]
    assert weights == [0.0, 0.0, 0.0, 10.0, 10.0]
    # Undelayed, or without an iteration, the weight stays the config's plain number.
    assert gradient_penalty_at(MStepConfig(gradient_penalty=10.0), jnp.int32(0)) == 10.0
    assert gradient_penalty_at(delayed, None) == 10.0


def test_gradient_penalty_flattens_the_trained_logit(network_batch):
    from emgail_jax.method.discriminator import input_gradient_norms

    net, params, batch = network_batch
    optimizer = optax.adam(1e-2)
    norms = {}
    for weight in (0.0, 1.0):
        fit = lambda p, w=weight: discriminator_update(
            net.apply, optimizer, p, 100, **batch, gradient_penalty=w
        )
        trained, _ = jax.jit(fit)(Learner.create(params, optimizer))
        norms[weight] = float(input_gradient_norms(net.apply, trained.params, **batch))
    assert norms[1.0] < 0.5 * norms[0.0]


@pytest.mark.parametrize("jit", [False, True])
def test_absorbing_pairs_hand_computed_one_sample_per_termination(jit):
    """The batch above with absorbing pairs: the indicator adds ln 3, so the absorbing logit
    is (ln 3, 2 ln 3) under the two conditions (D = 3/4, 9/10). One demonstration ended in a
    termination with gamma (1/2, 1/2): one real sample more; row 0's policy terminated twice:
    two fake samples more, none in row 1."""
    absorbed = dict(expert_absorbed=jnp.array([0.5, 0.5]), policy_absorbed=jnp.array([2.0, 0.0]))
    loss_of = lambda p: discriminator_loss(toy_absorbing_apply, p, **HAND_BATCH, **absorbed)
    loss, metrics = (jax.jit(loss_of) if jit else loss_of)(HAND_PARAMS)
    # -log D of the absorbing pair: log 4/3, log 10/9; -log(1 - D) under row 0: log 4.
    real = 0.5 * math.log(2) + 0.5 * math.log(4 / 3) + math.log(4)
    expert_term = (real + 0.5 * math.log(4 / 3) + 0.5 * math.log(10 / 9)) / 3
    policy_term = (math.log(4 / 3) + math.log(4) + 2 * math.log(4)) / 4
    assert float(loss) == pytest.approx(expert_term + policy_term, rel=1e-6)
    assert float(metrics["discriminator/absorbing_d"]) == pytest.approx(0.825, rel=1e-6)
    assert float(metrics["discriminator/policy_d"]) == pytest.approx(0.5, rel=1e-6)
    # No termination on either side: the loss without absorbing pairs, to the bit.
    none = dict(expert_absorbed=jnp.zeros(2), policy_absorbed=jnp.zeros(2))
    without, _ = discriminator_loss(toy_absorbing_apply, HAND_PARAMS, **HAND_BATCH, **none)
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
