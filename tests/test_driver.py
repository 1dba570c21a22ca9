"""The synthetic driver env (paper §5.1): dynamics, observations, paths, the analytic expert and
the options `envs.make` accepts."""

import itertools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from envs.driver import DriverEnv

STILL = {"init_position_noise": 0.0, "init_heading_noise": 0.0}


@pytest.fixture(scope="module")
def env2():
    return envs.make("driver", intentions=2)


def test_make_gives_a_driver_with_the_requested_intentions():
    env = envs.make("driver", intentions=3, radius=10.0)
    assert isinstance(env, DriverEnv)
    assert env.num_intentions == 3 and env.max_intentions == 4
    assert (env.observation_size, env.action_size, env.episode_length) == (10, 1, 100)
    assert env.options()["radius"] == 10.0


def test_reset_and_step_shapes_finite_and_jit(env2):
    state = env2.reset(jax.random.PRNGKey(0))
    assert state.obs.shape == (10,)
    assert state.reward.shape == (2,)
    assert state.done.shape == ()
    jit_reset = jax.jit(env2.reset)
    jit_step = jax.jit(env2.step)
    jitted = jit_reset(jax.random.PRNGKey(0))
    np.testing.assert_allclose(jitted.obs, state.obs, rtol=1e-6, atol=1e-7)
    action = jnp.array([0.3])
    eager_next, jit_next = env2.step(state, action), jit_step(jitted, action)
    for eager, jitted in zip(jax.tree.leaves(eager_next), jax.tree.leaves(jit_next), strict=True):
        np.testing.assert_allclose(eager, jitted, rtol=1e-5, atol=1e-6)
    assert eager_next.obs.shape == (10,) and eager_next.reward.shape == (2,)
    assert np.all(np.isfinite(eager_next.obs)) and np.all(np.isfinite(eager_next.reward))
    assert float(eager_next.done) == 0.0


def test_reset_history_extrapolated_along_initial_heading(env2):
    for seed in range(3):
        state = env2.reset(jax.random.PRNGKey(seed))
        heading = float(state.physics.heading)
        history = np.asarray(state.obs).reshape(5, 2)  # x, y at t-4 .. t
        np.testing.assert_allclose(history[-1], state.physics.history[-1])
        step = env2.speed * np.array([math.cos(heading), math.sin(heading)])
        # Equally spaced by one step of the car along the heading, oldest first.
        np.testing.assert_allclose(np.diff(history, axis=0), np.tile(step, (4, 1)), atol=1e-6)
        assert abs(heading) < 1.0 and np.linalg.norm(history[-1]) < 0.5  # small start noise


def test_step_hand_computed():
    env = envs.make("driver", intentions=3, **STILL)
    state = env.reset(jax.random.PRNGKey(0))
    # Noise off: at the origin heading +x, having come from (-0.4, 0).
    np.testing.assert_allclose(state.obs, [-0.4, 0, -0.3, 0, -0.2, 0, -0.1, 0, 0, 0], atol=1e-6)
    state = env.step(state, jnp.array([0.0]))
    # Straight on: (0.1, 0). Path 1 and its mirror path 3 are circles of radius 3.5 about
    # (0, +-3.5); path 2 a circle of radius 20 about (0, 20).
    np.testing.assert_allclose(state.obs[-2:], [0.1, 0.0], atol=1e-6)
    d1 = math.hypot(0.1, 3.5) - 3.5
    d2 = math.hypot(0.1, 20.0) - 20.0
    np.testing.assert_allclose(state.reward, [-d1, -d2, -d1], rtol=1e-3, atol=1e-6)
    # Half left: heading 0.5 * max_turn = 0.1 rad, then one step of 0.1 along it.
    state = env.step(state, jnp.array([0.5]))
    np.testing.assert_allclose(float(state.physics.heading), 0.1, rtol=1e-6)
    expected = [0.1 + 0.1 * math.cos(0.1), 0.1 * math.sin(0.1)]
    np.testing.assert_allclose(state.obs[-2:], expected, rtol=1e-5)
    np.testing.assert_allclose(state.obs[:-2], [-0.2, 0, -0.1, 0, 0, 0, 0.1, 0], atol=1e-6)


def test_actions_are_clipped():
    env = envs.make("driver", **STILL)
    state = env.reset(jax.random.PRNGKey(0))
    np.testing.assert_allclose(
        env.step(state, jnp.array([7.0])).obs, env.step(state, jnp.array([1.0])).obs
    )
    np.testing.assert_allclose(
        env.step(state, jnp.array([-3.0])).obs, env.step(state, jnp.array([-1.0])).obs
    )


def drive(env, intention, key, noisy):
    """One episode of the expert of ``intention``: per-step rewards [T, K], positions [T, 2]."""

    def body(state, step_key):
        if noisy:
            action = env.expert_policy(state, jnp.asarray(intention), step_key)
        else:
            action = env.expert_action(state, jnp.asarray(intention))
        state = env.step(state, action)
        return state, (state.reward, state.physics.history[-1])

    state = env.reset(key)
    _, (rewards, positions) = jax.lax.scan(body, state, jax.random.split(key, env.episode_length))
    return rewards, positions


@pytest.fixture(scope="module")
def expert_runs():
    env = envs.make("driver", intentions=4)
    run = jax.jit(jax.vmap(lambda i, key: drive(env, i, key, True)))
    keys = jax.random.split(jax.random.PRNGKey(3), 4)
    rewards, positions = run(jnp.arange(4), keys)
    return env, np.asarray(rewards), np.asarray(positions)  # [K, T, K], [K, T, 2]


def test_expert_stays_on_its_own_path(expert_runs):
    _, rewards, _ = expert_runs
    for k in range(4):
        distance = -rewards[k]  # [T, K] distance to every path
        assert distance[:, k].mean() < 0.1
        assert distance[:, k].max() < 0.2
        # Its return under its own reward is near the maximum, 0 (measured about -1.5 to -2) ...
        assert rewards[k, :, k].sum() > -5.0
        # ... and clearly worse under every other path's reward (measured -150 to -370).
        for j in range(4):
            if j != k:
                assert rewards[k, :, j].sum() < -100.0
                assert distance[:, j].mean() > 1.0


def test_expert_reaches_its_destination(expert_runs):
    env, _, positions = expert_runs
    destinations = env.destinations()
    for k in range(4):
        np.testing.assert_allclose(positions[k, -1], destinations[k], atol=0.2)


def test_paths_three_and_four_mirror_one_and_two():
    env = envs.make("driver", intentions=4, radius=8.0)
    np.testing.assert_allclose(env.curvatures, [1 / 3.5, 1 / 8.0, -1 / 3.5, -1 / 8.0], rtol=1e-6)
    mirror = np.array([1.0, -1.0])
    for k in (0, 1):
        np.testing.assert_allclose(env.path_points(k + 2), env.path_points(k) * mirror, atol=1e-9)
    destinations = env.destinations()
    np.testing.assert_allclose(destinations[2:], destinations[:2] * mirror, atol=1e-9)
    # The distance of a point to path 3 (4) is that of its mirror image to path 1 (2).
    points = jax.random.uniform(jax.random.PRNGKey(0), (20, 2), minval=-5.0, maxval=10.0)
    distances = jax.vmap(env.path_distances)(points)
    mirrored = jax.vmap(env.path_distances)(points * mirror)
    np.testing.assert_allclose(distances[:, 2:], mirrored[:, :2], rtol=1e-5, atol=1e-5)
    # With no start noise the noiseless expert of path 3 drives path 1's trajectory mirrored.
    still = envs.make("driver", intentions=4, radius=8.0, **STILL)
    key = jax.random.PRNGKey(0)
    run = jax.jit(jax.vmap(lambda i: drive(still, i, key, False)))
    _, positions = run(jnp.arange(4))
    np.testing.assert_allclose(positions[2], positions[0] * mirror, atol=1e-4)
    np.testing.assert_allclose(positions[3], positions[1] * mirror, atol=1e-4)


def test_three_paths_are_the_first_three_of_four():
    three, four = envs.make("driver", intentions=3), envs.make("driver", intentions=4)
    np.testing.assert_array_equal(three.curvatures, four.curvatures[:3])
    np.testing.assert_allclose(three.destinations(), four.destinations()[:3])


def test_lower_radius_moves_destination_two_towards_one():
    gaps = [
        np.linalg.norm(np.diff(envs.make("driver", radius=r).destinations(), axis=0))
        for r in (20.0, 10.0, 5.0, 3.5)
    ]
    assert all(a > b for a, b in itertools.pairwise(gaps))
    assert gaps[-1] == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize(
    ("name", "kwargs", "match"),
    [
        ("cart", {}, "unknown env 'cart'"),
        ("driver", {"intentions": 5}, "choose a number from 1 to 4"),
        ("driver", {"intentions": 0}, "choose a number from 1 to 4"),
        ("driver", {"raduis": 3.0}, "no option 'raduis'"),
        ("driver", {"radius": 0.4}, "speed/max_turn = 0.5"),
        ("driver", {"path1_radius": 0.1}, "tighter than the car can turn"),
        ("driver", {"radius": -1.0}, "radii must be positive"),
    ],
)
def test_make_errors(name, kwargs, match):
    with pytest.raises(envs.EnvError, match=match):
        envs.make(name, **kwargs)


def test_program_key_leaves_out_the_radii_which_are_data():
    """Radii only set the curvatures, which a program takes as data; any other option, K or a
    wrapper gives another program."""
    key = DriverEnv(2, radius=20.0).program_key()
    assert DriverEnv(2, radius=5.0, path1_radius=4.0).program_key() == key
    assert hash(key) == hash(DriverEnv(2, radius=7.0).program_key())
    assert DriverEnv(3).program_key() != key
    assert DriverEnv(2, speed=0.2).program_key() != key
    assert envs.wrap_for_training(DriverEnv(2)).program_key() != key
    assert DriverEnv(2, radius=5.0).data()["curvatures"][1] == pytest.approx(0.2)
