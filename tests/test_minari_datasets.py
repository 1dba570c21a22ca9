"""Minari datasets in and out: the export of labelled demonstrations (one dataset per
intention), the round trip back to the same arrays, datasets written by Minari itself, and the
refusal of every malformed dataset. Every dataset goes to a temporary MINARI_DATASETS_PATH."""

import dataclasses
import json

import gymnasium
import jax
import minari
import numpy as np
import pytest
from minari.data_collector import EpisodeBuffer

import envs
from emgail_jax import experts
from emgail_jax.host import demonstration_files, demonstration_sources, minari_datasets
from emgail_jax.host.demonstration_files import DemonstrationError
from emgail_jax.host.problem import shipped_demos_path
from emgail_jax.method import demonstrations

FIELDS = (
    "observations",
    "actions",
    "episode_starts",
    "intentions",
    "expert_returns",
    "rewards",
    "final_observations",
)


@pytest.fixture(autouse=True)
def datasets_root(tmp_path, monkeypatch):
    root = tmp_path / "minari"
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(root))
    return root


@pytest.fixture(scope="module")
def driver():
    return envs.make("driver", intentions=2)


@pytest.fixture(scope="module")
def driver_demos(driver):
    return demonstrations.generate(driver, driver.expert_policy, 3, jax.random.PRNGKey(0))


def assert_same(a, b):
    for name in FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and x.shape == y.shape, name
        np.testing.assert_array_equal(x, y, err_msg=name)


def test_generated_demonstrations_carry_rewards_and_final_observations(driver, driver_demos):
    demos = driver_demos
    assert demos.rewards.shape == (len(demos),) and demos.final_observations.shape == (6, 10)
    for intention in range(2):
        own = demos.intentions == intention
        assert demonstrations.mean_episode_return(
            demos.rewards[own], demos.episode_starts[own]
        ) == pytest.approx(demos.expert_returns[intention], rel=1e-6)
    # The final observation follows the last pair's, one step of the driver further on.
    last = np.flatnonzero(np.roll(demos.episode_starts, -1))
    step = np.linalg.norm(demos.final_observations[:, -2:] - demos.observations[last, -2:], axis=1)
    np.testing.assert_allclose(step, driver.speed, rtol=1e-3)


def test_npz_to_minari_to_npz_gives_identical_arrays(tmp_path, datasets_root):
    """The shipped swimmer demonstrations through ``experts --export-minari`` and back."""
    swimmer = envs.make("swimmer")
    assert experts.main(["--env", "swimmer", "--export-minari", "--quiet"]) == 0
    ids = [minari_datasets.dataset_id("swimmer", name) for name in swimmer.intention_names]
    for intention, identifier in enumerate(ids):
        stored = minari_datasets.metadata(f"minari:{identifier}")
        assert stored["intention"] == swimmer.intention_names[intention]
        assert stored["emgail_env"] == "swimmer"
        assert minari.load_dataset(identifier).total_episodes == 5
    sources = [f"minari:{identifier}" for identifier in ids]
    back = tmp_path / "back.npz"
    demonstration_files.save(demonstration_sources.load(sources, swimmer), str(back))
    shipped = demonstration_files.load(shipped_demos_path("swimmer"), swimmer)
    assert_same(demonstration_files.load(str(back), swimmer), shipped)


def test_an_export_refuses_to_overwrite_and_writes_nothing(driver, driver_demos, datasets_root):
    minari_datasets.write(driver_demos, driver, str(datasets_root))
    before = sorted(p.name for p in datasets_root.rglob("*"))
    with pytest.raises(DemonstrationError, match="already in"):
        minari_datasets.write(driver_demos, driver, str(datasets_root))
    assert sorted(p.name for p in datasets_root.rglob("*")) == before


def test_datasets_written_by_minari_are_one_intention_each(driver, driver_demos, minari_user):
    """No metadata of ours: the list order labels the pairs, the rewards give the returns."""
    sources = [
        minari_user.dataset(f"path{i}", minari_user.buffers(driver_demos, i)) for i in range(2)
    ]
    demos = demonstration_sources.load(sources, driver)
    np.testing.assert_array_equal(demos.intentions, driver_demos.intentions)
    np.testing.assert_array_equal(demos.observations, driver_demos.observations)
    for intention, source in enumerate(sources):
        returns = [e.rewards.sum() for e in minari.MinariDataset(f"{source}/data")]
        assert demos.expert_returns[intention] == pytest.approx(np.mean(returns), rel=1e-6)


def test_one_dataset_may_carry_its_labels_in_its_infos(driver, driver_demos, minari_user):
    buffers = []
    for intention in range(2):
        for buffer in minari_user.buffers(driver_demos, intention):
            labels = np.full(len(buffer.observations), intention)  # [T + 1], as Minari records
            buffers.append(EpisodeBuffer(**{**vars(buffer), "infos": {"intention": labels}}))
    demos = demonstration_sources.load([minari_user.dataset("mix", buffers)], driver)
    np.testing.assert_array_equal(demos.intentions, driver_demos.intentions)
    np.testing.assert_allclose(demos.expert_returns, driver_demos.expert_returns, rtol=1e-6)
    unlabelled = demonstration_sources.load(
        [minari_user.dataset("plain", minari_user.buffers(driver_demos, 0))]
    )
    assert unlabelled.intentions is None and unlabelled.expert_returns is None


def _corrupt_metadata(directory):
    (directory / "data" / "metadata.json").write_text("{not json")


def _truncate_data(directory):
    path = directory / "data" / "main_data.hdf5"
    path.write_bytes(path.read_bytes()[:100])


def _unsupported_version(directory):
    path = directory / "data" / "metadata.json"
    path.write_text(json.dumps({**json.loads(path.read_text()), "minari_version": "0.0.1"}))


def _remove_data(directory):
    (directory / "data" / "main_data.hdf5").unlink()


BOX = gymnasium.spaces.Box(-1.0, 1.0, (1,), np.float32)


def _malformed(name, demos, minari_user):
    """``(buffers, spaces, file damage)`` of a malformed dataset."""
    nan = demos.observations[:100].copy()
    nan[5] = np.nan
    one = lambda **fields: minari_user.buffers(demos, 0, **fields)[:1]
    cases = {
        "dict observations": (
            one(observations={"x": np.zeros((101, 10), np.float32)}),
            {"observation_space": gymnasium.spaces.Dict({"x": gymnasium.spaces.Box(-1, 1, (10,))})},
            None,
        ),
        "discrete actions": (
            one(actions=np.zeros(100, np.int64)),
            {"action_space": gymnasium.spaces.Discrete(3)},
            None,
        ),
        "other dimensions": (
            one(observations=np.zeros((101, 11), np.float32)),
            {"obs_dim": 11},
            None,
        ),
        "no final observation": (one(observations=demos.observations[:100]), {}, None),
        "nan observations": (one(observations=np.concatenate([nan, nan[:1]])), {}, None),
        "float labels": (one(infos={"intention": np.zeros(101)}), {}, None),
        "labels changing within an episode": (
            one(infos={"intention": np.arange(101) % 2}),
            {},
            None,
        ),
        "labels on some episodes only": (
            [*minari_user.buffers(demos, 0)[:1], *one(infos={"intention": np.zeros(101, int)})],
            {},
            None,
        ),
        "corrupt metadata": (one(), {}, _corrupt_metadata),
        "truncated data file": (one(), {}, _truncate_data),
        "missing data file": (one(), {}, _remove_data),
        "unsupported minari version": (one(), {}, _unsupported_version),
    }
    return cases[name]


MALFORMED = {
    "dict observations": "observation space must be a flat Box",
    "discrete actions": "action space must be a flat Box",
    "other dimensions": "obs dim 11 and action dim 1, but env 'driver' expects obs dim 10",
    "no final observation": "100 observations for 100 actions",
    "nan observations": "observations contain NaN",
    "float labels": "infos\\['intention'\\] must be \\[T\\] or \\[T \\+ 1\\] integer labels",
    "labels changing within an episode": "changes within an episode",
    "labels on some episodes only": "1 of 2 episodes carry infos\\['intention'\\]",
    "corrupt metadata": "not a readable Minari dataset",
    "truncated data file": "not a readable Minari dataset",
    "missing data file": "not a readable Minari dataset",
    "unsupported minari version": "not a readable Minari dataset",
}


@pytest.mark.parametrize("case", sorted(MALFORMED))
def test_every_malformed_dataset_is_refused_in_one_line(
    driver, driver_demos, tmp_path, case, minari_user
):
    buffers, spaces, damage = _malformed(case, driver_demos, minari_user)
    directory = minari_user.dataset(case.replace(" ", "-"), buffers, **spaces)
    if damage is not None:
        damage(tmp_path / "minari" / "user" / f"{case.replace(' ', '-')}-v0")
    with pytest.raises(DemonstrationError, match=MALFORMED[case]) as error:
        demonstration_sources.load([directory], driver)
    assert "\n" not in str(error.value)


def test_sources_that_are_not_datasets_are_refused(driver, driver_demos, tmp_path):
    minari_datasets.write(driver_demos, driver, str(tmp_path / "minari"))
    path1, path2 = (f"minari:{minari_datasets.dataset_id('driver', f'path{i}')}" for i in (1, 2))
    cases = {
        "minari:nothing-v0": "no Minari dataset 'nothing-v0'",
        "minari:not an id": "a Minari dataset id is",
        str(tmp_path): "not a Minari dataset directory",
    }
    for source, message in cases.items():
        with pytest.raises(DemonstrationError, match=message):
            demonstration_sources.load([source], driver)
    with pytest.raises(DemonstrationError, match="demonstrates 'path2' but stands at place 1"):
        demonstration_sources.load([path2, path1], driver)
    with pytest.raises(DemonstrationError, match="recorded in env 'driver', not 'swimmer'"):
        demonstration_sources.load([path1, path2], _driver_shaped_swimmer())
    mixed = tmp_path / "mixed.npz"
    demonstration_files.save(driver_demos, str(mixed))
    with pytest.raises(DemonstrationError, match="holds 2 labelled intentions"):
        demonstration_sources.load([str(mixed), path2], driver)


def _driver_shaped_swimmer():
    """A stand-in env of the driver's sizes under another name."""
    env = envs.make("driver", intentions=2)

    class Other(type(env)):
        name = "swimmer"

    return Other(intentions=2)


def test_the_shipped_hopper_demonstrations_are_exported_and_read_back(tmp_path):
    """Hopper's rewards and final observations come from a replay (``experts --add-rewards``):
    the datasets give back the file's pairs, episodes and those arrays; each dataset's expert
    return is its rewards' mean episode return, within 1e-4 of the file's stored one."""
    hopper = envs.make("hopper")
    out = tmp_path / "datasets"
    assert experts.main(["--env", "hopper", "--export-minari", "--out", str(out)]) == 0
    shipped = demonstration_files.load(shipped_demos_path("hopper"), hopper)
    sources = [
        str(out / minari_datasets.dataset_id("hopper", name)) for name in hopper.intention_names
    ]
    back = demonstration_sources.load(sources, hopper)
    for name in (field for field in FIELDS if field != "expert_returns"):
        np.testing.assert_array_equal(getattr(back, name), getattr(shipped, name), name)
    np.testing.assert_allclose(back.expert_returns, shipped.expert_returns, rtol=1e-4)
    dataset = minari.MinariDataset(f"{sources[0]}/data")
    episodes = list(dataset)
    assert len(episodes) == 5 and all(len(e.actions) == hopper.episode_length for e in episodes)
    assert all(e.truncations[-1] and not e.terminations.any() for e in episodes)


def test_demonstrations_without_rewards_are_not_exported(driver, driver_demos, datasets_root):
    bare = dataclasses.replace(driver_demos, rewards=None, final_observations=None)
    with pytest.raises(DemonstrationError, match=r"lack: .*--add-rewards") as error:
        minari_datasets.write(bare, driver, str(datasets_root))
    assert "\n" not in str(error.value)
    assert not list(datasets_root.rglob("*"))
