"""The env registry over every registered env: construction, sizes and its error messages."""

import pytest

import envs

ALL = envs.names()


def test_every_paper_env_is_registered():
    assert {"driver", "swimmer", "hopper", "halfcheetah", "reacher"} <= set(ALL)


# Intentions an env gets by default: all of them, except the driver's paper setting of 2 paths.
DEFAULT_K = {"driver": 2}


@pytest.mark.parametrize("name", ALL)
def test_make_defaults(name):
    env = envs.make(name)
    assert env.name == name
    assert env.max_intentions == len(env.intention_names)
    assert env.num_intentions == DEFAULT_K.get(name, env.max_intentions)
    assert env.observation_size > 0 and env.action_size > 0 and env.episode_length > 0
    assert isinstance(env.options(), dict)


@pytest.mark.parametrize("name", ALL)
def test_make_selects_the_first_k_intentions(name):
    assert envs.make(name, intentions=1).num_intentions == 1


@pytest.mark.parametrize("name", ALL)
@pytest.mark.parametrize("offset", [1, 5])
def test_too_many_intentions_is_an_env_error(name, offset):
    max_k = len(envs.env_class(name).intention_names)
    with pytest.raises(envs.EnvError, match=rf"'{name}' has {max_k} intentions.*1 to {max_k}"):
        envs.make(name, intentions=max_k + offset)


@pytest.mark.parametrize("name", ALL)
def test_zero_intentions_is_an_env_error(name):
    with pytest.raises(envs.EnvError, match="choose a number from 1"):
        envs.make(name, intentions=0)


def test_unknown_env_is_an_env_error_listing_the_names():
    with pytest.raises(envs.EnvError, match="unknown env 'walker'.*" + ".*".join(ALL)):
        envs.make("walker")


@pytest.mark.parametrize("name", ALL)
def test_unknown_option_is_an_env_error(name):
    with pytest.raises(envs.EnvError, match=f"env '{name}' has no option 'bogus'"):
        envs.make(name, bogus=1)


@pytest.mark.parametrize(
    "name,obs,act,k,length",
    [
        ("swimmer", 8, 2, 2, 500),
        ("hopper", 11, 3, 3, 500),
        ("halfcheetah", 17, 6, 3, 500),
        ("reacher", 26, 2, 4, 50),
    ],
)
def test_mjx_env_sizes_follow_the_design_table(name, obs, act, k, length):
    env = envs.make(name)
    assert (env.observation_size, env.action_size, env.max_intentions) == (obs, act, k)
    assert env.episode_length == length


@pytest.mark.parametrize("name", ["swimmer", "hopper", "halfcheetah", "reacher"])
def test_bad_solver_settings_are_env_errors(name):
    with pytest.raises(envs.EnvError, match="must be >= 1"):
        envs.make(name, solver_iterations=0)
