"""Checkpoints and resume: a resumed run reproduces the straight run to the bit, also after a
write that failed (full disk, read-only directory: one line and exit 2) and after SIGKILLs at
random moments."""

import json
import os
import random
import signal
import subprocess
import sys
import time

import pytest

from emgail_jax import run
from emgail_jax.host import checkpoints, records

pytestmark = pytest.mark.heavy

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


def _same_results(a, b):
    assert (a / "metrics.csv").read_text() == (b / "metrics.csv").read_text()
    first = json.loads((a / "summary.json").read_text())["final"]
    second = json.loads((b / "summary.json").read_text())["final"]
    for key in ("erd", "erd_per_intention", "cluster_accuracy", "returns"):
        assert first[key] == second[key], key


def test_resume_gives_the_straight_run_bit_for_bit(straight_and_resumed):
    _same_results(*straight_and_resumed)


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
    assert err.startswith("error: ") and "\n" not in err and "Traceback" not in err, err
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


def _with_a_damaged_checkpoint(run_dir, tmp_path):
    """A copy of ``run_dir`` whose newest checkpoint's array data are cut to nothing."""
    import shutil

    broken = tmp_path / "broken"
    shutil.copytree(run_dir, broken)
    step = broken / "checkpoints" / "8" / "state"
    for root, _, files in os.walk(step):
        for name in files:
            if name not in ("_METADATA", "commit_success.txt"):
                open(os.path.join(root, name), "wb").close()  # truncate the array data
    return broken


# Orbax's reads under way when one fails would each print a traceback around the one-line error.
@pytest.mark.filterwarnings("error::pytest.PytestUnraisableExceptionWarning")
def test_corrupt_checkpoint_is_reported(straight_and_resumed, tmp_path, capsys):
    straight, _ = straight_and_resumed
    broken = _with_a_damaged_checkpoint(straight, tmp_path)
    summary_before = (broken / "summary.json").read_text()
    assert run.main(["--resume", str(broken), "--iterations", "10", "--quiet"]) == 2
    assert "cannot be read" in _one_line_error(capsys)
    assert (broken / "summary.json").read_text() == summary_before


def test_corrupt_checkpoint_is_one_line_on_stderr_to_the_processs_end(
    straight_and_resumed, tmp_path
):
    """What orbax's other reads report as they finish or are collected, up to the process's exit
    (where the test above cannot look), stays off stderr: the one error line is all of it."""
    straight, _ = straight_and_resumed
    broken = _with_a_damaged_checkpoint(straight, tmp_path)
    command = [sys.executable, "-m", "emgail_jax.run", "--resume", str(broken), "--quiet"]
    done = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "cannot be read" in lines[0], done.stderr


@pytest.mark.slow  # end to end (make test-slow); cheaper tests cover its parts
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
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
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


ITERATIONS = 8
FULL_DISK = OSError(28, "No space left on device")


@pytest.fixture(scope="module")
def straight(straight_and_resumed):
    return straight_and_resumed[0]


def _failing_at_call(monkeypatch, module, name, failing_call: int):
    """``module.name`` raising a full disk on its ``failing_call``-th call (from 1)."""
    real, calls = getattr(module, name), []

    def write(*args, **kwargs):
        calls.append(args)
        if len(calls) == failing_call:
            raise FULL_DISK
        return real(*args, **kwargs)

    monkeypatch.setattr(module, name, write)


def _fails_then_resumes(monkeypatch, capsys, out, straight, module, name, failing_call, what):
    _failing_at_call(monkeypatch, module, name, failing_call)
    assert run.main([*TINY, "--iterations", str(ITERATIONS), "--out", str(out)]) == 2
    err = _one_line_error(capsys)
    assert "No space left on device" in err and what in err
    monkeypatch.undo()
    assert run.main(["--resume", str(out), "--quiet"]) == 0
    _same_results(straight, out)


def test_a_full_disk_while_a_checkpoint_is_written(tmp_path, straight, capsys, monkeypatch):
    # The orbax write itself fails, on the second checkpoint: the first one stays and resumes.
    import orbax.checkpoint as ocp

    real_save, saves = ocp.CheckpointManager.save, []

    def save(manager, step, *args, **kwargs):
        saves.append(step)
        if len(saves) == 2:
            raise ValueError("RESOURCE_EXHAUSTED: Error writing: No space left on device")
        return real_save(manager, step, *args, **kwargs)

    monkeypatch.setattr(ocp.CheckpointManager, "save", save)
    out = tmp_path / "run"
    assert run.main([*TINY, "--iterations", str(ITERATIONS), "--out", str(out)]) == 2
    err = _one_line_error(capsys)
    assert "checkpoint of iteration 4 could not be written" in err and "--resume" in err
    assert checkpoints.latest_iteration(str(out)) == 2
    monkeypatch.undo()
    assert run.main(["--resume", str(out), "--quiet"]) == 0
    _same_results(straight, out)


def test_a_full_disk_while_metrics_csv_is_written(tmp_path, straight, capsys, monkeypatch):
    # The third chunk's rows (after the checkpoint of iteration 4).
    _fails_then_resumes(
        monkeypatch, capsys, tmp_path / "run", straight, records.MetricsLog, "write", 3, ""
    )


def test_a_full_disk_while_summary_json_is_written(tmp_path, straight, capsys, monkeypatch):
    # The final summary, after the last checkpoint.
    _fails_then_resumes(
        monkeypatch, capsys, tmp_path / "run", straight, records, "write_json", 2, ""
    )


def test_a_run_killed_before_its_first_checkpoint_resumes_from_the_start(tmp_path, straight):
    import shutil

    out = tmp_path / "early"
    shutil.copytree(straight, out)
    shutil.rmtree(out / "checkpoints")
    summary = json.loads((out / "summary.json").read_text())
    records.write_json(str(out / "summary.json"), {**summary, "status": "running"})
    header, first_row = (out / "metrics.csv").read_text().splitlines()[:2]
    (out / "metrics.csv").write_text(f"{header}\n{first_row[:7]}")  # killed mid-row
    assert run.main(["--resume", str(out), "--quiet"]) == 0
    _same_results(straight, out)


def _kill_and_resume(straight, out, kills: int, seed: int):
    """Runs the straight run's command in a child, SIGKILLs it ``kills`` times at random
    moments of its life (start-up, compiles, chunks, checkpoint writes), each time continuing
    with --resume (or the first command again, if the kill came before the run wrote its
    summary), then lets it finish."""
    python = [sys.executable, "-m", "emgail_jax.run"]
    first = [*python, *TINY, "--iterations", str(ITERATIONS), "--out", str(out)]
    # How long one uninterrupted child takes, to draw the moments from.
    start = time.monotonic()
    subprocess.run([*first[:-1], str(out) + "-timing"], check=True, timeout=600)
    lifetime = time.monotonic() - start
    rng = random.Random(seed)
    killed = 0
    while True:
        resumable = (out / "summary.json").exists()
        command = [*python, "--resume", str(out), "--quiet"] if resumable else first
        child = subprocess.Popen(command, stderr=subprocess.PIPE, text=True)
        if killed < kills:
            try:
                child.wait(timeout=rng.uniform(0.5, lifetime))
            except subprocess.TimeoutExpired:
                child.kill()
                child.wait()
                killed += 1
                continue
        _, err = child.communicate(timeout=600)
        assert child.returncode == 0, err[-3000:]
        if killed >= kills:
            break
    _same_results(straight, out)


@pytest.mark.slow  # 1-4 minutes: three children and two resumes
def test_sigkills_at_random_moments_then_resume_give_the_straight_run(tmp_path, straight):
    _kill_and_resume(straight, tmp_path / "killed", kills=2, seed=0)


@pytest.mark.slow
def test_twenty_sigkills_then_resume_give_the_straight_run(tmp_path, straight):
    _kill_and_resume(straight, tmp_path / "killed", kills=20, seed=1)
