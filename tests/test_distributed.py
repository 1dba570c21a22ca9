"""A run spread over two processes (jax.distributed on 127.0.0.1, one CPU device each) gives the
final metrics of the same run in one process, and process 0 alone writes the run directory."""

import json
import os
import socket
import subprocess
import sys

import pytest

from emgail_jax import run
from emgail_jax.host import jax_setup

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


def _environment(devices: int) -> dict:
    cache = os.path.join(os.path.dirname(os.path.dirname(__file__)), ".cache", "jax")
    count = "--xla_force_host_platform_device_count"
    inherited = [f for f in os.environ.get("XLA_FLAGS", "").split() if not f.startswith(count)]
    flags = " ".join([*inherited, f"{count}={devices}"])
    return {**os.environ, "XLA_FLAGS": flags, "JAX_COMPILATION_CACHE_DIR": cache}


def test_two_processes_give_the_one_process_results(tmp_path):
    one = tmp_path / "one"  # in this process, whose two host devices the conftest made
    assert run.main([*TINY, "--out", str(one)]) == 0
    command = [sys.executable, "-m", "emgail_jax.run", *TINY]

    two = tmp_path / "two"
    coordinator = f"127.0.0.1:{_free_port()}"
    processes = [
        subprocess.Popen(
            [
                *command,
                "--out",
                str(two),
                "--coordinator",
                coordinator,
                "--num-processes",
                "2",
                "--process-id",
                str(i),
            ],
            env=_environment(1),
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
        )
        for i in range(2)
    ]
    outputs = [p.communicate(timeout=600) for p in processes]
    for process, (_, err) in zip(processes, outputs, strict=True):
        lines = [line for line in err.decode().splitlines() if not line.startswith("    @")]
        assert process.returncode == 0, "\n".join(lines[-40:])

    a = json.loads((one / "summary.json").read_text())
    b = json.loads((two / "summary.json").read_text())
    assert b["processes"] == 2 and len(b["devices"]) == 2
    for key in ("erd", "erd_per_intention", "cluster_accuracy", "returns"):
        assert a["final"][key] == b["final"][key], key
    assert (one / "metrics.csv").read_text() == (two / "metrics.csv").read_text()


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
