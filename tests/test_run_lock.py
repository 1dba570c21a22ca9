"""One writer per run directory: a second run or resume on a directory a live process writes is
refused at once, naming that process; the lock goes when its holder ends, even by SIGKILL."""

import errno
import json
import os
import signal
import socket
import subprocess
import sys
import time

import pytest

from emgail_jax import run
from emgail_jax.host import run_lock
from emgail_jax.host.run_spec import RunError

TINY = ["--env", "driver", "--seeds", "2", "--iterations", "2", "--quiet"]


@pytest.fixture
def holder(tmp_path):
    """Another process holding ``tmp_path/held``'s lock until it is killed."""
    held = tmp_path / "held"
    held.mkdir()
    code = (
        "import sys, time\n"
        "from emgail_jax.host import run_lock\n"
        "with run_lock.hold(sys.argv[1]):\n"
        "    print('held', flush=True)\n"
        "    time.sleep(600)\n"
    )
    process = subprocess.Popen(
        [sys.executable, "-c", code, str(held)], stdout=subprocess.PIPE, text=True
    )
    assert process.stdout.readline().strip() == "held"
    yield held, process
    process.kill()
    process.wait()


def test_a_second_holder_is_refused_with_the_first_ones_pid_and_host(tmp_path):
    with run_lock.hold(str(tmp_path)):
        with pytest.raises(RunError) as error, run_lock.hold(str(tmp_path)):
            pass
        message = str(error.value)
        assert f"pid {os.getpid()} on {socket.gethostname()}" in message
        assert "\n" not in message
    with run_lock.hold(str(tmp_path)):  # released on leaving the block
        pass


def test_a_run_or_resume_on_a_directory_another_process_writes_is_refused(holder, capsys):
    held, process = holder
    (held / "summary.json").write_text("{}")
    for argv in ([*TINY, "--out", str(held), "--overwrite"], ["--resume", str(held)]):
        start = time.monotonic()
        assert run.main(argv) == 2
        assert time.monotonic() - start < 5
        err = capsys.readouterr().err.strip()
        assert err.startswith("error: ") and "\n" not in err
        assert f"pid {process.pid} on {socket.gethostname()}" in err
    assert sorted(os.listdir(held)) == [run_lock.LOCK_NAME, "summary.json"]
    assert (held / "summary.json").read_text() == "{}"


def test_the_lock_is_released_when_its_holder_is_killed(holder):
    held, process = holder
    with pytest.raises(RunError), run_lock.hold(str(held)):
        pass
    process.send_signal(signal.SIGKILL)
    process.wait()
    with run_lock.hold(str(held)):
        pass


def test_a_refused_new_run_leaves_no_directory(tmp_path, capsys):
    out = tmp_path / "new"
    assert run.main([*TINY, "--env", "nope", "--out", str(out)]) == 2
    assert run.main([*TINY, "--radius", "0.1", "--out", str(out)]) == 2  # fails after the lock
    assert not out.exists()


def _main_in_a_new_process(*argv: str) -> subprocess.CompletedProcess:
    """``run.main(argv)`` in a fresh interpreter, which prints whether JAX was imported."""
    code = (
        "import sys\n"
        "from emgail_jax import run\n"
        "code = run.main(sys.argv[1:])\n"
        "print('jax imported' if 'jax' in sys.modules else 'no jax')\n"
        "sys.exit(code)\n"
    )
    return subprocess.run(
        [sys.executable, "-c", code, *argv], capture_output=True, text=True, timeout=60
    )


def test_a_refused_command_ends_before_jax_starts(holder):
    held, process = holder
    locked = _main_in_a_new_process(*TINY, "--out", str(held), "--overwrite")
    unshared = _main_in_a_new_process(
        *TINY[:2], "--seeds", "1", "--coordinator", "127.0.0.1:1", "--num-processes", "2",
        "--process-id", "0",
    )  # fmt: skip
    for refused in (locked, unshared):
        assert refused.returncode == 2, refused.stderr
        assert refused.stdout.strip() == "no jax"
        assert len(refused.stderr.strip().splitlines()) == 1
    assert f"pid {process.pid}" in locked.stderr


def test_evaluate_and_reoptimize_refuse_a_directory_a_live_run_writes(holder, capsys):
    from emgail_jax import evaluate, reoptimize

    held, process = holder
    for main in (evaluate.main, reoptimize.main):
        assert main([str(held)]) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith(f"error: '{held}' is being written by a run") and "\n" not in err
        assert f"pid {process.pid} on {socket.gethostname()}" in err
    assert sorted(os.listdir(held)) == [run_lock.LOCK_NAME]


def test_readers_share_the_lock_and_keep_a_writer_out(tmp_path):
    where = str(tmp_path)
    refused = pytest.raises(RunError, match="written or read by another process")
    with run_lock.reading(where), run_lock.reading(where), refused, run_lock.hold(where):
        pass
    refused = pytest.raises(RunError, match="being written by a run")
    with run_lock.hold(where), refused, run_lock.reading(where):
        pass


def test_a_directory_that_cannot_be_written_is_read_unguarded(tmp_path, monkeypatch):
    def read_only(path, flags, mode=0o777):
        raise OSError(errno.EROFS, "Read-only file system", path)

    monkeypatch.setattr(run_lock.os, "open", read_only)
    with run_lock.reading(str(tmp_path)):
        assert os.listdir(tmp_path) == []
    with pytest.raises(OSError), run_lock.hold(str(tmp_path)):  # a writer needs to write
        pass


@pytest.mark.slow  # two runs of 20 iterations, one of them in a child process
def test_a_refused_run_leaves_the_live_run_as_it_would_have_been(tmp_path, capsys):
    options = [*TINY[:4], "--iterations", "20", "--chunk-size", "2", "--quiet"]
    straight, live = tmp_path / "straight", tmp_path / "live"
    assert run.main([*options, "--out", str(straight)]) == 0
    command = [sys.executable, "-m", "emgail_jax.run", *options, "--out", str(live)]
    child = subprocess.Popen(command, stderr=subprocess.PIPE, text=True)
    while not (live / "summary.json").exists():
        assert child.poll() is None, child.stderr.read()
        time.sleep(0.1)
    capsys.readouterr()
    for argv in ([*options, "--out", str(live), "--overwrite"], ["--resume", str(live)]):
        start = time.monotonic()
        assert run.main(argv) == 2
        assert time.monotonic() - start < 5
        assert f"pid {child.pid} on" in capsys.readouterr().err
    _, err = child.communicate(timeout=600)
    assert child.returncode == 0, err[-2000:]
    assert (live / "metrics.csv").read_text() == (straight / "metrics.csv").read_text()
    finals = [json.loads((d / "summary.json").read_text())["final"] for d in (straight, live)]
    assert finals[0]["erd"] == finals[1]["erd"]
    assert finals[0]["cluster_accuracy"] == finals[1]["cluster_accuracy"]
