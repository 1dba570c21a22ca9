"""An IRL problem: env, demonstrations (generated, or from a --demos file) and ERD's random
reference."""

import dataclasses

import jax
import numpy as np
import pytest

import envs
from emgail_jax.host import demonstration_files
from emgail_jax.host.demonstration_files import DemonstrationError
from emgail_jax.host.problem import (
    DRIVER_DEMO_EPISODES,
    default_demos,
    make_problem,
    shipped_demos_path,
)
from emgail_jax.method import demonstrations
from emgail_jax.method.demonstrations import Demonstrations


@pytest.fixture(scope="module")
def driver():
    return make_problem("driver", 2)


@pytest.fixture(scope="module")
def demos_file(driver, tmp_path_factory):
    """The driver problem's demonstrations saved as a --demos file."""
    path = str(tmp_path_factory.mktemp("demos") / "driver.npz")
    demonstration_files.save(driver.demos, path)
    return path


def test_driver_problem_has_500_pairs_per_intention(driver):
    assert driver.num_intentions == driver.env.num_intentions == 2
    assert driver.env.name == "driver"
    assert len(driver.demos) == 2 * DRIVER_DEMO_EPISODES * driver.env.episode_length == 1000
    np.testing.assert_array_equal(np.bincount(driver.demos.intentions), [500, 500])
    assert driver.demos.expert_returns.shape == (2,)
    assert "generated" in driver.demos_source and "seed 0" in driver.demos_source


def test_driver_demos_are_the_noisy_expert_with_the_demo_seed(driver):
    env = driver.env
    again = demonstrations.generate(
        env, env.expert_policy, DRIVER_DEMO_EPISODES, jax.random.PRNGKey(0)
    )
    np.testing.assert_array_equal(driver.demos.observations, again.observations)
    np.testing.assert_array_equal(driver.demos.actions, again.actions)


def test_random_returns_are_far_below_the_expert_returns(driver):
    random_returns = np.asarray(driver.random_returns)
    assert random_returns.shape == (2,)
    assert np.all(np.isfinite(random_returns))
    assert np.all(driver.demos.expert_returns > random_returns + 50)
    # Minus a distance summed over 100 steps: negative, and the expert stays close to 0.
    assert np.all(random_returns < -50) and np.all(driver.demos.expert_returns > -10)


def test_demos_file_round_trip(driver, demos_file):
    problem = make_problem("driver", None, demos_file)
    assert problem.num_intentions == 2  # from the file's labels
    assert problem.demos_source == demos_file
    for field in ("observations", "actions", "episode_starts", "intentions", "expert_returns"):
        np.testing.assert_array_equal(getattr(problem.demos, field), getattr(driver.demos, field))


def _relabelled_copy(demos, label, k):
    """The pairs of intention 0, labelled ``label``, appended (a ``k``-intention dataset)."""
    keep = demos.intentions == 0
    returns = np.concatenate([demos.expert_returns, np.full(k - 2, -1.0, np.float32)])
    return Demonstrations(
        observations=np.concatenate([demos.observations, demos.observations[keep]]),
        actions=np.concatenate([demos.actions, demos.actions[keep]]),
        episode_starts=np.concatenate([demos.episode_starts, demos.episode_starts[keep]]),
        intentions=np.concatenate([demos.intentions, np.full(keep.sum(), label, np.int32)]),
        expert_returns=returns,
    )


def test_a_file_with_more_intentions_gives_the_first_k(driver, tmp_path):
    path = str(tmp_path / "three.npz")
    demonstration_files.save(_relabelled_copy(driver.demos, 2, 3), path)
    problem = make_problem("driver", 2, path)
    assert problem.num_intentions == 2
    np.testing.assert_array_equal(problem.demos.observations, driver.demos.observations)
    np.testing.assert_array_equal(problem.demos.intentions, driver.demos.intentions)
    np.testing.assert_array_equal(problem.demos.expert_returns, driver.demos.expert_returns)
    # Same env and seed: the random reference does not depend on where the demos came from.
    np.testing.assert_allclose(problem.random_returns, driver.random_returns, rtol=1e-6)
    assert make_problem("driver", None, path).num_intentions == 3


def test_more_intentions_than_the_file_holds_are_learned_and_the_true_ones_scored(demos_file):
    problem = make_problem("driver", 3, demos_file)
    assert problem.num_intentions == 3 and problem.true_intentions == 2
    assert problem.demos.num_intentions == 2
    assert problem.random_returns.shape == (2,) and np.all(np.isfinite(problem.random_returns))


def test_zero_intentions_with_a_demos_file_is_rejected(demos_file):
    with pytest.raises(envs.EnvError, match="choose a number from 1 to 4"):
        make_problem("driver", 0, demos_file)


def test_zero_intentions_without_a_demos_file_is_rejected():
    with pytest.raises(envs.EnvError, match="choose a number from 1 to 4"):
        make_problem("driver", 0)


def test_env_options_reach_the_env(demos_file):
    problem = make_problem("driver", 2, demos_file, {"radius": 10.0})
    assert problem.env.radius == 10.0
    with pytest.raises(envs.EnvError, match="has no option 'nope'"):
        make_problem("driver", 2, demos_file, {"nope": 1})


def test_an_unlabelled_file_is_accepted(driver, tmp_path):
    path = str(tmp_path / "bare.npz")
    d = driver.demos
    demonstration_files.save(Demonstrations(d.observations, d.actions, d.episode_starts), path)
    problem = make_problem("driver", 2, path)
    assert problem.demos.intentions is None and problem.demos.expert_returns is None
    assert len(problem.demos) == 1000


def test_actions_outside_the_range_are_clipped_as_the_env_executes_them(driver, tmp_path):
    """A --demos file may hold raw actions (e.g. a policy's unclipped means); the problem holds
    what the env executed, clipped to its action range."""
    raw = np.where(np.arange(len(driver.demos))[:, None] % 2 == 0, 3.0, -0.5).astype(np.float32)
    path = str(tmp_path / "raw.npz")
    demos = dataclasses.replace(driver.demos, actions=raw)
    demonstration_files.save(demos, path)
    problem = make_problem("driver", demo_sources=path)
    np.testing.assert_array_equal(problem.demos.actions, np.clip(raw, -1.0, 1.0))
    assert problem.demos.actions.dtype == np.float32
    # The file itself is left as it is.
    np.testing.assert_array_equal(demonstration_files.load(path).actions, raw)


@pytest.mark.parametrize("env_name", ["swimmer", "hopper", "halfcheetah", "reacher"])
def test_shipped_demonstrations_hold_executed_actions(env_name):
    demos = demonstration_files.load(shipped_demos_path(env_name))
    assert np.abs(demos.actions).max() <= 1.0


def test_unknown_env_is_an_env_error():
    with pytest.raises(envs.EnvError, match="unknown env 'nope'"):
        make_problem("nope", 2)


class _Unshipped(envs.Env):
    """An env for which the package ships no demonstrations."""

    name = "unshipped"
    intention_names = ("a", "b")
    observation_size = 1
    action_size = 1
    episode_length = 5

    def reset(self, key):
        raise NotImplementedError

    def step(self, state, action):
        raise NotImplementedError


def test_default_demos_without_shipped_data_says_how_to_make_them():
    assert shipped_demos_path("unshipped").endswith("emgail_jax/data/unshipped.npz")
    with pytest.raises(DemonstrationError) as error:
        default_demos(_Unshipped())
    message = str(error.value)
    assert "no demonstrations ship for env 'unshipped'" in message
    assert "--demos FILE" in message
    assert "python -m emgail_jax.experts --env unshipped" in message
    assert "\n" not in message
