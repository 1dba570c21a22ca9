"""The four networks: shapes with and without an intention condition, initialisation, and the
policy's action distribution against the diagonal-Gaussian formula."""

import copy
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from emgail_jax.method.networks import (
    MLP,
    AIRLDiscriminator,
    Discriminator,
    GaussianPolicy,
    Posterior,
    ValueNet,
    action_distribution,
    policy_action,
)
from emgail_jax.method.normalizer import RunningStats, normalize

N, OBS, ACT, K = 7, 5, 3, 2
HIDDEN = (8,)


@pytest.fixture(scope="module")
def inputs():
    keys = jax.random.split(jax.random.PRNGKey(0), 4)
    obs = jax.random.normal(keys[0], (N, OBS))
    action = jax.random.uniform(keys[1], (N, ACT), minval=-1.0, maxval=1.0)
    one_hot = jax.nn.one_hot(jax.random.randint(keys[2], (N,), 0, K), K)
    time = jax.random.uniform(keys[3], (N,))
    return obs, action, one_hot, time


def _first_kernel(params):
    return params["params"]["MLP_0"]["Dense_0"]["kernel"]


@pytest.mark.parametrize("conditioned", [True, False], ids=["one-hot", "empty"])
def test_output_shapes_with_and_without_a_condition(inputs, conditioned):
    obs, action, one_hot, time = inputs
    condition = one_hot if conditioned else jnp.zeros((N, 0))
    width = K if conditioned else 0
    key = jax.random.PRNGKey(1)

    policy = GaussianPolicy(ACT, HIDDEN, init_log_std=-0.5)
    params = policy.init(key, obs, condition)
    mean, log_std = policy.apply(params, obs, condition)
    assert mean.shape == log_std.shape == (N, ACT)
    assert _first_kernel(params).shape == (OBS + width, HIDDEN[0])

    value = ValueNet(HIDDEN)
    params = value.init(key, obs, condition, time)
    assert value.apply(params, obs, condition, time).shape == (N,)
    # The normalised time is one more input.
    assert _first_kernel(params).shape == (OBS + width + 1, HIDDEN[0])

    discriminator = Discriminator(HIDDEN)
    params = discriminator.init(key, obs, action, condition)
    assert discriminator.apply(params, obs, action, condition).shape == (N,)
    assert _first_kernel(params).shape == (OBS + ACT + width, HIDDEN[0])


@pytest.mark.parametrize("heads", [False, True])
def test_an_absorbing_discriminator_has_one_input_more_zero_for_real_pairs(inputs, heads):
    """The absorbing indicator is one input more, after the pair's; without its row of the
    first kernel the network is the discriminator without it, on which a real pair reads 0."""
    obs, action, one_hot, _ = inputs
    key = jax.random.PRNGKey(1)
    plain, absorbing = Discriminator(HIDDEN, heads), Discriminator(HIDDEN, heads, absorbing=True)
    params = absorbing.init(key, obs, action, one_hot)
    first = params["params"]["heads" if heads else "MLP_0"]["Dense_0"]
    without = copy.deepcopy(params)
    layer = without["params"]["heads" if heads else "MLP_0"]["Dense_0"]
    layer["kernel"] = jnp.delete(first["kernel"], OBS + ACT, axis=-2)
    expected = jax.eval_shape(plain.init, key, obs, action, one_hot)
    assert jax.tree.map(jnp.shape, without) == jax.tree.map(jnp.shape, expected)
    real = absorbing.apply(params, obs, action, one_hot)
    np.testing.assert_allclose(real, plain.apply(without, obs, action, one_hot), atol=1e-6)
    zero = absorbing.apply(params, obs, action, one_hot, absorbed=jnp.zeros(N))
    np.testing.assert_array_equal(real, zero)
    flagged = absorbing.apply(params, obs, action, one_hot, absorbed=jnp.ones(N))
    assert not np.allclose(flagged, real)


def test_posterior_gives_k_logits(inputs):
    obs, action, _, _ = inputs
    posterior = Posterior(num_intentions=3, hidden=HIDDEN)
    params = posterior.init(jax.random.PRNGKey(2), obs, action)
    logits = posterior.apply(params, obs, action)
    assert logits.shape == (N, 3)
    assert np.all(np.isfinite(logits))
    # Not a constant: different pairs get different posteriors.
    assert np.ptp(np.asarray(logits[:, 0])) > 0


def test_networks_accept_extra_leading_batch_axes(inputs):
    obs, _, one_hot, time = inputs
    policy = GaussianPolicy(ACT, HIDDEN)
    params = policy.init(jax.random.PRNGKey(3), obs, one_hot)
    # A rollout's [T, K, B, D] observations.
    obs4 = jnp.broadcast_to(obs[:4], (2, 3, 4, OBS))
    cond4 = jnp.broadcast_to(one_hot[:4], (2, 3, 4, K))
    mean, log_std = policy.apply(params, obs4, cond4)
    assert mean.shape == log_std.shape == (2, 3, 4, ACT)
    # Same maths; a different batch shape may round the last bit differently.
    np.testing.assert_allclose(
        mean[1, 2], policy.apply(params, obs[:4], one_hot[:4])[0], rtol=1e-5, atol=1e-7
    )
    value = ValueNet(HIDDEN)
    vparams = value.init(jax.random.PRNGKey(4), obs, one_hot, time)
    assert value.apply(vparams, obs4, cond4, jnp.zeros((2, 3, 4))).shape == (2, 3, 4)


@pytest.mark.parametrize("init_log_std", [0.0, -0.5, 0.7])
def test_initial_log_std_is_init_log_std_everywhere(inputs, init_log_std):
    obs, _, one_hot, _ = inputs
    policy = GaussianPolicy(ACT, HIDDEN, init_log_std=init_log_std)
    params = policy.init(jax.random.PRNGKey(5), obs, one_hot)
    np.testing.assert_allclose(params["params"]["log_std"], np.full(ACT, init_log_std), rtol=1e-6)
    _, log_std = policy.apply(params, obs, one_hot)
    np.testing.assert_allclose(log_std, np.full((N, ACT), init_log_std))


def test_log_std_is_state_independent_and_trainable(inputs):
    obs, _, one_hot, _ = inputs
    policy = GaussianPolicy(ACT, HIDDEN)
    params = policy.init(jax.random.PRNGKey(6), obs, one_hot)
    params["params"]["log_std"] = jnp.array([-1.0, 0.0, 2.0])
    _, log_std = policy.apply(params, obs, one_hot)
    np.testing.assert_array_equal(log_std, np.tile([-1.0, 0.0, 2.0], (N, 1)))


def test_final_layer_is_final_scale_times_a_lecun_normal_layer(inputs):
    """Same key: the hidden layers are identical and the last kernel is exactly ``final_scale``
    times the LeCun-normal one (zero bias), so the outputs scale by the same factor."""
    obs, _, _, _ = inputs
    key = jax.random.PRNGKey(7)
    small, normal = MLP(HIDDEN, 4, final_scale=0.01), MLP(HIDDEN, 4, final_scale=1.0)
    p_small, p_normal = small.init(key, obs), normal.init(key, obs)
    np.testing.assert_array_equal(
        p_small["params"]["Dense_0"]["kernel"], p_normal["params"]["Dense_0"]["kernel"]
    )
    np.testing.assert_allclose(
        p_small["params"]["Dense_1"]["kernel"],
        0.01 * p_normal["params"]["Dense_1"]["kernel"],
        rtol=1e-5,
    )
    np.testing.assert_array_equal(p_small["params"]["Dense_1"]["bias"], np.zeros(4))
    np.testing.assert_allclose(
        small.apply(p_small, obs), 0.01 * normal.apply(p_normal, obs), rtol=1e-4, atol=1e-8
    )


def test_final_layer_standard_deviation_is_final_scale_over_sqrt_fan_in():
    fan_in, out = 256, 64
    x = jnp.zeros((1, 3))
    for scale in (0.01, 1.0):
        params = MLP((fan_in,), out, final_scale=scale).init(jax.random.PRNGKey(8), x)
        kernel = np.asarray(params["params"]["Dense_1"]["kernel"])
        assert kernel.shape == (fan_in, out)
        # 16384 draws: the sample std is within a few percent of the target.
        assert kernel.std() == pytest.approx(scale / math.sqrt(fan_in), rel=0.05)
        assert abs(kernel.mean()) < 0.05 * scale / math.sqrt(fan_in)


def test_initial_policy_means_are_near_zero_but_not_the_other_heads(inputs):
    """The policy's last layer starts small (means ~ 0: the first actions are the log-std's
    exploration noise around zero); value, discriminator and posterior start normal-sized."""
    obs, action, one_hot, time = inputs
    obs = 3.0 * obs
    key = jax.random.PRNGKey(9)
    policy = GaussianPolicy(ACT, (64, 64))
    mean, _ = policy.apply(policy.init(key, obs, one_hot), obs, one_hot)
    assert np.max(np.abs(mean)) < 0.05
    assert np.max(np.abs(mean)) > 0  # not zero either: the means depend on the input
    posterior = Posterior(K, (64, 64))
    logits = posterior.apply(posterior.init(key, obs, action), obs, action)
    assert np.max(np.abs(logits)) > 0.1
    value = ValueNet((64, 64))
    values = value.apply(value.init(key, obs, one_hot, time), obs, one_hot, time)
    assert np.max(np.abs(values)) > 0.1


def test_the_condition_and_the_time_change_the_outputs(inputs):
    obs, action, _, time = inputs
    first = jax.nn.one_hot(jnp.zeros(N, jnp.int32), K)
    second = jax.nn.one_hot(jnp.ones(N, jnp.int32), K)
    key = jax.random.PRNGKey(10)
    policy = GaussianPolicy(ACT, HIDDEN)
    params = policy.init(key, obs, first)
    assert not np.allclose(
        policy.apply(params, obs, first)[0], policy.apply(params, obs, second)[0]
    )
    value = ValueNet(HIDDEN)
    params = value.init(key, obs, first, time)
    assert not np.allclose(
        value.apply(params, obs, first, time), value.apply(params, obs, first, 0 * time)
    )
    discriminator = Discriminator(HIDDEN)
    params = discriminator.init(key, obs, action, first)
    assert not np.allclose(
        discriminator.apply(params, obs, action, first),
        discriminator.apply(params, obs, action, second),
    )


def _gaussian_log_prob(x, mean, log_std):
    """log N(x; mean, diag(exp(log_std)^2)), written out."""
    z = (x - mean) / np.exp(log_std)
    d = x.shape[-1]
    return -0.5 * np.sum(z**2, -1) - np.sum(log_std, -1) - 0.5 * d * np.log(2 * np.pi)


def test_action_distribution_log_prob_is_the_diagonal_gaussian_formula():
    rng = np.random.default_rng(0)
    mean = rng.normal(size=(N, ACT)).astype(np.float32)
    log_std = rng.normal(scale=0.5, size=(N, ACT)).astype(np.float32)
    x = rng.normal(size=(N, ACT)).astype(np.float32)
    dist = action_distribution(jnp.asarray(mean), jnp.asarray(log_std))
    log_prob = np.asarray(dist.log_prob(jnp.asarray(x)))
    assert log_prob.shape == (N,)
    np.testing.assert_allclose(log_prob, _gaussian_log_prob(x, mean, log_std), rtol=1e-5)
    # At the mean with unit std in one dimension: log N(0; 0, 1) = -log(2 pi) / 2.
    unit = action_distribution(jnp.zeros((1, 1)), jnp.zeros((1, 1)))
    assert float(unit.log_prob(jnp.zeros((1, 1)))[0]) == pytest.approx(-0.5 * math.log(2 * math.pi))
    # Entropy of a diagonal Gaussian: sum(log_std) + d/2 (1 + log 2 pi).
    entropy = log_std.sum(-1) + 0.5 * ACT * (1 + np.log(2 * np.pi))
    np.testing.assert_allclose(dist.entropy(), entropy, rtol=1e-5)


def test_action_distribution_samples_have_the_given_mean_and_std():
    mean = jnp.array([0.5, -2.0])
    log_std = jnp.log(jnp.array([0.1, 2.0]))
    samples = action_distribution(mean, log_std).sample(
        seed=jax.random.PRNGKey(11), sample_shape=(20000,)
    )
    assert samples.shape == (20000, 2)
    np.testing.assert_allclose(samples.mean(0), [0.5, -2.0], atol=0.05)
    np.testing.assert_allclose(samples.std(0), [0.1, 2.0], rtol=0.03)


def _heads_networks():
    """The three intention-conditioned networks with one head per intention, and how to call
    each on ``(obs, action, condition, time)``."""
    return {
        "policy": (
            GaussianPolicy(ACT, HIDDEN, heads=True),
            lambda obs, act, c, t, **kw: (obs, c),
        ),
        "value": (ValueNet(HIDDEN, heads=True), lambda obs, act, c, t, **kw: (obs, c, t)),
        "discriminator": (
            Discriminator(HIDDEN, heads=True),
            lambda obs, act, c, t, **kw: (obs, act, c),
        ),
    }


def _output(net, params, args, **kwargs):
    out = net.apply(params, *args, **kwargs)
    return out[0] if isinstance(out, tuple) else out


@pytest.mark.parametrize("name", ["policy", "value", "discriminator"])
def test_heads_share_nothing_between_intentions(inputs, name):
    """With one head per intention, changing the parameters of head 1 changes the outputs of
    intention 1's rows only; the heads are stacked on a leading K axis."""
    obs, action, one_hot, time = inputs
    net, args = _heads_networks()[name]
    params = net.init(jax.random.PRNGKey(12), *args(obs, action, one_hot, time))
    kernel = params["params"]["heads"]["Dense_0"]["kernel"]
    assert kernel.shape[0] == K
    assert "MLP_0" not in params["params"]
    out = _output(net, params, args(obs, action, one_hot, time))
    bumped = jax.tree_util.tree_map_with_path(
        lambda path, x: x.at[1].add(0.5) if "heads" in jax.tree_util.keystr(path) else x, params
    )
    changed = np.abs(np.asarray(_output(net, bumped, args(obs, action, one_hot, time)) - out))
    changed = changed.reshape(N, -1).max(-1)
    rows_of_1 = np.asarray(one_hot[:, 1]) > 0
    assert np.all(changed[~rows_of_1] == 0) and np.all(changed[rows_of_1] > 0)


@pytest.mark.parametrize("heads", [False, True], ids=["one-hot", "heads"])
@pytest.mark.parametrize("name", ["policy", "value", "discriminator"])
def test_intention_major_inputs_give_the_general_outputs(inputs, name, heads):
    """``intention_major=True`` (row k of ``[K, M]`` inputs is intention k; head k runs on row k
    only) computes what the general path computes from the one-hot conditions."""
    obs, action, _, time = inputs
    net, args = _heads_networks()[name]
    net = net.clone(heads=heads)
    grouped = lambda x: jnp.broadcast_to(x, (K, *x.shape))  # every sample under each intention
    condition = jnp.broadcast_to(jnp.eye(K)[:, None, :], (K, N, K))
    grouped_args = args(grouped(obs), grouped(action), condition, grouped(time))
    params = net.init(jax.random.PRNGKey(13), *grouped_args)
    general = _output(net, params, grouped_args)
    major = _output(net, params, grouped_args, intention_major=True)
    np.testing.assert_allclose(major, general, rtol=1e-5, atol=1e-6)
    # The condition broadcasts: [K, 1, K] is enough in the intention-major layout.
    slim = args(grouped(obs), grouped(action), jnp.eye(K)[:, None, :], grouped(time))
    np.testing.assert_allclose(
        _output(net, params, slim, intention_major=True), general, rtol=1e-5, atol=1e-6
    )


def test_policy_action_is_the_mean_unless_exploring():
    policy = GaussianPolicy(action_size=2, hidden=(8,), init_log_std=-1.0)
    obs = jnp.array([[1.0, 2.0, 3.0], [0.5, -1.0, 2.0]])
    condition = jnp.zeros((2, 0))
    params = policy.init(jax.random.PRNGKey(0), obs, condition)
    stats = RunningStats(mean=jnp.array([1.0, 0.0, 0.0]), var=jnp.full(3, 4.0), count=jnp.ones(()))
    mean, log_std = policy.apply(params, normalize(stats, obs, 5.0), condition)
    key = jax.random.PRNGKey(1)
    np.testing.assert_array_equal(
        policy_action(policy, params, stats, obs, condition, obs_clip=5.0), mean
    )
    quiet = policy_action(
        policy, params, stats, obs, condition, obs_clip=5.0, key=key, explore=False
    )
    np.testing.assert_array_equal(quiet, mean)
    sample = policy_action(
        policy, params, stats, obs, condition, obs_clip=5.0, key=key, explore=True
    )
    np.testing.assert_allclose(sample, mean + jnp.exp(log_std) * jax.random.normal(key, (2, 2)))
    # The same draw as the action distribution's own sampler, so that either may be used.
    np.testing.assert_array_equal(sample, action_distribution(mean, log_std).sample(seed=key))


def _airl(heads: bool):
    net = AIRLDiscriminator(HIDDEN, heads, discount=0.9)
    obs = jnp.zeros((1, OBS))
    params = net.init(jax.random.PRNGKey(0), obs, jnp.zeros((1, OBS + 1)), jnp.eye(K)[:1])
    shaping = lambda p, o, c, **kw: net.apply(p, o, c, method=lambda m, *a: m.shaping_net(*a))
    return net, params, shaping


@pytest.mark.parametrize("heads", [False, True])
@pytest.mark.parametrize("jit", [False, True])
def test_airl_f_is_reward_plus_discounted_shaping_difference(heads, jit):
    """f(s, s', i) = g_i(s) + 0.9 h_i(s') - h_i(s), and h(s') is dropped (h(s') = 0) where
    the transition terminated."""
    net, params, shaping = _airl(heads)
    keys = jax.random.split(jax.random.PRNGKey(1), 3)
    obs, next_obs = jax.random.normal(keys[0], (N, OBS)), jax.random.normal(keys[1], (N, OBS))
    going_on = (jnp.arange(N) % 2).astype(jnp.float32)  # even rows terminated
    condition = jax.nn.one_hot(jnp.arange(N) % K, K)
    f_of = lambda p: net.apply(
        p, obs, jnp.concatenate([next_obs, going_on[:, None]], -1), condition
    )
    f = (jax.jit(f_of) if jit else f_of)(params)
    g = net.apply(params, obs, condition, method="reward")
    h, h_next = shaping(params, obs, condition), shaping(params, next_obs, condition)
    np.testing.assert_allclose(f, g + 0.9 * going_on * h_next - h, rtol=1e-5, atol=1e-6)
    assert np.all(np.isfinite(h_next)) and float(jnp.abs(h_next).max()) > 0
    # g and h are two networks of the state alone, each conditioned on the intention.
    assert set(params["params"]) == {"reward_net", "shaping_net"}
    other = jax.nn.one_hot((jnp.arange(N) + 1) % K, K)
    assert not np.allclose(g, net.apply(params, obs, other, method="reward"))


def test_airl_intention_major_rows_use_their_own_heads():
    net, params, _ = _airl(True)
    obs = jax.random.normal(jax.random.PRNGKey(2), (K, N, OBS))
    follows = jnp.concatenate([obs[..., ::-1], jnp.ones((K, N, 1))], -1)
    rows = jnp.broadcast_to(jnp.eye(K)[:, None, :], (K, N, K))
    major = net.apply(params, obs, follows, rows, intention_major=True)
    np.testing.assert_allclose(major, net.apply(params, obs, follows, rows), rtol=1e-5)


def test_airl_continuation_flag_has_no_input_gradient():
    """The flag is data: the gradient penalty reads d f / d(s, s') alone."""
    net, params, _ = _airl(True)
    follows = jnp.ones((N, OBS + 1))
    total = lambda x: net.apply(params, jnp.ones((N, OBS)), x, jnp.eye(K)[jnp.arange(N) % K]).sum()
    grad = jax.grad(total)(follows)
    assert float(jnp.abs(grad[:, -1]).max()) == 0.0 and float(jnp.abs(grad[:, :-1]).max()) > 0
