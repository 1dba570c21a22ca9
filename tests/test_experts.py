"""Experts: the training/checkpoint round trip (on the cheap driver) and the shipped experts and
demonstrations of the MJX envs (their files, and a fresh replay of every expert)."""

import dataclasses
import json
import os
import pathlib

import jax
import numpy as np
import pytest

import envs
from emgail_jax import experts
from emgail_jax.host import demonstration_files
from emgail_jax.host.problem import shipped_demos_path
from emgail_jax.method import demonstrations

pytestmark = pytest.mark.heavy

MJX_ENVS = ("swimmer", "hopper", "halfcheetah", "reacher")
TINY = experts.ExpertSpec(iterations=2, num_envs=2, rollout_length=20, demo_episodes=2)


@pytest.fixture(scope="module")
def driver_experts(tmp_path_factory):
    env = envs.make("driver", intentions=4)  # all, as the command trains them
    trained, own_returns, _ = experts.train(env, TINY, 2, jax.random.PRNGKey(0), progress=False)
    root = str(tmp_path_factory.mktemp("experts"))
    experts.save(env.name, trained, {"env": env.name}, root)
    return env, trained, own_returns, root


@pytest.mark.slow  # end to end (make test-slow); cheaper tests cover its parts
def test_training_keeps_the_best_seed_of_every_intention(driver_experts):
    _, trained, own_returns, _ = driver_experts
    assert own_returns.shape == (2, TINY.iterations, 4)  # [seeds, iterations, K]
    leaves = jax.tree.leaves(trained)
    assert leaves and all(leaf.shape[0] == 4 for leaf in leaves)


def test_checkpoint_round_trip_and_first_k(driver_experts):
    env, trained, _, root = driver_experts
    restored = experts.load(env, root, TINY)
    for a, b in zip(jax.tree.leaves(trained), jax.tree.leaves(restored), strict=True):
        np.testing.assert_array_equal(a, b)
    one = experts.load(envs.make("driver", intentions=1), root, TINY)
    assert all(leaf.shape[0] == 1 for leaf in jax.tree.leaves(one))


def test_policy_picks_each_rows_intention(driver_experts):
    env, trained, _, _ = driver_experts
    policy = experts.make_policy(env, trained, TINY)
    obs = jax.random.normal(jax.random.PRNGKey(1), (3, env.observation_size))
    own = [policy(obs, np.full(3, i)) for i in range(2)]  # of intentions 0 and 1 of 4
    mixed = policy(obs, np.array([0, 1, 0]))
    np.testing.assert_allclose(mixed, np.stack([own[0][0], own[1][1], own[0][2]]), rtol=1e-6)
    assert not np.allclose(own[0], own[1])


def test_missing_checkpoint_is_a_one_line_error(tmp_path, capsys):
    with pytest.raises(experts.ExpertError, match=r"python -m emgail_jax\.experts --env swimmer"):
        experts.load(envs.make("swimmer"), str(tmp_path))
    assert experts.main(["--env", "swimmer", "--evaluate", "--out", str(tmp_path)]) == 2
    error = capsys.readouterr().err.strip()
    assert error.startswith("error: no experts for 'swimmer'") and "\n" not in error


def test_retraining_an_unknown_intention_is_a_one_line_error(tmp_path, capsys):
    args = ["--env", "swimmer", "--only", "sideways", "--out", str(tmp_path)]
    assert experts.main(args) == 2
    error = capsys.readouterr().err.strip()
    assert error == (
        "error: 'swimmer' has no intention sideways; its intentions are forward, backward"
    )


def test_retraining_keeps_the_other_intentions_rows():
    old = np.arange(8.0).reshape(4, 2)
    merged = experts._replace_rows(old, np.array([[-1.0, -1.0]]), [2])
    np.testing.assert_array_equal(merged, [[0, 1], [2, 3], [-1, -1], [6, 7]])
    assert old[2, 0] == 4.0  # the kept experts are not modified in place


def test_corrupt_checkpoint_is_a_one_line_error(driver_experts, tmp_path):
    env = driver_experts[0]
    params = os.path.join(experts.checkpoint_dir(env.name, str(tmp_path)), "params")
    os.makedirs(params)
    with open(os.path.join(params, "_METADATA"), "w") as f:
        f.write("not a checkpoint")
    with pytest.raises(experts.ExpertError, match="cannot be read"):
        experts.load(env, str(tmp_path), TINY)


@pytest.mark.parametrize("name", MJX_ENVS)
def test_shipped_demonstrations_match_their_env(name):
    env = envs.make(name)
    spec = experts.SPECS[name]
    demos = demonstration_files.load(shipped_demos_path(name), env)
    assert demos.num_intentions == env.max_intentions
    counts = np.bincount(demos.intentions, minlength=env.max_intentions)
    full = spec.demo_episodes * env.episode_length  # 2500 (reacher 1500) unless an expert fell
    assert np.all(counts <= full) and np.all(counts >= 0.9 * full), counts
    assert demos.episode_starts.sum() == spec.demo_episodes * env.max_intentions
    assert demos.expert_returns.shape == (env.max_intentions,)
    # Every env's file carries what a Minari dataset needs (hopper's and halfcheetah's from a
    # replay of their pairs, `experts --add-rewards`), and the rewards sum to the returns.
    assert demos.final_observations.shape == (demos.episodes, env.observation_size)
    returns = [
        demonstrations.mean_episode_return(demos.rewards[own], demos.episode_starts[own])
        for own in (demos.intentions == i for i in range(env.max_intentions))
    ]
    np.testing.assert_allclose(returns, demos.expert_returns, rtol=1e-4)


@pytest.mark.parametrize("name", MJX_ENVS)
def test_shipped_experts_meta_records_their_quality(name):
    path = os.path.join(experts.checkpoint_dir(name), "meta.json")
    with open(path) as f:
        meta = json.load(f)
    assert meta["env"] == name
    assert [q["intention"] for q in meta["quality"]] == list(envs.make(name).intention_names)
    np.testing.assert_allclose(
        meta["demo_returns"],
        demonstration_files.load(shipped_demos_path(name)).expert_returns,
        rtol=1e-6,
    )


def _swimmer_file(directory, scale_returns: float = 1.0):
    """The first demonstration of each swimmer intention, without their rewards and final
    observations, as ``directory/swimmer.npz`` (their expert returns times ``scale_returns``):
    ``(path, the demonstrations with them)``."""
    swimmer = envs.make("swimmer")
    shipped = demonstration_files.load(shipped_demos_path("swimmer"), swimmer)
    first = demonstrations.first_episodes(shipped, [1, 1])
    returns = [
        demonstrations.mean_episode_return(first.rewards[own], first.episode_starts[own])
        for own in (first.intentions == i for i in range(2))
    ]
    bare = dataclasses.replace(
        first,
        expert_returns=np.array(returns, np.float32) * np.float32(scale_returns),
        rewards=None,
        final_observations=None,
    )
    directory.mkdir()
    path = str(directory / "swimmer.npz")
    demonstration_files.save(bare, path)
    return path, first


@pytest.mark.slow  # end to end (make test-slow); cheaper tests cover its parts
def test_added_rewards_are_the_recorded_ones(tmp_path, capsys):
    """Swimmer demonstrations carry their recorded rewards and final observations: stripped of
    them, ``--add-rewards`` gives them back from a replay, every other array as it was; a
    second time it is refused, and so is a file whose returns the replay does not give."""
    good = tmp_path / "good"
    path, recorded = _swimmer_file(good)
    with np.load(path) as stripped:
        before = {k: stripped[k] for k in stripped.files}
    assert experts.main(["--env", "swimmer", "--add-rewards", "--out", str(good)]) == 0
    with np.load(path) as added:
        for name, values in before.items():
            assert added[name].dtype == values.dtype and np.array_equal(added[name], values)
        np.testing.assert_allclose(added["rewards"], recorded.rewards, atol=1e-4)
        np.testing.assert_allclose(
            added["final_observations"], recorded.final_observations, atol=1e-5
        )
    assert experts.main(["--env", "swimmer", "--add-rewards", "--out", str(good)]) == 2
    assert "already carries rewards or final_observations" in capsys.readouterr().err
    off, _ = _swimmer_file(tmp_path / "off", scale_returns=1.05)
    unchanged = pathlib.Path(off).read_bytes()
    assert experts.main(["--env", "swimmer", "--add-rewards", "--out", str(tmp_path / "off")]) == 2
    error = capsys.readouterr().err.strip()
    assert error.startswith("error: the replay does not reproduce") and "\n" not in error
    assert pathlib.Path(off).read_bytes() == unchanged


def test_files_the_replay_cannot_serve_are_refused_in_one_line(tmp_path, capsys):
    def refused(env_name, directory, **arrays):
        directory.mkdir()
        if arrays:
            np.savez(directory / f"{env_name}.npz", **arrays)
        argv = ["--env", env_name, "--add-rewards", "--out", str(directory)]
        assert experts.main(argv) == 2
        error = capsys.readouterr().err.strip()
        assert error.startswith("error: ") and "\n" not in error
        return error

    with np.load(shipped_demos_path("reacher")) as shipped:
        reacher = {k: shipped[k] for k in ("observations", "actions", "episode_starts")}
    assert "do not give back its state" in refused("reacher", tmp_path / "reacher", **reacher)
    with np.load(shipped_demos_path("swimmer")) as shipped:
        unlabelled = {k: shipped[k] for k in ("observations", "actions", "episode_starts")}
    assert "has no intentions" in refused("swimmer", tmp_path / "swimmer", **unlabelled)
    assert "does not exist" in refused("hopper", tmp_path / "empty")


# The swimmer in every run; the other envs' replays (40-70 s each) with `make test-slow`.
@pytest.mark.parametrize(
    "name", [n if n == "swimmer" else pytest.param(n, marks=pytest.mark.slow) for n in MJX_ENVS]
)
def test_replayed_experts_reproduce_the_shipped_returns(name):
    """A fresh replay of the shipped checkpoints, with other start states than the demos."""
    env = envs.make(name)
    spec = experts.SPECS[name]
    policy = experts.load_expert_policy(env)
    assert policy is not None
    stored = demonstration_files.load(shipped_demos_path(name)).expert_returns
    expert = lambda state, intention, _: policy(state.obs, intention)
    # The swimmer's recorded returns are within 10% of their mean: two episodes serve.
    episodes = 2 if name == "swimmer" else spec.demo_episodes
    replay = demonstrations.generate(env, expert, episodes, jax.random.PRNGKey(7))
    scale = np.abs(stored) + 0.1 * np.abs(stored).mean()
    np.testing.assert_array_less(np.abs(replay.expert_returns - stored), 0.15 * scale)
