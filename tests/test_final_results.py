"""A run's final results as a typed record, and its reader: every committed summary reads
back as it was written."""

import json
import pathlib

import pytest

from emgail_jax.host.final_results import FinalResults, read_final
from emgail_jax.host.run_spec import RunError

ROOT = pathlib.Path(__file__).resolve().parent.parent
COMMITTED = sorted((ROOT / "results" / "runs").glob("*/summary.json"))


@pytest.mark.parametrize("path", COMMITTED, ids=lambda p: p.parent.name)
def test_every_committed_summary_reads_back_as_it_was_written(path):
    """The 79 cells of results/runs, of every version since the first: their "final" read as
    a FinalResults and written again is the same dict, key order included."""
    summary = json.loads(path.read_text())
    final = FinalResults.from_summary(summary)
    assert final.seeds == summary["seeds"]
    assert list(final.to_summary().items()) == list(summary["final"].items())


def test_absent_results_are_left_out_and_undefined_ones_null():
    final = FinalResults(
        erd=None,
        erd_per_intention=None,
        cluster_accuracy=None,
        expert_returns=None,
        returns=[[1.0, 2.0]],
        random_returns=[-1.0, -2.0],
        compile_time_s=1.0,
        train_time_s=2.0,
        iteration_time_s=0.5,
        env_steps=10,
    )
    written = final.to_summary()
    assert written["erd"] is None and written["cluster_accuracy"] is None
    assert "demonstrations_held" not in written and "trajectory_cluster_accuracy" not in written
    with_trajectories = FinalResults(**{**vars(final), "trajectory_labels": True})
    assert with_trajectories.to_summary()["trajectory_cluster_accuracy"] is None


def test_read_final(tmp_path):
    with pytest.raises(RunError, match="no summary"):
        read_final(str(tmp_path))
    (tmp_path / "summary.json").write_text(json.dumps({"status": "running"}))
    assert read_final(str(tmp_path)) is None  # a run that has no final results yet
    committed = COMMITTED[0]
    assert (
        read_final(str(committed.parent)).env_steps
        == json.loads(committed.read_text())["final"]["env_steps"]
    )
