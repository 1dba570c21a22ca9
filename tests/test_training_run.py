"""Training a run into its directory: what it leaves per chunk and at the end."""

import json

import numpy as np

from emgail_jax.host.records import to_json_value
from emgail_jax.host.saved_run import SavedRun
from emgail_jax.host.training_run import parameter_counts, progress_fields, summary_header
from emgail_jax.method.training import RunData, make_train


def test_progress_fields_are_the_latest_measured_means():
    erd = np.full((2, 5), np.nan)
    erd[:, 1] = [0.2, 0.4]
    erd[0, 3] = 0.5  # iteration 3 measured on one seed only: its mean is that seed's
    accuracy = np.full((2, 5), np.nan)
    fields = progress_fields({"eval/erd": erd, "eval/cluster_accuracy": accuracy})
    assert fields == {"ERD": "0.500", "acc": "-"}


def test_the_summary_header_and_parameters_are_the_runs(tiny_run):
    """What the run wrote at its head is what its spec, problem and config give again."""
    summary = json.loads((tiny_run / "summary.json").read_text())
    saved = SavedRun.open(str(tiny_run))
    header = json.loads(
        json.dumps(to_json_value(summary_header(saved.spec, saved.problem, saved.config)))
    )
    assert header == {name: summary[name] for name in header}
    assert list(summary)[: len(header)] == list(header)
    init, _ = make_train(saved.config.method, saved.problem.env)
    data = RunData.create(saved.demonstration_pairs, saved.problem.env, saved.config.info_weight)
    assert parameter_counts(init, data) == summary["parameters"]


def test_checkpoints_and_snapshots_follow_their_cadence(tiny_run):
    """4 iterations in chunks of 2, snapshots every 2: snapshots at 2 and 4, and the last
    checkpoint (every 50, and at the end) at 4."""
    snapshots = sorted(p.name for p in (tiny_run / "snapshots").iterdir())
    assert snapshots == ["iteration_000002.msgpack", "iteration_000004.msgpack"]
    summary = json.loads((tiny_run / "summary.json").read_text())
    assert summary["iterations_done"] == 4 and summary["timings"]["iterations"] == 4
    assert SavedRun.open(str(tiny_run)).iteration == 4
