"""Checkpoints and resume: a resumed run reproduces the straight run to the bit."""

import json
import os
import signal
import subprocess
import sys
import time

import pytest

from emgail_jax import run
from emgail_jax.host import checkpoints

TINY = [
    "--env", "driver",
    "--seeds", "2",
    "--num-envs", "2",
    "--rollout-length", "20",
    "--chunk-size", "2",
    "--checkpoint-every", "2",
    "--snapshot-every", "4",
    "--quiet",
]  # fmt: skip


@pytest.fixture(scope="module")
def straight_and_resumed(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("resume")
    straight, resumed = tmp / "straight", tmp / "resumed"
    assert run.main([*TINY, "--iterations", "8", "--out", str(straight)]) == 0
    assert run.main([*TINY, "--iterations", "4", "--out", str(resumed)]) == 0
    assert run.main(["--resume", str(resumed), "--iterations", "8", "--quiet"]) == 0
    return straight, resumed


def test_resume_gives_the_straight_run_bit_for_bit(straight_and_resumed):
    straight, resumed = straight_and_resumed
    assert (straight / "metrics.csv").read_text() == (resumed / "metrics.csv").read_text()
    a = json.loads((straight / "summary.json").read_text())["final"]
    b = json.loads((resumed / "summary.json").read_text())["final"]
    for key in ("erd", "cluster_accuracy", "returns"):
        assert a[key] == b[key], key


def test_snapshots_survive_a_resume_bit_for_bit(straight_and_resumed):
    straight, resumed = straight_and_resumed
    assert checkpoints.snapshot_iterations(str(straight)) == [4, 8]
    assert checkpoints.snapshot_iterations(str(resumed)) == [4, 8]
    for name in ("iteration_000004.msgpack", "iteration_000008.msgpack"):
        assert (straight / "snapshots" / name).read_bytes() == (
            resumed / "snapshots" / name
        ).read_bytes()


def test_resumed_summary_accumulates(straight_and_resumed):
    _, resumed = straight_and_resumed
    summary = json.loads((resumed / "summary.json").read_text())
    assert summary["status"] == "completed"
    assert summary["iterations"] == 8 and summary["iterations_done"] == 8
    assert summary["timings"]["iterations"] == 8
    assert checkpoints.latest_iteration(str(resumed)) == 8


def test_resume_of_a_finished_run_changes_nothing(straight_and_resumed, capsys):
    _, resumed = straight_and_resumed
    before = (resumed / "metrics.csv").read_text()
    assert run.main(["--resume", str(resumed), "--quiet"]) == 0
    assert (resumed / "metrics.csv").read_text() == before


def _one_line_error(capsys):
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err
    return err


def test_resume_refuses_other_settings(straight_and_resumed, capsys):
    _, resumed = straight_and_resumed
    assert run.main(["--resume", str(resumed), "--algo", "gail"]) == 2
    assert "drop --algo" in _one_line_error(capsys)


def test_resume_without_a_run_or_checkpoint(straight_and_resumed, tmp_path, capsys):
    assert run.main(["--resume", str(tmp_path)]) == 2
    assert "no summary.json" in _one_line_error(capsys)
    (tmp_path / "summary.json").write_text("{}")
    assert run.main(["--resume", str(tmp_path)]) == 2
    assert "does not describe a run" in _one_line_error(capsys)
    straight, _ = straight_and_resumed
    (tmp_path / "summary.json").write_text((straight / "summary.json").read_text())
    assert run.main(["--resume", str(tmp_path)]) == 2
    assert "no checkpoint" in _one_line_error(capsys)


def test_corrupt_checkpoint_is_reported(straight_and_resumed, tmp_path, capsys):
    import shutil

    straight, _ = straight_and_resumed
    broken = tmp_path / "broken"
    shutil.copytree(straight, broken)
    step = broken / "checkpoints" / "8" / "state"
    for root, _, files in os.walk(step):
        for name in files:
            if name not in ("_METADATA", "commit_success.txt"):
                open(os.path.join(root, name), "wb").close()  # truncate the array data
    summary_before = (broken / "summary.json").read_text()
    assert run.main(["--resume", str(broken), "--iterations", "10", "--quiet"]) == 2
    assert "cannot be read" in _one_line_error(capsys)
    assert (broken / "summary.json").read_text() == summary_before


def test_sigterm_leaves_a_valid_checkpoint_and_an_interrupted_summary(tmp_path):
    out = tmp_path / "interrupted"
    command = [
        sys.executable,
        "-m",
        "emgail_jax.run",
        *TINY,
        "--iterations",
        "400",
        "--out",
        str(out),
    ]
    cache = os.path.join(os.path.dirname(os.path.dirname(__file__)), ".cache", "jax")
    env = {**os.environ, "JAX_COMPILATION_CACHE_DIR": cache}
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    deadline = time.time() + 240
    while checkpoints.latest_iteration(str(out)) is None and time.time() < deadline:
        time.sleep(0.5)
    process.send_signal(signal.SIGTERM)
    assert process.wait(timeout=120) == 130
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "interrupted" and summary["stopped_by"] == "SIGTERM"
    done = summary["iterations_done"]
    assert 0 < done < 400 and checkpoints.latest_iteration(str(out)) == done
    # The interrupted run resumes (here to a shorter total, so the test stays quick).
    assert run.main(["--resume", str(out), "--iterations", str(done + 2), "--quiet"]) == 0
    assert json.loads((out / "summary.json").read_text())["status"] == "completed"
