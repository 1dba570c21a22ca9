"""The trainer skeleton: its policy-side stages (acting, the rollout, the B-step on a given
reward) and one iteration of collect, normalise, reward, improve and evaluate, each the same
jitted and not."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct

import envs
from emgail_jax.method import normalizer as obs_norm
from emgail_jax.method.b_step import PolicySamples
from emgail_jax.method.batches import LearningBatch
from emgail_jax.method.config import RunConfig
from emgail_jax.method.gae import absorbing_value
from emgail_jax.method.networks import GaussianPolicy, ValueNet, policy_action
from emgail_jax.method.rollout import batch_reset, steps_left, time_major
from emgail_jax.method.skeleton import (
    PolicyStages,
    Rewarded,
    intention_rows,
    make_update,
    unconditioned,
)

pytestmark = pytest.mark.heavy

K, B, T = 2, 2, 5
CONFIG = (
    RunConfig()
    .with_values(num_envs=B, rollout_length=T, hidden=(4,), value_epochs=1, value_minibatches=1)
    .method
)


@struct.dataclass
class State:
    policy: object
    value: object
    normalizer: obs_norm.RunningStats
    env_state: envs.State
    key: jax.Array
    iteration: jax.Array
    extra: jax.Array  # a field only the reward stage changes


@pytest.fixture(scope="module")
def env():
    return envs.make("driver", intentions=K)


# Unconditioned stages' own compiles go to make test-slow: test_rl's chunks run them compiled
# (the RL trainer's policy is unconditioned), and one-hot stages check the same semantics here.
UNCONDITIONED = pytest.param("unconditioned", marks=pytest.mark.slow)


@pytest.fixture(scope="module", params=["one-hot", UNCONDITIONED])
def stages(request, env):
    config = CONFIG.resolved(env)
    if request.param == "unconditioned":
        condition = unconditioned
    else:
        condition = lambda intentions: jax.nn.one_hot(intentions, K)
    policy = GaussianPolicy(env.action_size, config.networks.hidden, heads=False)
    return PolicyStages.create(policy, ValueNet(config.networks.hidden), condition, config, env)


@pytest.fixture(scope="module")
def state(env, stages):
    keys = jax.random.split(jax.random.PRNGKey(0), 4)
    policy, value = stages.init(keys[0], keys[1])
    return State(
        policy=policy,
        value=value,
        normalizer=obs_norm.RunningStats.create(env.observation_size),
        env_state=batch_reset(envs.wrap_for_training(env), keys[2], (K, B)),
        key=keys[3],
        iteration=jnp.zeros((), jnp.int32),
        extra=jnp.zeros(()),
    )


def assert_trees_close(a, b):
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        np.testing.assert_allclose(x, y, rtol=1e-5, atol=1e-6)


def test_intention_rows_number_the_leading_axis():
    np.testing.assert_array_equal(intention_rows((2, 3)), [[0, 0, 0], [1, 1, 1]])
    assert intention_rows((3,)).tolist() == [0, 1, 2]
    assert intention_rows(()).shape == ()
    assert unconditioned(intention_rows((2, 3))).shape == (2, 3, 0)


@pytest.mark.parametrize("jit", [False, True])
def test_acting_takes_the_mean_unless_exploring(stages, state, jit):
    obs = jax.random.normal(jax.random.PRNGKey(1), (K, B, state.normalizer.mean.shape[0]))
    key = jax.random.PRNGKey(2)
    wrap = jax.jit if jit else (lambda f: f)
    act = lambda explore: wrap(stages.acting(state.policy, state.normalizer, explore))
    condition = stages.condition(intention_rows((K, B)))
    mean = policy_action(
        stages.policy,
        state.policy,
        state.normalizer,
        obs,
        condition,
        obs_clip=CONFIG.networks.obs_clip,
    )
    np.testing.assert_allclose(act(False)(obs, None), mean, rtol=1e-6)
    np.testing.assert_allclose(act(jnp.asarray(False))(obs, key), mean, rtol=1e-6)
    explored = act(True)(obs, key)
    assert not np.allclose(explored, mean)
    np.testing.assert_allclose(act(jnp.asarray(True))(obs, key), explored, rtol=1e-6)


@pytest.fixture(scope="module")
def collect(env, stages):
    """``collect(state, key) -> (env_state, transitions)``: a rollout of ``state``'s policy."""
    train_env = envs.wrap_for_training(env)

    def collect(state, key):
        policy = stages.acting(state.policy, state.normalizer, explore=True)
        return stages.collect(train_env, policy, state.env_state, key)

    return collect


@pytest.fixture(scope="module")
def jitted(collect, stages):
    """The stages jitted once for the module's tests (each jit of them is a compile)."""
    return {
        "collect": jax.jit(collect),
        "improve": jax.jit(stages.improve),
        "b_step": jax.jit(stages.b_step),
    }


def test_collect_is_the_same_jitted_and_not(env, collect, jitted, state):
    eager = collect(state, jax.random.PRNGKey(3))
    got = jitted["collect"](state, jax.random.PRNGKey(3))
    assert got[1].obs.shape == (T, K, B, env.observation_size)
    assert_trees_close(eager, got)


@pytest.fixture(scope="module")
def rollout(jitted, state):
    return jitted["collect"](state, jax.random.PRNGKey(4))


def _policy_samples(stages, batch, normalizer) -> PolicySamples:
    """``batch`` as the B-step reads it, written out."""
    return PolicySamples.of(
        batch,
        lambda x: obs_norm.normalize(normalizer, x, CONFIG.networks.obs_clip),
        time_major(stages.condition(intention_rows((K, T * B))), T),
        stages.condition(intention_rows((K, B))),
    )


# Op by op, TRPO and the value fit take about half a minute.
@pytest.mark.parametrize("jit", [pytest.param(False, marks=pytest.mark.slow), True])
def test_improve_is_the_b_step_on_the_normalised_rollout(env, stages, jitted, state, rollout, jit):
    end, transitions = rollout
    batch = LearningBatch.of(transitions, end, env.episode_length)
    normalizer = obs_norm.update(state.normalizer, transitions.obs)
    reward = transitions.true_reward[..., 0]
    key = jax.random.PRNGKey(5)
    improve = jitted["improve"] if jit else stages.improve
    got = improve(state, batch, normalizer, reward, key)
    samples = _policy_samples(stages, batch, normalizer)
    want = jitted["b_step"](state.policy, state.value, samples, reward, key)
    assert_trees_close((got.policy, got.value), (want.policy, want.value))


def test_improve_bootstraps_a_termination_with_the_absorbing_states_value(
    env, stages, jitted, state, rollout
):
    """Row k's absorbing reward, for every step its episode has left to the time limit."""
    end, transitions = rollout
    transitions = transitions.replace(done=transitions.done.at[2].set(1.0))  # all end at t = 2
    batch = LearningBatch.of(transitions, end, env.episode_length)
    normalizer = obs_norm.update(state.normalizer, transitions.obs)
    reward, key = transitions.true_reward[..., 0], jax.random.PRNGKey(5)
    absorbing = jnp.array([-2.0, 3.0])
    got = jitted["improve"](state, batch, normalizer, reward, key, absorbing)
    left = steps_left(batch.time, env.episode_length)
    np.testing.assert_array_equal(left[:, 0, 0], env.episode_length - 1 - np.arange(T))
    end_values = absorbing_value(absorbing[:, None], left, CONFIG.b_step.gamma)
    samples = _policy_samples(stages, batch, normalizer)
    b_step = jitted["b_step"]
    want = b_step(state.policy, state.value, samples, reward, key, end_values)
    assert_trees_close((got.policy, got.value), (want.policy, want.value))
    without = b_step(state.policy, state.value, samples, reward, key)
    pairs = zip(jax.tree.leaves(got.value), jax.tree.leaves(without.value), strict=True)
    assert any(not np.allclose(a, b) for a, b in pairs)


def make_toy_update(env, stages):
    """The skeleton with the true reward of each row's intention times its ``scale`` argument
    as its reward stage (which also sets ``extra``) and an evaluation that reads the improved
    state."""
    train_env = envs.wrap_for_training(env)

    def collect(state, key, scale):
        policy = stages.acting(state.policy, state.normalizer, explore=True)
        return (*stages.collect(train_env, policy, state.env_state, key), {"collected": scale})

    def reward(state, transitions, normalizer, scale):
        own = jnp.take_along_axis(
            transitions.true_reward, intention_rows((K, B))[None, ..., None], -1
        )
        rewards = scale * own[..., 0]
        return Rewarded(rewards, {"extra": normalizer.count}, {"reward": rewards.mean()})

    def evaluate(state, key, scale):
        return {"evaluated": state.iteration, "key": key}

    return make_update(stages, collect, reward, evaluate)


def test_one_iteration_runs_every_stage_in_order(env, stages, state):
    update = jax.jit(make_toy_update(env, stages))
    new, metrics = update(state, jnp.float32(2.0))
    keys = jax.random.split(state.key, 4)
    np.testing.assert_array_equal(new.key, keys[0])
    np.testing.assert_array_equal(metrics["key"], keys[3])
    assert int(new.iteration) == 1 and int(metrics["evaluated"]) == 1
    # The rollout joined the statistics, and the reward stage saw them (and set `extra`).
    assert float(new.normalizer.count) == float(new.extra) == T * K * B
    assert float(metrics["collected"]) == 2.0
    np.testing.assert_array_equal(new.env_state.info["steps"], np.full((K, B), T))
    assert {"reward", "policy/kl", "value/loss"} <= set(metrics)
    # The reward stage's reward is what the B-step improves on (the same program, negated).
    negated, _ = update(state, jnp.float32(-2.0))
    pairs = zip(jax.tree.leaves(new.policy), jax.tree.leaves(negated.policy), strict=True)
    assert any(not np.allclose(a, b) for a, b in pairs)


@pytest.mark.slow  # op-by-op execution of a whole iteration
def test_one_iteration_is_the_same_jitted_and_not(env, stages, state):
    update = make_toy_update(env, stages)
    assert_trees_close(update(state, jnp.float32(1.0)), jax.jit(update)(state, jnp.float32(1.0)))
