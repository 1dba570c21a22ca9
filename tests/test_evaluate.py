"""python -m emgail_jax.evaluate: scores, figures, and bad input."""

import json
import shutil

import numpy as np
import pytest

from emgail_jax import evaluate, run

PNG = b"\x89PNG\r\n\x1a\n"


def test_evaluate_writes_its_figures(tiny_run, capsys):
    out = tiny_run / "figs"
    assert evaluate.main([str(tiny_run), "--episodes", "2", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "seed 0: ERD" in printed and "seed 1: ERD" in printed and "accuracy" in printed
    assert printed.count("demonstrations held per learned intention") == 2
    for name in ("learning_curves.png", "paths_seed0.png"):
        data = (out / name).read_bytes()
        assert data.startswith(PNG) and len(data) > 10_000, name


def test_evaluate_names_seeds_as_run_seed_numbered_them(renumbered_run, tmp_path, capsys):
    # A folder of its own: the renumbered copy may hold figures other tests drew in tiny_run.
    out = tmp_path / "figs"
    args = [str(renumbered_run), "--episodes", "2", "--seed", "5", "--out", str(out)]
    assert evaluate.main(args) == 0
    assert "seed 4: ERD" in capsys.readouterr().out
    assert (out / "paths_seed5.png").exists() and not (out / "paths_seed0.png").exists()
    written = json.loads((renumbered_run / "evaluation.json").read_text())
    assert set(written["seeds"]) == {"4", "5"}


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
        # Each of the 10 demonstrations is held by one learned intention.
        assert len(result["demonstrations_held"]) == 2
        assert sum(result["demonstrations_held"]) == 10


@pytest.fixture(scope="module")
def auto_run(tmp_path_factory):
    """--intentions auto on demonstrations of the driver's first two paths: three intentions
    learned for two true ones (in the default trajectory E-step)."""
    import jax

    import envs
    from emgail_jax.host import demonstration_files
    from emgail_jax.method import demonstrations

    tmp = tmp_path_factory.mktemp("auto")
    env = envs.make("driver", intentions=2)
    demos = demonstrations.generate(env, env.expert_policy, 2, jax.random.PRNGKey(0))
    demonstration_files.save(demos, str(tmp / "two-paths.npz"))
    out = tmp / "emgail"
    args = [
        *("--env", "driver", "--seeds", "2", "--iterations", "3", "--num-envs", "2"),
        *("--rollout-length", "20", "--quiet", "--out", str(out)),
        *("--demos", str(tmp / "two-paths.npz"), "--intentions", "auto", "--max-intentions", "3"),
    ]
    assert run.main(args) == 0
    return out


@pytest.mark.slow  # end to end (make test-slow); cheaper tests cover its parts
def test_auto_run_learns_more_intentions_than_it_scores(auto_run):
    summary = json.loads((auto_run / "summary.json").read_text())
    assert summary["intentions"] == 3 and summary["demonstrations"]["intentions"] == 2
    assert summary["config"]["choose_intentions"] and summary["config"]["prior"] == "mixture"
    final = summary["final"]
    assert [len(w) for w in final["intention_weights"]] == [3, 3]
    assert all(1 <= k <= 3 for k in final["intentions_chosen"])
    assert [len(e) for e in final["erd_per_intention"]] == [2, 2]
    assert [len(r) for r in final["returns"]] == [2, 2]


def test_evaluate_recomputes_the_logged_accuracies(tiny_run):
    """Both accuracies of a run in the default trajectory E-step (pairs, and whole
    demonstrations), as evaluate recomputes them from the checkpoint, equal those training
    logged at its last iteration: same posterior, same pairs, same function."""
    from emgail_jax.host.saved_run import SavedRun

    # The episodes of the other evaluations of tiny_run: their compiled programs serve.
    assert evaluate.main([str(tiny_run), "--episodes", "2", "--out", str(tiny_run / "g")]) == 0
    written = json.loads((tiny_run / "evaluation.json").read_text())
    history = SavedRun.open(str(tiny_run)).history
    for name in ("cluster_accuracy", "trajectory_cluster_accuracy"):
        for seed in range(2):
            logged = float(history[f"eval/{name}"][seed, -1])
            assert written["seeds"][str(seed)][name] == logged, name


def test_evaluate_scores_the_intentions_an_auto_run_keeps(auto_run):
    """evaluate scores the final state: the intentions its weights keep (training logs those
    the iteration started with, one weight update earlier), and draws the weights."""
    from emgail_jax.host.saved_run import SavedRun

    out = auto_run / "figures"
    assert evaluate.main([str(auto_run), "--episodes", "1", "--out", str(out)]) == 0
    assert (out / "intention_weights.png").read_bytes().startswith(PNG)
    written = json.loads((auto_run / "evaluation.json").read_text())
    run = SavedRun.open(str(auto_run))
    for seed in range(2):
        result = written["seeds"][str(seed)]
        in_use = run.intentions_in_use(seed)
        assert result["intentions_chosen"] == int(in_use.sum())
        assert len(set(result["matching"])) == 2 and set(result["matching"]) <= {0, 1, 2}
        if in_use.sum() >= 2:  # every true intention matched to a learned one in use
            assert all(in_use[j] for j in result["matching"])
        assert 0.0 <= result["cluster_accuracy"] <= 1.0


def test_an_auto_run_reports_what_the_seeds_agree_on(auto_run):
    """The intentions each seed keeps, as training wrote them at its end, equal those the
    saved run recomputes from the final state: held by their weights, then the seeds'
    consensus on each demonstration's intention; the final accuracies are the final state's
    with those kept."""
    from emgail_jax.host.saved_run import SavedRun
    from emgail_jax.method.choosing import (
        consensus_intentions,
        demonstration_intentions,
        holds_demonstrations,
    )

    summary = json.loads((auto_run / "summary.json").read_text())
    final = summary["final"]
    run = SavedRun.open(str(auto_run))
    pairs = run.demonstration_pairs
    weights = np.asarray(run.state.intention_weights)
    labels = [
        demonstration_intentions(
            run.responsibilities(seed).gamma,
            pairs.episode,
            pairs.episodes,
            np.asarray(holds_demonstrations(weights[seed], pairs.episodes)),
        )
        for seed in range(2)
    ]
    expected = consensus_intentions(np.stack(labels), weights)
    for seed in range(2):
        np.testing.assert_array_equal(run.intentions_in_use(seed), expected[seed])
        np.testing.assert_array_equal(final["intentions_kept"][seed], expected[seed])
        assert final["intentions_chosen"][seed] == expected[seed].sum()
        assert final["cluster_accuracy"][seed] == run.clustering(seed)["cluster_accuracy"]
    assert all(1 <= k <= 3 for k in final["intentions_held"])


def test_a_saved_run_without_the_stored_choice_decides_k_as_training_did(auto_run, tmp_path):
    """The intentions kept come from the run's final results; a summary without them (older
    runs) has them decided again from the final state, to the same."""
    from emgail_jax.host.saved_run import SavedRun

    copy = tmp_path / "older"
    shutil.copytree(auto_run, copy)
    summary = json.loads((copy / "summary.json").read_text())
    stored = summary["final"].pop("intentions_kept")
    (copy / "summary.json").write_text(json.dumps(summary))
    again = SavedRun.open(str(copy))
    for seed in range(2):
        np.testing.assert_array_equal(again.intentions_in_use(seed), stored[seed])


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
