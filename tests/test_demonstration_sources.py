"""A run's --demos sources end to end: the driver's demonstrations as an npz file, as the
Minari datasets this package exports and as datasets written by Minari itself train alike;
bad sources stop a run before it writes anything. Minari datasets go to a temporary
MINARI_DATASETS_PATH."""

import json

import minari
import numpy as np
import pytest

from emgail_jax import run
from emgail_jax.host import demonstration_files, demonstration_sources, minari_datasets
from emgail_jax.host.problem import make_problem, problem_of
from emgail_jax.host.run_spec import RunSpec

# The sizes of conftest's tiny_run, so that these runs share its compiled program.
TINY = [
    *("--env", "driver", "--seeds", "2", "--iterations", "4", "--num-envs", "2"),
    *("--rollout-length", "20", "--chunk-size", "2", "--quiet"),
]


@pytest.fixture(scope="module")
def datasets(tmp_path_factory, minari_user):
    """The driver's default demonstrations as an npz file, as our export and as datasets of
    Minari's own writing whose rewards are twice the true ones."""
    root = tmp_path_factory.mktemp("minari")
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("MINARI_DATASETS_PATH", str(root))
        problem = make_problem("driver", 2)
        npz = str(root / "driver.npz")
        demonstration_files.save(problem.demos, npz)
        ids = minari_datasets.write(problem.demos, problem.env, str(root))
        doubled = [
            minari_user.dataset(f"doubled{i}", doubled_rewards(problem.demos, i, minari_user))
            for i in range(2)
        ]
    return {"root": root, "npz": npz, "ids": ids, "doubled": doubled, "demos": problem.demos}


def doubled_rewards(demos, intention, minari_user):
    buffers = minari_user.buffers(demos, intention)
    return [type(b)(**{**vars(b), "rewards": 2 * b.rewards}) for b in buffers]


@pytest.fixture(scope="module")
def runs(datasets, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("runs")
    sources = {
        "npz": [datasets["npz"]],
        "exported": [f"minari:{identifier}" for identifier in datasets["ids"]],
        "minari-written": datasets["doubled"],
    }
    outs = {}
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("MINARI_DATASETS_PATH", str(datasets["root"]))
        for name, demos in sources.items():
            outs[name] = tmp / name
            assert run.main([*TINY, "--demos", *demos, "--out", str(outs[name])]) == 0
    return outs


def summary(out):
    return json.loads((out / "summary.json").read_text())


@pytest.mark.slow  # end to end (make test-slow); cheaper tests cover its parts
def test_the_exported_minari_datasets_train_to_the_same_bytes_as_the_npz(runs):
    npz, exported = (runs[name] / "metrics.csv" for name in ("npz", "exported"))
    assert npz.read_bytes() == exported.read_bytes()
    assert summary(runs["exported"])["final"] == summary(runs["npz"])["final"] | {
        key: summary(runs["exported"])["final"][key]
        for key in ("compile_time_s", "train_time_s", "iteration_time_s")
    }


def test_datasets_written_by_minari_train_as_two_intentions(runs, datasets):
    """The accuracy from the dataset index, the expert returns from the datasets' rewards."""
    result = summary(runs["minari-written"])
    assert result["intentions"] == 2 and result["demonstrations"]["labels"]
    assert all(0.0 <= a <= 1.0 for a in result["final"]["cluster_accuracy"])
    means = [
        np.mean([e.rewards.sum() for e in minari.MinariDataset(f"{source}/data")])
        for source in datasets["doubled"]
    ]
    np.testing.assert_allclose(result["final"]["expert_returns"], means, rtol=1e-6)
    np.testing.assert_allclose(means, 2 * datasets["demos"].expert_returns, rtol=1e-5)


def test_a_run_of_several_sources_reopens_with_them(runs, datasets, monkeypatch):
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(datasets["root"]))
    stored = summary(runs["exported"])
    assert stored["demonstrations"]["path"] == [f"minari:{i}" for i in datasets["ids"]]
    assert summary(runs["npz"])["demonstrations"]["path"] == datasets["npz"]  # one: a string
    reopened = problem_of(RunSpec.from_summary(stored)).demos
    np.testing.assert_array_equal(reopened.observations, datasets["demos"].observations)
    np.testing.assert_array_equal(reopened.intentions, datasets["demos"].intentions)


def test_a_single_source_is_taken_as_it_is(datasets):
    one = demonstration_sources.load([datasets["npz"]])
    np.testing.assert_array_equal(one.intentions, datasets["demos"].intentions)
    assert demonstration_sources.canonical("minari:a/b-v0") == "minari:a/b-v0"
    assert demonstration_sources.canonical("x.npz").endswith("/x.npz")


@pytest.mark.parametrize(
    ("source", "message"),
    [
        ("other-dimensions", "expects obs dim 10 and action dim 1"),
        ("minari:missing-v0", "no Minari dataset 'missing-v0'"),
    ],
)
def test_a_bad_source_stops_the_run_before_it_writes(
    datasets, tmp_path, monkeypatch, capsys, minari_user, source, message
):
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "minari"))
    if source == "other-dimensions":
        demos = datasets["demos"]
        wide = np.zeros((101, 11), np.float32)
        buffers = minari_user.buffers(demos, 0, observations=wide)[:1]
        source = minari_user.dataset(source, buffers, obs_dim=11)
    out = tmp_path / "run"
    assert run.main([*TINY, "--demos", source, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and message in err and "\n" not in err
    assert not out.exists()
