"""Demonstrations: generation with the driver's analytic expert, the file format and its
validation (README, "Demonstrations format")."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from emgail_jax import demos as demos_lib
from emgail_jax.demos import DemonstrationError, Demonstrations

EPISODES, LENGTH, K = 5, 100, 2


@pytest.fixture(scope="module")
def env():
    return envs.make("driver", intentions=K)


@pytest.fixture(scope="module")
def generated(env):
    return demos_lib.generate(env, env.expert_policy, EPISODES, jax.random.PRNGKey(0))


def test_generate_sizes_labels_and_episode_starts(generated):
    assert len(generated) == K * EPISODES * LENGTH
    assert generated.observations.shape == (1000, 10)
    assert generated.actions.shape == (1000, 1)
    assert generated.observations.dtype == generated.actions.dtype == np.float32
    np.testing.assert_array_equal(np.bincount(generated.intentions), [500, 500])
    # Intention-major, then episode, then time.
    np.testing.assert_array_equal(generated.intentions, np.repeat([0, 1], 500))
    np.testing.assert_array_equal(np.flatnonzero(generated.episode_starts), np.arange(0, 1000, 100))
    assert generated.num_intentions == K
    assert np.all(np.abs(generated.actions) <= 1.0)
    assert np.all(np.isfinite(generated.observations))


def test_episode_starts_are_initial_states_and_episodes_are_contiguous(env, generated):
    history = generated.observations.reshape(-1, 5, 2)
    spacing = np.linalg.norm(np.diff(history, axis=1), axis=-1)  # [N, 4]
    np.testing.assert_allclose(spacing, env.speed, rtol=1e-3)  # constant speed everywhere
    starts = generated.episode_starts
    # A start is near the origin; every other observation continues the previous one.
    assert np.all(np.linalg.norm(history[starts, -1], axis=-1) < 0.3)
    following = ~starts[1:]
    np.testing.assert_allclose(history[1:][following, :-1], history[:-1][following, 1:], atol=1e-6)


def test_generate_is_deterministic_for_a_key(env, generated):
    again = demos_lib.generate(env, env.expert_policy, EPISODES, jax.random.PRNGKey(0))
    np.testing.assert_array_equal(again.observations, generated.observations)
    np.testing.assert_array_equal(again.actions, generated.actions)
    np.testing.assert_array_equal(again.expert_returns, generated.expert_returns)
    other = demos_lib.generate(env, env.expert_policy, EPISODES, jax.random.PRNGKey(1))
    assert not np.allclose(other.actions, generated.actions)


def test_expert_returns_equal_the_own_path_return_recomputed_from_the_pairs(env, generated):
    """Replays each pair's action from its observation (the heading is the direction of the last
    move) and sums minus the distance to the own path: the mean per intention is expert_returns."""
    history = generated.observations.reshape(-1, 5, 2)
    move = history[:, -1] - history[:, -2]
    heading = np.arctan2(move[:, 1], move[:, 0]) + env.max_turn * generated.actions[:, 0]
    position = history[:, -1] + env.speed * np.stack([np.cos(heading), np.sin(heading)], -1)
    distances = np.asarray(jax.vmap(env.path_distances)(jnp.asarray(position)))  # [N, K]
    own = -distances[np.arange(len(position)), generated.intentions]
    per_episode = own.reshape(K, EPISODES, LENGTH).sum(-1)
    np.testing.assert_allclose(generated.expert_returns, per_episode.mean(-1), rtol=2e-3)
    # Near the maximum (0) of the own path's reward: the expert follows its path.
    assert np.all(generated.expert_returns > -5.0)


class _Counter(envs.Env):
    """Counts its steps and terminates on its own after ``stop`` of them; reward 1 per step."""

    name = "counter"
    intention_names = ("a", "b")
    observation_size = 1
    action_size = 1
    episode_length = 10
    stop = 3

    def reset(self, key):
        return envs.State(
            physics=jnp.zeros(()), obs=jnp.zeros(1), reward=jnp.zeros(2), done=jnp.zeros(())
        )

    def step(self, state, action):
        count = state.physics + 1
        done = (count >= self.stop).astype(jnp.float32)
        return state.replace(physics=count, obs=count[None], reward=jnp.ones(2), done=done)


def test_generate_drops_pairs_after_an_early_termination():
    counter = _Counter()
    expert = lambda state, intention, key: jnp.zeros(1)
    demos = demos_lib.generate(counter, expert, 2, jax.random.PRNGKey(0))
    # 2 intentions x 2 episodes x 3 steps before the env ended each episode (of 10 allowed).
    assert len(demos) == 12
    np.testing.assert_array_equal(demos.observations[:, 0], np.tile([0, 1, 2], 4))
    np.testing.assert_array_equal(np.flatnonzero(demos.episode_starts), [0, 3, 6, 9])
    np.testing.assert_array_equal(demos.intentions, np.repeat([0, 1], 6))
    np.testing.assert_array_equal(demos.expert_returns, [3.0, 3.0])


def test_save_load_round_trip(tmp_path, env, generated):
    path = str(tmp_path / "demos.npz")
    generated.save(path)
    assert not (tmp_path / "demos.npz.tmp.npz").exists()
    loaded = demos_lib.load(path, env)
    for field in ("observations", "actions", "episode_starts", "intentions", "expert_returns"):
        np.testing.assert_array_equal(getattr(loaded, field), getattr(generated, field))
    assert loaded.observations.dtype == np.float32
    assert loaded.episode_starts.dtype == bool
    assert np.issubdtype(loaded.intentions.dtype, np.integer)


def test_optional_keys_may_be_absent(tmp_path):
    path = str(tmp_path / "bare.npz")
    Demonstrations(np.zeros((3, 10)), np.zeros((3, 1)), np.array([True, False, False])).save(path)
    loaded = demos_lib.load(path, envs.make("driver"))
    assert loaded.intentions is None and loaded.expert_returns is None
    assert loaded.num_intentions is None


def test_first_intentions_keeps_the_first_k(generated):
    four = Demonstrations(
        observations=np.arange(8, dtype=np.float32)[:, None],
        actions=np.zeros((8, 1), np.float32),
        episode_starts=np.array([1, 0, 1, 0, 1, 0, 1, 0], bool),
        intentions=np.array([0, 0, 1, 1, 2, 2, 3, 3]),
        expert_returns=np.array([-1.0, -2.0, -3.0, -4.0], np.float32),
    )
    two = demos_lib.first_intentions(four, 2)
    np.testing.assert_array_equal(two.observations[:, 0], [0, 1, 2, 3])
    np.testing.assert_array_equal(two.intentions, [0, 0, 1, 1])
    np.testing.assert_array_equal(two.expert_returns, [-1.0, -2.0])
    assert two.num_intentions == 2


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
        (_with(observations=np.zeros((4, 9), np.float32)), "obs dim 9 .*driver' has 10"),
        (
            _with(actions=np.zeros((4, 2), np.float32)),
            "action dim 2, but env 'driver' has 10 and 1",
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
        demos_lib.load(path, envs.make("driver", intentions=2))


def test_load_accepts_more_labelled_intentions_than_the_env_rewards(tmp_path):
    # The env rewards 2 of the driver's 4 intentions; a 4-intention dataset is still valid for
    # it (the caller keeps the first 2 with first_intentions).
    path = _write(tmp_path, **_with(intentions=np.array([0, 1, 2, 3]), expert_returns=-np.ones(4)))
    loaded = demos_lib.load(path, envs.make("driver", intentions=2))
    assert loaded.num_intentions == 4
    assert demos_lib.first_intentions(loaded, 2).num_intentions == 2


def test_load_without_env_skips_only_the_env_checks(tmp_path):
    path = _write(tmp_path, **_with(observations=np.zeros((4, 9), np.float32)))
    assert demos_lib.load(path).observations.shape == (4, 9)
    with pytest.raises(DemonstrationError, match="NaN"):
        demos_lib.load(_write(tmp_path, **_nan_obs()))


def test_load_rejects_missing_and_empty_files(tmp_path):
    with pytest.raises(DemonstrationError, match="does not exist"):
        demos_lib.load(str(tmp_path / "nowhere.npz"))
    empty = tmp_path / "empty.npz"
    empty.write_bytes(b"")
    with pytest.raises(DemonstrationError, match="is empty"):
        demos_lib.load(str(empty))


def test_load_rejects_a_file_that_is_not_an_npz(tmp_path):
    text = tmp_path / "notes.npz"
    text.write_text("observations,actions\n1,2\n")
    with pytest.raises(DemonstrationError, match=r"not an \.npz file \(not a zip archive\)"):
        demos_lib.load(str(text))
    truncated = tmp_path / "truncated.npz"
    truncated.write_bytes(b"PK\x03\x04" + b"\x00" * 20)
    with pytest.raises(DemonstrationError, match=r"not a readable \.npz file"):
        demos_lib.load(str(truncated))


def test_load_rejects_an_npy_file(tmp_path):
    path = tmp_path / "observations.npy"
    np.save(path, np.zeros((4, 10), np.float32))
    with pytest.raises(DemonstrationError, match="npz"):
        demos_lib.load(str(path))


def test_load_rejects_non_numeric_observations(tmp_path):
    path = _write(tmp_path, **_with(observations=np.full((4, 10), "x")))
    with pytest.raises(DemonstrationError, match="observations"):
        demos_lib.load(path)


def test_load_names_a_bad_episode_starts_shape(tmp_path):
    path = _write(tmp_path, **_with(episode_starts=np.zeros((4, 2), bool)))
    with pytest.raises(DemonstrationError, match=r"\(4, 2\)"):
        demos_lib.load(path)
