"""A run spread over two processes (jax.distributed on 127.0.0.1, started as the README says,
each with the devices jax_setup gives it) gives the final metrics of the same run in one
process, and process 0 alone writes the run directory; seeds the processes cannot share, a
process that fails or is killed, and a signal to one process end them all within bounded time."""

import json
import os
import signal
import socket
import subprocess
import sys
import time

import pytest

from emgail_jax import run
from emgail_jax.host import jax_setup

pytestmark = pytest.mark.heavy

TINY = [
    "--env", "driver",
    "--seeds", "2",
    "--iterations", "4",
    "--chunk-size", "2",
    "--num-envs", "2",
    "--rollout-length", "20",
    "--quiet",
]  # fmt: skip


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _environment() -> dict:
    """This process's environment without the conftest's device count: each process splits the
    CPU as jax_setup does for a user (one device per core, here 2 for each of 2 processes)."""
    count = "--xla_force_host_platform_device_count"
    inherited = [f for f in os.environ.get("XLA_FLAGS", "").split() if not f.startswith(count)]
    return {**os.environ, "XLA_FLAGS": " ".join(inherited)}


def _start_two(out, *options) -> list[subprocess.Popen]:
    """The README's command, once per process."""
    coordinator = f"127.0.0.1:{_free_port()}"
    return [
        subprocess.Popen(
            [
                *(sys.executable, "-m", "emgail_jax.run", *options, "--out", str(out)),
                *("--coordinator", coordinator, "--num-processes", "2", "--process-id", str(i)),
            ],
            env=_environment(),
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for i in range(2)
    ]


def _error_lines(err: str) -> list[str]:
    return [line for line in err.splitlines() if line.startswith("error: ")]


@pytest.mark.slow  # two processes compiling the run cold (the failure paths below stay in CI)
def test_two_processes_give_the_one_process_results(tmp_path):
    one = tmp_path / "one"  # in this process, whose two host devices the conftest made
    assert run.main([*TINY, "--out", str(one)]) == 0

    two = tmp_path / "two"
    processes = _start_two(two, *TINY)
    outputs = [p.communicate(timeout=600) for p in processes]
    for process, (_, err) in zip(processes, outputs, strict=True):
        lines = [line for line in err.splitlines() if not line.startswith("    @")]
        assert process.returncode == 0, "\n".join(lines[-40:])

    a = json.loads((one / "summary.json").read_text())
    b = json.loads((two / "summary.json").read_text())
    assert b["processes"] == 2 and len(b["devices"]) == 2
    for key in ("erd", "erd_per_intention", "cluster_accuracy", "returns"):
        assert a["final"][key] == b["final"][key], key
    assert (one / "metrics.csv").read_text() == (two / "metrics.csv").read_text()


def test_seeds_the_processes_cannot_share_are_refused_by_each_in_one_line(tmp_path):
    start = time.monotonic()
    processes = _start_two(tmp_path / "one-seed", *TINY[:2], "--seeds", "1", *TINY[4:])
    for process in processes:
        _, err = process.communicate(timeout=60)
        assert process.returncode == 2, err[-2000:]
        assert _error_lines(err) == [
            "error: --seeds 1 cannot be shared equally by 2 processes: give a multiple of 2 seeds"
        ]
    assert time.monotonic() - start < 90  # 11 s on an idle 2-core machine; bounded, not a hang
    assert not (tmp_path / "one-seed").exists()


LONG = [*TINY[:4], "--iterations", "400", "--checkpoint-every", "2", *TINY[6:]]


def _training_after_a_signal(out, sig, to: int, timeout=300) -> list[subprocess.Popen]:
    """A long run of two processes, sent ``sig`` to process ``to`` once it has checkpointed."""
    processes = _start_two(out, *LONG)
    deadline = time.monotonic() + timeout
    while not (out / "checkpoints").is_dir():
        assert time.monotonic() < deadline and all(p.poll() is None for p in processes)
        time.sleep(0.5)
    processes[to].send_signal(sig)
    return processes


@pytest.mark.slow
@pytest.mark.parametrize("killed", [1, 0])  # process 0 holds the coordination service
def test_a_killed_process_ends_the_other_naming_it(tmp_path, killed):
    processes = _training_after_a_signal(tmp_path / "killed", signal.SIGKILL, to=killed)
    start = time.monotonic()
    _, err = processes[1 - killed].communicate(timeout=90)
    processes[killed].wait()
    assert time.monotonic() - start < 60
    assert processes[1 - killed].returncode not in (0, None)
    lines = _error_lines(err)
    # Whichever notices first (a collective, the peer watch, the service) names the peer.
    assert len(lines) == 1 and f"process {killed} " in lines[0], err[-2000:]
    assert "Check failure stack trace" not in err


@pytest.mark.slow
def test_a_signal_to_one_process_stops_both_with_a_checkpoint(tmp_path):
    out = tmp_path / "stopped"
    for process in _training_after_a_signal(out, signal.SIGTERM, to=1):
        process.communicate(timeout=60)
        assert process.returncode == 130
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "interrupted" and summary["stopped_by"] == "SIGTERM"
    assert 0 < summary["iterations_done"] < 400


@pytest.mark.parametrize(
    ("options", "message"),
    [
        (("127.0.0.1:1234", None, 0), "needs --coordinator HOST:PORT, --num-processes N"),
        (("localhost", 2, 0), "must be HOST:PORT"),
        (("127.0.0.1:1234", 2, 2), "0 <= --process-id < --num-processes"),
    ],
)
def test_incomplete_distributed_options_are_refused(options, message, monkeypatch):
    for name in ("JAX_COORDINATOR_ADDRESS", "JAX_NUM_PROCESSES", "JAX_PROCESS_ID"):
        monkeypatch.delenv(name, raising=False)
    with pytest.raises(ValueError, match=message):
        jax_setup.Distributed.from_options(*options)


def test_distributed_options_from_jax_environment_variables(monkeypatch):
    monkeypatch.setenv("JAX_COORDINATOR_ADDRESS", "10.0.0.1:7777")
    monkeypatch.setenv("JAX_NUM_PROCESSES", "4")
    monkeypatch.setenv("JAX_PROCESS_ID", "3")
    assert jax_setup.Distributed.from_options(None, None, None) == jax_setup.Distributed(
        "10.0.0.1:7777", 4, 3
    )
    monkeypatch.delenv("JAX_COORDINATOR_ADDRESS")
    monkeypatch.delenv("JAX_NUM_PROCESSES")
    monkeypatch.delenv("JAX_PROCESS_ID")
    assert jax_setup.Distributed.from_options(None, None, None) is None
