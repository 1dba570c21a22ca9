"""One writer per run directory: a second run or resume on a directory a live process writes is
refused at once, naming that process; the lock goes when its holder ends, even by SIGKILL."""

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
