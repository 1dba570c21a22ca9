"""Plain RL of one policy per intention (the experts' trainer and re-optimisation's)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from emgail_jax.host.seed_runner import chunks, run_chunks
from emgail_jax.method.config import RunConfig
from emgail_jax.method.rl import intention_chunk, make_rl_train

CONFIG = RunConfig().with_values(hidden=(8,), num_envs=2, rollout_length=10, value_epochs=1).method


@pytest.fixture(scope="module")
def trainer():
    return make_rl_train(CONFIG, envs.make("driver"), eval_episodes=1)


@pytest.fixture(scope="module")
def init(trainer):
    """``init(keys [I]) -> states [I]``, jitted once for the module's tests."""
    return jax.jit(jax.vmap(trainer.init))


@pytest.fixture(scope="module")
def chunk(trainer):
    """Two intentions' chunk, jitted once for the module's tests."""
    return intention_chunk(trainer, jnp.arange(2))


def test_one_seed_chunk_trains_every_intention_on_its_own_reward(init, chunk):
    # Chunks of 3, the length the other tests' chunks compile.
    k = 2
    states = init(jax.random.split(jax.random.PRNGKey(0), k))
    seen = []
    record = lambda first, length, states, metrics: seen.append((first, metrics)) or True
    states = run_chunks(chunk, states, chunks(0, 6, 3), lambda f, n: np.ones(n, bool), record)
    assert [first for first, _ in seen] == [0, 3]
    assert seen[0][1]["eval/returns"].shape == (3, k, k)  # [chunk, learned, true]
    # Each policy is scored on its own intention's reward.
    returns, own = seen[1][1]["eval/returns"], seen[1][1]["eval/own_return"]
    np.testing.assert_allclose(own, np.stack([returns[:, i, i] for i in range(k)], -1))
    assert np.asarray(states.iteration).tolist() == [6, 6]


def test_seeds_chunk_trains_each_row_on_its_own_reward_parameters(init, chunk):
    """Row s trains on reward_data[s]: a scale of 1 is the true reward (what intention_chunk
    trains on, bit for bit), a scale of -1 another reward and so another policy."""
    from emgail_jax.method.rl import seeds_chunk

    env = envs.make("driver")
    scaled = lambda obs, action, true, intention, scale: scale * jnp.take(true, intention, -1)
    rescaled = make_rl_train(CONFIG, env, scaled, eval_episodes=1)
    k = 2
    keys = jax.random.split(jax.random.PRNGKey(0), k)
    one = init(keys)
    both = jax.tree.map(lambda x: np.stack([x, x]), one)
    inputs = np.ones(3, bool)
    _, metrics = seeds_chunk(rescaled, jnp.arange(k))(both, inputs, jnp.array([1.0, -1.0]))
    _, expected = chunk(one, inputs)  # the true reward's (the trainer's)
    np.testing.assert_array_equal(metrics["eval/returns"][:, 0], expected["eval/returns"])
    # The first rollout is the same policy's: only the reward differs.
    np.testing.assert_allclose(metrics["train/reward"][0, 1], -expected["train/reward"][0], 1e-6)
    assert not np.array_equal(metrics["eval/returns"][-1, 1], expected["eval/returns"][-1])


def test_an_iteration_not_evaluating_trains_the_same_and_leaves_its_returns_nan(init, chunk):
    """Skipping the evaluation episodes changes nothing but the returns: the keys, the policies
    and the reward earned are those of a chunk that evaluates every iteration."""
    states = init(jax.random.split(jax.random.PRNGKey(0), 2))
    every, some = np.ones(3, bool), np.array([True, False, True])
    end_every, seen_every = chunk(states, every)
    end_some, seen_some = chunk(states, some)
    for a, b in zip(jax.tree.leaves(end_every), jax.tree.leaves(end_some), strict=True):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(seen_some["train/reward"], seen_every["train/reward"])
    returns = np.asarray(seen_some["eval/returns"])  # [3, K, K env]
    np.testing.assert_array_equal(returns[some], np.asarray(seen_every["eval/returns"])[some])
    assert np.isnan(returns[1]).all() and np.isfinite(returns[some]).all()
    assert np.isnan(seen_some["eval/own_return"][1]).all()


# A compile of its own; the chunk's test above (evaluating or not, per iteration) covers it.
@pytest.mark.slow
@pytest.mark.parametrize("jitted", [False, True])
def test_one_update_scores_the_new_policy_only_when_evaluating(trainer, jitted):
    update = jax.jit(trainer.update) if jitted else trainer.update
    state = trainer.init(jax.random.PRNGKey(0))
    _, scored = update(state, jnp.int32(0), None, True)
    _, skipped = update(state, jnp.int32(0), None, False)
    assert np.isfinite(scored["eval/returns"]).all() and np.isnan(skipped["eval/returns"]).all()
    np.testing.assert_array_equal(scored["train/reward"], skipped["train/reward"])


@pytest.mark.parametrize("jitted", [False, True])
def test_a_fall_is_paid_the_absorbing_reward_for_every_step_left(jitted):
    """Episodes of 10 steps, 2 envs, 4 steps each: env 0 falls after the step at t = 2 (7 steps
    left, paid -3 each), env 1 reaches no end; every sample is paid 1."""
    from emgail_jax.method.rl import reward_per_step
    from emgail_jax.method.rollout import Transitions

    batch = Transitions.zeros(4, 1, 2, 3, 1)
    time = jnp.array([[0.0, 0.6], [0.1, 0.7], [0.2, 0.8], [0.0, 0.9]])[:, None]  # [T, 1, B]
    batch = batch.replace(time=time, done=jnp.zeros((4, 1, 2)).at[2, 0, 0].set(1.0))
    rewards = jnp.ones((4, 1, 2))
    per_step = jax.jit(reward_per_step, static_argnums=2) if jitted else reward_per_step
    assert np.isclose(per_step(rewards, batch, 10), 1.0)  # no absorbing state: the mean
    paid = per_step(rewards, batch, 10, jnp.array([-3.0]))
    assert np.isclose(paid, (8 * 1.0 + 7 * -3.0) / (8 + 7))
    ended = batch.replace(done=batch.done.at[3, 0, 1].set(1.0))  # env 1's limit: no step left
    assert np.isclose(per_step(rewards, ended, 10, jnp.array([-3.0])), paid)
