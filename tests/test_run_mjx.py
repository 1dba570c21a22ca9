"""An MJX env through the whole tool: a tiny EM-GAIL run on the swimmer's shipped
demonstrations (the MJX env that compiles fastest), checkpointed, resumed and evaluated (the
driver covers the rest in detail)."""

import json
import math

import pytest

from emgail_jax import evaluate, run
from emgail_jax.host import checkpoints

pytestmark = pytest.mark.heavy

TINY = [
    "--env", "swimmer",
    "--intentions", "2",
    "--seeds", "2",
    "--num-envs", "2",
    "--rollout-length", "10",
    "--chunk-size", "1",
    "--checkpoint-every", "1",
    "--random-episodes", "2",  # ERD's random reference: 2 swimmer episodes, not 50
    "--quiet",
]  # fmt: skip


@pytest.fixture(scope="module")
def resumed_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("swimmer") / "emgail"
    assert run.main([*TINY, "--iterations", "2", "--out", str(out)]) == 0
    # Two chunks after the resume: the restored state must fit the program the run compiled.
    assert run.main(["--resume", str(out), "--iterations", "4", "--quiet"]) == 0
    return out


@pytest.mark.slow  # an MJX run compiled cold (test_run covers the tool, test_envs_mjx the envs)
def test_an_mjx_run_checkpoints_and_resumes(resumed_run):
    summary = json.loads((resumed_run / "summary.json").read_text())
    assert summary["status"] == "completed" and summary["iterations_done"] == 4
    assert summary["random_episodes"] == 2  # the resumed run kept the run's setting
    assert checkpoints.latest_iteration(str(resumed_run)) == 4
    final = summary["final"]
    assert len(final["erd"]) == 2 and all(math.isfinite(erd) for erd in final["erd"])
    assert all(0.5 <= accuracy <= 1.0 for accuracy in final["cluster_accuracy"])
    rows = (resumed_run / "metrics.csv").read_text().strip().splitlines()
    assert len(rows) == 1 + 4 * 2  # header, then 4 iterations x 2 seeds


@pytest.mark.slow  # evaluate compiles its own episodes of the swimmer: 50-100 s
def test_evaluate_draws_the_x_position_over_time(resumed_run):
    assert evaluate.main([str(resumed_run), "--episodes", "1"]) == 0
    figures = sorted(p.name for p in (resumed_run / "figures").glob("*.png"))
    assert "learning_curves.png" in figures and len(figures) >= 2, figures
    assert all((resumed_run / "figures" / name).stat().st_size > 1000 for name in figures)
