"""Demonstration files: save and load, and the validation of the format (README,
"Demonstrations format")."""

import jax
import numpy as np
import pytest

import envs
from emgail_jax.host import demonstration_files
from emgail_jax.host.demonstration_files import DemonstrationError
from emgail_jax.method import demonstrations
from emgail_jax.method.demonstrations import Demonstrations


def test_save_load_round_trip(tmp_path):
    env = envs.make("driver", intentions=2)
    generated = demonstrations.generate(env, env.expert_policy, 2, jax.random.PRNGKey(0))
    path = str(tmp_path / "demos.npz")
    demonstration_files.save(generated, path)
    assert not (tmp_path / "demos.npz.tmp.npz").exists()
    loaded = demonstration_files.load(path, env)
    for field in ("observations", "actions", "episode_starts", "intentions", "expert_returns"):
        np.testing.assert_array_equal(getattr(loaded, field), getattr(generated, field))
    assert loaded.observations.dtype == np.float32
    assert loaded.episode_starts.dtype == bool
    assert np.issubdtype(loaded.intentions.dtype, np.integer)


def test_optional_keys_may_be_absent(tmp_path):
    path = str(tmp_path / "bare.npz")
    demonstration_files.save(
        Demonstrations(np.zeros((3, 10)), np.zeros((3, 1)), np.array([True, False, False])), path
    )
    loaded = demonstration_files.load(path, envs.make("driver"))
    assert loaded.intentions is None and loaded.expert_returns is None
    assert loaded.num_intentions is None


def test_added_arrays_leave_the_stored_ones_as_they_were(tmp_path):
    """Even arrays that loading would cast (float64 observations, int64 labels) keep their
    dtype and bytes."""
    path = str(tmp_path / "d.npz")
    stored = {
        "observations": np.linspace(0, 1, 12).reshape(4, 3),
        "actions": np.ones((4, 1), np.float32),
        "episode_starts": np.array([True, False, True, False]),
        "intentions": np.array([0, 0, 1, 1]),
    }
    np.savez(path, **stored)
    demonstration_files.add_arrays(path, rewards=np.arange(4, dtype=np.float32))
    with np.load(path) as written:
        assert written.files == [*stored, "rewards"]
        for name, values in stored.items():
            assert written[name].dtype == values.dtype
            assert written[name].tobytes() == values.tobytes()
        np.testing.assert_array_equal(written["rewards"], np.arange(4))
    assert not list(tmp_path.glob("*.tmp.npz"))


# ---- load rejects bad files with a message naming the problem ------------------------------


def _arrays(n=4, obs_dim=10, act_dim=1, k=2):
    return {
        "observations": np.zeros((n, obs_dim), np.float32),
        "actions": np.zeros((n, act_dim), np.float32),
        "episode_starts": np.array([True] + [False] * (n - 1)),
        "intentions": np.arange(n) % k,
        "expert_returns": -np.ones(k, np.float32),
    }


def _write(tmp_path, **arrays):
    path = str(tmp_path / "bad.npz")
    np.savez(path, **arrays)
    return path


def _without(key):
    arrays = _arrays()
    del arrays[key]
    return arrays


def _with(**changes):
    return {**_arrays(), **changes}


def _nan_obs():
    arrays = _arrays()
    arrays["observations"][2, 3] = np.nan
    return arrays


def _inf_actions():
    arrays = _arrays()
    arrays["actions"][1, 0] = -np.inf
    return arrays


@pytest.mark.parametrize(
    ("arrays", "match"),
    [
        (_without("actions"), "lacks the key\\(s\\) actions"),
        (_without("episode_starts"), "lacks the key\\(s\\) episode_starts"),
        (
            _with(observations=np.zeros((4, 9), np.float32)),
            "obs dim 9 .*driver' expects obs dim 10",
        ),
        (
            _with(actions=np.zeros((4, 2), np.float32)),
            "action dim 2, but env 'driver' expects obs dim 10 and action dim 1",
        ),
        (_nan_obs(), "observations contain NaN or inf"),
        (_inf_actions(), "actions contain NaN or inf"),
        (
            _with(intentions=np.array([0, 1, 4, 2]), expert_returns=-np.ones(5)),
            "labels name 5 intentions but env 'driver' has only 4",
        ),
        (_with(intentions=np.array([0, 1, -1, 1])), "non-negative"),
        (_with(intentions=np.array([0.0, 1.0, 0.0, 1.0])), "intentions must be \\[N\\] integers"),
        (_with(expert_returns=np.array([-1.0, np.nan])), "expert_returns must be a finite"),
        (_with(expert_returns=-np.ones(3)), "expert_returns has 3 entries but the labels name 2"),
        (
            _with(actions=np.zeros((3, 1), np.float32)),
            r"must agree; got shapes \(4, 10\), \(3, 1\) and \(4,\)",
        ),
        (_with(observations=np.zeros(4, np.float32)), "must be 2-D"),
        (
            {
                "observations": np.zeros((0, 10)),
                "actions": np.zeros((0, 1)),
                "episode_starts": np.zeros(0, bool),
            },
            "holds no state-action pairs",
        ),
    ],
    ids=[
        "missing-actions",
        "missing-starts",
        "obs-dim",
        "action-dim",
        "nan-obs",
        "inf-actions",
        "too-many-intentions",
        "negative-label",
        "float-labels",
        "nan-returns",
        "returns-vs-labels",
        "lengths",
        "1d-obs",
        "no-pairs",
    ],
)
def test_load_rejects_bad_contents(tmp_path, arrays, match):
    path = _write(tmp_path, **arrays)
    with pytest.raises(DemonstrationError, match=match):
        demonstration_files.load(path, envs.make("driver", intentions=2))


def test_load_accepts_more_labelled_intentions_than_the_env_rewards(tmp_path):
    # The env rewards 2 of the driver's 4 intentions; a 4-intention dataset is still valid for
    # it (the caller keeps the first 2 with first_intentions).
    path = _write(tmp_path, **_with(intentions=np.array([0, 1, 2, 3]), expert_returns=-np.ones(4)))
    loaded = demonstration_files.load(path, envs.make("driver", intentions=2))
    assert loaded.num_intentions == 4
    assert demonstrations.first_intentions(loaded, 2).num_intentions == 2


def test_load_without_env_skips_only_the_env_checks(tmp_path):
    path = _write(tmp_path, **_with(observations=np.zeros((4, 9), np.float32)))
    assert demonstration_files.load(path).observations.shape == (4, 9)
    with pytest.raises(DemonstrationError, match="NaN"):
        demonstration_files.load(_write(tmp_path, **_nan_obs()))


def test_load_rejects_missing_and_empty_files(tmp_path):
    with pytest.raises(DemonstrationError, match="does not exist"):
        demonstration_files.load(str(tmp_path / "nowhere.npz"))
    empty = tmp_path / "empty.npz"
    empty.write_bytes(b"")
    with pytest.raises(DemonstrationError, match="is empty"):
        demonstration_files.load(str(empty))


def test_load_rejects_a_file_that_is_not_an_npz(tmp_path):
    text = tmp_path / "notes.npz"
    text.write_text("observations,actions\n1,2\n")
    with pytest.raises(DemonstrationError, match=r"not an \.npz file \(not a zip archive\)"):
        demonstration_files.load(str(text))
    truncated = tmp_path / "truncated.npz"
    truncated.write_bytes(b"PK\x03\x04" + b"\x00" * 20)
    with pytest.raises(DemonstrationError, match=r"not a readable \.npz file"):
        demonstration_files.load(str(truncated))


def test_load_rejects_an_npy_file(tmp_path):
    path = tmp_path / "observations.npy"
    np.save(path, np.zeros((4, 10), np.float32))
    with pytest.raises(DemonstrationError, match="npz"):
        demonstration_files.load(str(path))


def test_load_rejects_non_numeric_observations(tmp_path):
    path = _write(tmp_path, **_with(observations=np.full((4, 10), "x")))
    with pytest.raises(DemonstrationError, match="observations"):
        demonstration_files.load(path)


def test_load_names_a_bad_episode_starts_shape(tmp_path):
    path = _write(tmp_path, **_with(episode_starts=np.zeros((4, 2), bool)))
    with pytest.raises(DemonstrationError, match=r"\(4, 2\)"):
        demonstration_files.load(path)


@pytest.mark.parametrize("starts", [[False] * 4, [False, True, False, False]])
def test_load_refuses_a_file_whose_first_pair_starts_no_episode(tmp_path, starts):
    path = _write(tmp_path, **_with(episode_starts=np.array(starts)))
    with pytest.raises(DemonstrationError, match="the first pair must start an episode") as error:
        demonstration_files.load(path)
    assert "\n" not in str(error.value)
