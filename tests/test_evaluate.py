"""python -m emgail_jax.evaluate: scores, figures, and bad input."""

import json

import pytest

from emgail_jax import evaluate, train

PNG = b"\x89PNG\r\n\x1a\n"


def test_evaluate_writes_its_figures(tiny_run, capsys):
    out = tiny_run / "figs"
    assert evaluate.main([str(tiny_run), "--episodes", "2", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "seed 0: ERD" in printed and "seed 1: ERD" in printed and "accuracy" in printed
    for name in ("learning_curves.png", "paths_seed0.png"):
        data = (out / name).read_bytes()
        assert data.startswith(PNG) and len(data) > 10_000, name


def test_evaluation_json_holds_what_evaluate_prints(tiny_run):
    assert evaluate.main([str(tiny_run), "--episodes", "2", "--out", str(tiny_run / "f")]) == 0
    written = json.loads((tiny_run / "evaluation.json").read_text())
    assert written["iteration"] == 4 and written["episodes_per_intention"] == 2
    assert set(written["seeds"]) == {"0", "1"}
    for result in written["seeds"].values():
        assert len(result["erd_per_intention"]) == 2
        assert result["erd"] == pytest.approx(sum(result["erd_per_intention"]) / 2)
        assert sorted(result["matching"]) == [0, 1] and result["episodes"] == 2
        assert len(result["returns"]) == 2 and len(result["returns"][0]) == 2
        assert 0.5 <= result["cluster_accuracy"] <= 1.0


@pytest.fixture(scope="module")
def trajectory_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("trajectory") / "emgail"
    args = [
        *("--env", "driver", "--seeds", "2", "--iterations", "3", "--num-envs", "2"),
        *("--rollout-length", "20", "--quiet", "--out", str(out)),
        *("--responsibilities", "trajectory"),
    ]
    assert train.main(args) == 0
    return out


def test_trajectory_mode_accuracies_equal_the_logged_ones(trajectory_run):
    """Both accuracies of a --responsibilities trajectory run, as evaluate recomputes them from
    the checkpoint, equal those training logged at its last iteration: same posterior, same
    pairs, same function."""
    from emgail_jax.host.saved_run import SavedRun

    assert evaluate.main([str(trajectory_run), "--episodes", "1"]) == 0
    written = json.loads((trajectory_run / "evaluation.json").read_text())
    history = SavedRun.open(str(trajectory_run)).history
    summary = json.loads((trajectory_run / "summary.json").read_text())
    for name in ("cluster_accuracy", "trajectory_cluster_accuracy"):
        for seed in range(2):
            logged = float(history[f"eval/{name}"][seed, -1])
            assert written["seeds"][str(seed)][name] == logged, name
        assert len(summary["final"][name]) == 2


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda tmp, run: tmp / "nothing", "no summary.json"),
        (lambda tmp, run: run, "seeds 0..1"),
    ],
)
def test_evaluate_bad_input(tmp_path, tiny_run, capsys, make, message):
    target = make(tmp_path, tiny_run)
    extra = ["--seed", "5"] if target == tiny_run else []
    assert evaluate.main([str(target), *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and "\n" not in err and "Traceback" not in err
