"""The table a run prints at its end, from its summary.json."""

import json
import pathlib

from emgail_jax.host.summary_table import print_summary

RUNS = pathlib.Path(__file__).resolve().parent.parent / "results" / "runs"


def _printed(capsys, name: str) -> str:
    summary = json.loads((RUNS / name / "summary.json").read_text())
    print_summary(summary)
    return capsys.readouterr().out


def test_a_row_per_seed_with_its_final_numbers(capsys):
    summary = json.loads((RUNS / "driver-r4-emgail" / "summary.json").read_text())
    out = _printed(capsys, "driver-r4-emgail")
    assert f"mean of the last 10 of {summary['iterations_done']} iterations" in out
    final = summary["final"]
    for seed in range(summary["seeds"]):
        assert f"{final['erd'][seed]:.3f}" in out
        assert f"{final['cluster_accuracy'][seed]:.3f}" in out
        assert " ".join(str(n) for n in final["demonstrations_held"][seed]) in out
    assert "demos held" in out and "K chosen" not in out


def test_a_run_choosing_k_shows_the_k_chosen(capsys):
    name = next(p.parent.name for p in sorted(RUNS.glob("*-auto/summary.json")))
    out = _printed(capsys, name)
    assert "K chosen" in out and "demos held" not in out  # summaries older than the column


def test_gail_has_no_accuracy(capsys):
    name = next(p.parent.name for p in sorted(RUNS.glob("*-gail/summary.json")))
    summary = json.loads((RUNS / name / "summary.json").read_text())
    assert summary["final"]["cluster_accuracy"] is None
    out = _printed(capsys, name)
    assert f"{summary['final']['erd'][0]:.3f}" in out and " - " in out
