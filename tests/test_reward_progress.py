"""What a reward check keeps while it runs: the training under way and the finished draws, read
back only for the same check."""

import dataclasses

import jax
import numpy as np
import pytest

from emgail_jax.reward.progress import FinishedDraws, PartialTraining, draws_done


@jax.tree_util.register_dataclass
@dataclasses.dataclass
class EnvState:  # like an MJX state: a pytree that is not a dict, with a zero-size leaf
    qpos: np.ndarray
    act: np.ndarray


def _states(scale=1.0):
    return {
        "policy": {"w": np.arange(6, dtype=np.float32).reshape(2, 3) * scale},
        "env": EnvState(qpos=np.ones((2, 4), np.float32) * scale, act=np.zeros((2, 0))),
        "key": np.array([[1, 2], [3, 4]], np.uint32),
    }


def _saved(path, identity=None):
    partial = PartialTraining(str(path), identity or {"options": {"draws": 3}, "iteration": 400})
    returns, earned = np.full((20, 2, 2, 2), 3.0), np.full((20, 2, 2), -1.0)
    partial.write(20, _states(2.0), returns, earned, train_s=12.5)
    return partial


def test_the_training_saved_is_read_back_whole(tmp_path):
    partial = _saved(tmp_path / "rl-0.partial.npz")
    done, states, returns, earned, train_s = partial.read(_states(), chunk=10, iterations=40)
    assert done == 20 and train_s == 12.5
    assert returns.shape == (20, 2, 2, 2) and earned.shape == (20, 2, 2)
    assert isinstance(states["env"], EnvState) and states["env"].act.shape == (2, 0)
    for a, b in zip(jax.tree.leaves(states), jax.tree.leaves(_states(2.0)), strict=True):
        np.testing.assert_array_equal(a, b)
        assert a.dtype == b.dtype
    assert not (tmp_path / "rl-0.partial.npz.tmp").exists()


@pytest.mark.parametrize(
    "why",
    ["another check", "another layout", "another chunking", "more than the check's iterations"],
)
def test_a_save_that_is_not_this_checks_is_not_read(tmp_path, why):
    path = tmp_path / "rl-0.partial.npz"
    partial = _saved(path)
    states, chunk, iterations = _states(), 10, 40
    if why == "another check":
        partial = PartialTraining(str(path), {"options": {"draws": 3}, "iteration": 300})
    elif why == "another layout":
        states["policy"]["w"] = np.zeros((2, 4), np.float32)
    elif why == "another chunking":
        chunk = 8
    else:
        iterations = 10
    assert partial.read(states, chunk, iterations) is None


def test_no_save_or_a_damaged_one_is_nothing_to_go_on_from(tmp_path):
    path = tmp_path / "rl-0.partial.npz"
    partial = PartialTraining(str(path), {"check": 1})
    assert partial.read(_states(), 10, 40) is None
    partial = _saved(path, {"check": 1})
    with open(path, "r+b") as f:
        f.truncate(100)
    assert partial.read(_states(), 10, 40) is None
    partial.remove()
    assert not path.exists()
    partial.remove()  # gone already: nothing to do


def test_a_finished_draw_is_read_back_for_the_same_check_only(tmp_path, capsys):
    check = str(tmp_path / "reoptimize-refit.json")
    finished = FinishedDraws(check, {"options": {"refit": True}, "iteration": 400})
    assert finished.directory == str(tmp_path / "reoptimize-refit.draws")
    assert finished.read(0, progress=True) is None
    finished.write(0, {"erd": [0.1, 0.2], "rl_seed": 0})
    assert finished.read(0, progress=True) == {"erd": [0.1, 0.2], "rl_seed": 0}
    assert "RL draw 0: finished before, reused" in capsys.readouterr().out
    assert finished.read(1, progress=False) is None
    other = FinishedDraws(check, {"options": {"refit": True}, "iteration": 300})
    assert other.read(0, progress=False) is None
    finished.remove()
    assert not (tmp_path / "reoptimize-refit.draws").exists()


def test_a_draw_written_as_finished_drops_its_saved_training(tmp_path):
    finished = FinishedDraws(str(tmp_path / "check.json"), {"options": {}, "iteration": 4})
    partial = finished.partial(1)
    assert partial.path == str(tmp_path / "check.draws" / "rl-1.partial.npz")
    assert partial.identity == {"options": {}, "iteration": 4, "rl_seed": 1}
    partial.write(10, _states(), np.zeros((10, 2, 2, 2)), np.zeros((10, 2, 2)), 1.0)
    assert partial.read(_states(), 10, 40) is not None
    finished.write(1, {"erd": [0.3]})
    assert sorted(p.name for p in (tmp_path / "check.draws").iterdir()) == ["rl-1.json"]


def test_the_draws_done_count_the_training_under_way_by_its_iterations(tmp_path):
    check = str(tmp_path / "reoptimize-refit.json")
    assert draws_done(check, draws=3, iterations=40) == 0.0
    finished = FinishedDraws(check, {"options": {}, "iteration": 4})
    finished.write(0, {"erd": [0.1]})
    finished.partial(1).write(10, _states(), np.zeros((10, 2, 2, 2)), np.zeros((10, 2, 2)), 1.0)
    assert draws_done(check, draws=3, iterations=40) == 1.25
    (tmp_path / "reoptimize-refit.draws" / "rl-2.partial.npz").write_bytes(b"cut short")
    assert draws_done(check, draws=3, iterations=40) == 1.25
    assert draws_done(check, draws=1, iterations=40) == 1.0  # draws beyond those asked not read
