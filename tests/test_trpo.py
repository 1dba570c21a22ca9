"""TRPO: conjugate gradient, the Fisher-vector product, and the trust-region step."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.flatten_util import ravel_pytree

from emgail_jax.method import trpo
from emgail_jax.method.networks import GaussianPolicy, action_distribution

pytestmark = pytest.mark.heavy

OBS, COND, ACT, N = 3, 2, 2, 6
CONFIG = trpo.TRPOConfig()


def random_spd(rng, n, low=1.0, high=3.0):
    q, _ = np.linalg.qr(rng.normal(size=(n, n)))
    return (q * rng.uniform(low, high, size=n)) @ q.T


# ---- conjugate gradient ---------------------------------------------------------------------


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_conjugate_gradient_matches_dense_solve(seed):
    rng = np.random.default_rng(seed)
    a = random_spd(rng, 8).astype(np.float32)
    b = rng.normal(size=8).astype(np.float32)
    x = trpo.conjugate_gradient(lambda v: jnp.asarray(a) @ v, jnp.asarray(b), 10)
    np.testing.assert_allclose(x, np.linalg.solve(a, b), rtol=1e-4, atol=1e-5)


def test_conjugate_gradient_few_iterations_on_diagonal_system():
    # A = diag(1, 2), b = (1, 1), x0 = 0. One step: r = d = b, alpha = |r|^2 / (d.A d) = 2 / 3,
    # x1 = (2/3, 2/3). Two steps solve a 2-D system exactly: x = (1, 1/2).
    a = jnp.diag(jnp.array([1.0, 2.0]))
    b = jnp.array([1.0, 1.0])
    np.testing.assert_allclose(trpo.conjugate_gradient(lambda v: a @ v, b, 1), [2 / 3, 2 / 3])
    np.testing.assert_allclose(trpo.conjugate_gradient(lambda v: a @ v, b, 2), [1.0, 0.5])


def test_conjugate_gradient_zero_rhs_returns_zero_not_nan():
    a = jnp.asarray(random_spd(np.random.default_rng(3), 8), jnp.float32)
    x = trpo.conjugate_gradient(lambda v: a @ v, jnp.zeros(8), 10)
    assert np.all(np.isfinite(x))
    np.testing.assert_array_equal(x, np.zeros(8))


def test_conjugate_gradient_more_iterations_than_dimension_stays_finite():
    a = jnp.diag(jnp.array([1.0, 4.0, 9.0]))
    b = jnp.array([1.0, 4.0, 9.0])
    x = jax.jit(lambda b: trpo.conjugate_gradient(lambda v: a @ v, b, 25))(b)
    np.testing.assert_allclose(x, [1.0, 1.0, 1.0], rtol=1e-5)


# ---- a tiny Gaussian policy -----------------------------------------------------------------

policy = GaussianPolicy(action_size=ACT, hidden=(4,), init_log_std=-0.5)


def make_problem(key, n=N, action_size=ACT):
    net = GaussianPolicy(action_size=action_size, hidden=(4,), init_log_std=-0.5)
    key_init, key_obs, key_cond, key_act = jax.random.split(key, 4)
    obs = jax.random.normal(key_obs, (n, OBS))
    cond = jax.nn.one_hot(jax.random.randint(key_cond, (n,), 0, COND), COND)
    params = net.init(key_init, obs, cond)
    # Move the last layer away from its near-zero initialisation so the mean depends on obs.
    params = jax.tree.map(lambda p: p + 0.3 * jax.random.normal(key_init, p.shape), params)
    distribution = lambda p: action_distribution(*net.apply(p, obs, cond))
    actions = distribution(params).sample(seed=key_act)
    return net, params, obs, cond, distribution, actions


def gaussian_kl(mean_p, log_std_p, mean_q, log_std_q):
    """KL(p || q) of diagonal Gaussians, summed over the action dims, in float64 numpy."""
    mean_p, log_std_p, mean_q, log_std_q = (
        np.asarray(x, np.float64) for x in (mean_p, log_std_p, mean_q, log_std_q)
    )
    var_p, var_q = np.exp(2 * log_std_p), np.exp(2 * log_std_q)
    return np.sum(log_std_q - log_std_p + (var_p + (mean_p - mean_q) ** 2) / (2 * var_q) - 0.5, -1)


@pytest.fixture(scope="module")
def fisher_problem():
    _, params, obs, cond, distribution, _ = make_problem(jax.random.PRNGKey(0))
    flat, unravel = ravel_pytree(params)
    old = distribution(params)
    mean_kl = lambda theta: jnp.mean(old.kl_divergence(distribution(unravel(theta))))
    return flat, unravel, obs, cond, mean_kl


def analytic_fisher(flat, unravel, obs, cond):
    """E_n[J_mu^T diag(1 / sigma^2) J_mu + J_logstd^T diag(2) J_logstd] for a diagonal Gaussian
    (the Fisher information of its mean and log-std parameters, chained through the network)."""
    mean_fn = lambda theta: policy.apply(unravel(theta), obs, cond)[0]
    log_std_fn = lambda theta: policy.apply(unravel(theta), obs, cond)[1]
    j_mean = np.asarray(jax.jit(jax.jacobian(mean_fn))(flat), np.float64)  # [N, A, P]
    j_log_std = np.asarray(jax.jit(jax.jacobian(log_std_fn))(flat), np.float64)
    inv_var = np.exp(-2 * np.asarray(log_std_fn(flat), np.float64))  # [N, A]
    fisher = np.einsum("nap,na,naq->pq", j_mean, inv_var, j_mean)
    fisher += 2.0 * np.einsum("nap,naq->pq", j_log_std, j_log_std)
    return fisher / obs.shape[0]


@pytest.fixture(scope="module")
def dense_fisher(fisher_problem):
    flat, unravel, obs, cond, _ = fisher_problem
    return analytic_fisher(flat, unravel, obs, cond)


def test_fisher_vector_product_matches_dense_fisher(fisher_problem, dense_fisher):
    flat, _, _, _, mean_kl = fisher_problem
    fisher = dense_fisher
    # Jitted: op by op, the Hessian compiles every primitive it runs.
    hessian = np.asarray(jax.jit(jax.hessian(mean_kl))(flat), np.float64)
    # The Hessian of the mean KL at the old parameters is the Fisher matrix.
    np.testing.assert_allclose(hessian, fisher, rtol=1e-3, atol=1e-5)
    rng = np.random.default_rng(0)
    # One program for every damping: the damping is an argument, not a constant of the program.
    damped = jax.jit(lambda v, damping: trpo.fisher_vector_product(mean_kl, flat, damping)(v))
    for damping in (0.0, 0.1):
        for _ in range(3):
            v = rng.normal(size=flat.shape).astype(np.float32)
            expected = fisher @ v + damping * v
            product = damped(jnp.asarray(v), jnp.float32(damping))
            np.testing.assert_allclose(product, expected, rtol=1e-3, atol=1e-4)


def test_cg_on_fisher_vector_product_matches_dense_solve(fisher_problem, dense_fisher):
    flat, _, _, _, mean_kl = fisher_problem
    damping = 0.1
    fisher = dense_fisher + damping * np.eye(flat.shape[0])
    b = np.random.default_rng(1).normal(size=flat.shape)
    x = trpo.conjugate_gradient(
        trpo.fisher_vector_product(mean_kl, flat, damping), jnp.asarray(b, jnp.float32), 60
    )
    np.testing.assert_allclose(x, np.linalg.solve(fisher, b), rtol=2e-2, atol=2e-2)


# ---- the TRPO step --------------------------------------------------------------------------


def _kl_between(net, old_params, new_params, obs, cond):
    old_mean, old_log_std = net.apply(old_params, obs, cond)
    new_mean, new_log_std = net.apply(new_params, obs, cond)
    return gaussian_kl(old_mean, old_log_std, new_mean, new_log_std).mean()


@pytest.fixture(
    scope="module",
    params=[
        trpo.TRPOConfig(max_kl=0.01),
        # A large trust region and little damping: the quadratic KL model overshoots, so the
        # line search has to backtrack.
        trpo.TRPOConfig(max_kl=0.5, cg_damping=1e-3),
    ],
    ids=["default", "backtracking"],
)
def random_steps(request):
    """TRPO steps on 24 random tiny problems with random advantages, compiled once."""
    config = request.param

    def one(key):
        key_problem, key_adv = jax.random.split(key)
        _, params, obs, cond, distribution, actions = make_problem(key_problem, n=16)
        advantages = jax.random.normal(key_adv, (16,))
        new_params, metrics = trpo.trpo_step(distribution, params, actions, advantages, config)
        return params, new_params, obs, cond, metrics

    keys = jax.random.split(jax.random.PRNGKey(42), 24)
    return config, jax.jit(jax.vmap(one))(keys)


def test_accepted_step_never_exceeds_max_kl(random_steps):
    config, (params, new_params, obs, cond, metrics) = random_steps
    net = GaussianPolicy(action_size=ACT, hidden=(4,))
    kls = []
    for i in range(obs.shape[0]):
        pick = lambda tree, i=i: jax.tree.map(lambda x: x[i], tree)
        kl = _kl_between(net, pick(params), pick(new_params), obs[i], cond[i])
        kls.append(kl)
        assert kl <= config.max_kl * (1 + 1e-3), f"problem {i}: KL {kl} > {config.max_kl}"
        np.testing.assert_allclose(metrics["policy/kl"][i], kl, rtol=1e-2, atol=1e-6)
    accepted = np.asarray(metrics["policy/accepted"])
    # Not vacuous: most problems take a step and the bound is active for some of them.
    assert accepted.mean() >= 0.75
    assert max(kls) > 0.5 * config.max_kl
    if config.max_kl > 0.1:
        assert np.min(metrics["policy/step_fraction"]) < 1.0  # the line search did backtrack
    # A rejected step leaves the parameters exactly where they were.
    for i in np.flatnonzero(accepted == 0):
        for a, b in zip(jax.tree.leaves(params), jax.tree.leaves(new_params), strict=True):
            np.testing.assert_array_equal(a[i], b[i])


def test_accepted_step_improves_the_surrogate(random_steps):
    _, (_, _, _, _, metrics) = random_steps
    accepted = np.asarray(metrics["policy/accepted"]) == 1
    assert np.all(np.asarray(metrics["policy/surrogate_improvement"])[accepted] > 0)
    assert np.all(np.asarray(metrics["policy/step_fraction"])[~accepted] == 0)


@pytest.fixture(scope="module")
def toy_step():
    """Advantages +1 for actions above the mean and -1 below: the mean should move up."""
    net, params, obs, cond, distribution, actions = make_problem(
        jax.random.PRNGKey(7), n=64, action_size=1
    )
    mean, _ = net.apply(params, obs, cond)
    advantages = jnp.sign(actions - mean)[:, 0]
    step = lambda p, a, adv: trpo.trpo_step(distribution, p, a, adv, CONFIG)
    return net, params, obs, cond, distribution, actions, advantages, step


def test_toy_problem_improves_surrogate_and_moves_mean_up(toy_step):
    net, params, obs, cond, distribution, actions, advantages, step = toy_step
    new_params, metrics = jax.jit(step)(params, actions, advantages)
    assert float(metrics["policy/accepted"]) == 1.0

    def surrogate(p):
        ratio = jnp.exp(distribution(p).log_prob(actions) - distribution(params).log_prob(actions))
        return float(jnp.mean(ratio * advantages))

    improvement = surrogate(new_params) - surrogate(params)
    assert improvement > 0
    np.testing.assert_allclose(metrics["policy/surrogate_improvement"], improvement, rtol=1e-3)
    old_mean, _ = net.apply(params, obs, cond)
    new_mean, _ = net.apply(new_params, obs, cond)
    shift = np.asarray(new_mean - old_mean)[:, 0]
    assert np.all(shift > 0), shift
    assert _kl_between(net, params, new_params, obs, cond) <= CONFIG.max_kl * (1 + 1e-3)


def test_zero_advantages_take_no_step(toy_step):
    _, params, _, _, _, actions, advantages, step = toy_step
    new_params, metrics = jax.jit(step)(params, actions, jnp.zeros_like(advantages))
    assert float(metrics["policy/accepted"]) == 0.0
    assert float(metrics["policy/step_fraction"]) == 0.0
    for a, b in zip(jax.tree.leaves(params), jax.tree.leaves(new_params), strict=True):
        np.testing.assert_array_equal(a, b)
    assert all(np.isfinite(float(v)) for v in metrics.values())


def test_jit_matches_eager(toy_step):
    _, params, _, _, _, actions, advantages, step = toy_step
    eager_params, eager_metrics = step(params, actions, advantages)
    jit_params, jit_metrics = jax.jit(step)(params, actions, advantages)
    for a, b in zip(jax.tree.leaves(eager_params), jax.tree.leaves(jit_params), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-6)
    for name in eager_metrics:
        np.testing.assert_allclose(eager_metrics[name], jit_metrics[name], rtol=1e-3, atol=1e-6)
