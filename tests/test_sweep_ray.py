"""The sweep's Ray engine (``experiments/sweep.py --engine ray``) on real Ray clusters of two
nodes on this machine: the same cells, outputs and results as the local engine, and a cell whose
node is lost resumed on the other from its checkpoint. Each test starts its own cluster and ends
it through its handle (never ``ray stop``, which would end every Ray process on the machine); the
sweeps run in child processes, so that no wait outlasts its timeout."""

import contextlib
import json
import os
import pathlib
import re
import subprocess
import sys
import time

import pytest

from emgail_jax.host.checkpoints import latest_iteration

pytest.importorskip("ray")
from ray.cluster_utils import Cluster

REPO = pathlib.Path(__file__).resolve().parents[1]
TIMEOUT_S = 600  # a sweep of tiny driver cells takes a minute or two here, compiles included
# The workers import this checkout, as every node of a real cluster must.
ENV = {**os.environ, "PYTHONPATH": str(REPO)}
TIMINGS = ("compile_time_s", "train_time_s", "iteration_time_s")  # every process its own


@contextlib.contextmanager
def _cluster(head_cpus: int, node_cpus: tuple[int, ...]):
    """A head node and worker nodes of ``node_cpus`` CPUs each, all on this machine (at its own
    address, which Ray uses even when asked for 127.0.0.1)."""
    checkout = {"env_vars": {"PYTHONPATH": str(REPO)}}
    cluster = Cluster()
    try:
        cluster.add_node(num_cpus=head_cpus, **checkout)  # its GCS on a free port
        for cpus in node_cpus:
            cluster.add_node(num_cpus=cpus, **checkout)
        cluster.wait_for_nodes(timeout=120)
        yield cluster
    finally:
        cluster.shutdown()


def _sweep(out, only: str, iterations: int, *engine: str) -> list[str]:
    return [
        *(sys.executable, str(REPO / "experiments" / "sweep.py"), "--only", only),
        *("--seeds", "1", "--iterations", str(iterations), "--out", str(out), *engine),
    ]


def _run(command: list[str]) -> None:
    done = subprocess.run(command, env=ENV, capture_output=True, text=True, timeout=TIMEOUT_S)
    assert done.returncode == 0, done.stderr[-3000:]


def _nodes_in(log: pathlib.Path) -> list[str]:
    """The Ray nodes that took the cell, in order (the Ray engine writes one line each)."""
    return re.findall(r"^# on Ray node (\w+)$", log.read_text(), flags=re.MULTILINE)


def _assert_same_results(cell: str, ray_out: pathlib.Path, local_out: pathlib.Path) -> None:
    runs = [out / "runs" / cell for out in (ray_out, local_out)]
    assert (runs[0] / "metrics.csv").read_bytes() == (runs[1] / "metrics.csv").read_bytes()
    finals = [json.loads((run / "summary.json").read_text())["final"] for run in runs]
    for final in finals:
        for timing in TIMINGS:
            final.pop(timing)
    assert finals[0] == finals[1]
    assert finals[0]["erd"]  # there is something to compare


@pytest.mark.slow  # a Ray cluster of two nodes started and a sweep run twice: 40 s of the suite
def test_sweep_on_a_two_node_ray_cluster_equals_the_local_engine(tmp_path):
    """Two tiny cells at once, one a node (a CPU each, a cell reserving its seed's one): the
    cells' runs and the report are the local engine's."""
    cells = ("driver-r20-emgail", "driver-r10-gail")
    only = ",".join(cells)
    _run(_sweep(tmp_path / "local", only, 3))
    with _cluster(1, (1,)) as cluster:
        address = ("--engine", "ray", "--ray-address", cluster.address)
        _run(_sweep(tmp_path / "ray", only, 3, *address))
        node_ids = {node.node_id for node in cluster.list_all_nodes()}

        # A cell asking for more than a node has is refused before anything runs.
        too_big = subprocess.run(
            [*_sweep(tmp_path / "too-big", only, 3, *address), "--cpus-per-cell", "2"],
            env=ENV, capture_output=True, text=True, timeout=TIMEOUT_S,
        )  # fmt: skip
    assert too_big.returncode == 2
    assert too_big.stderr.strip().splitlines()[-1] == (
        "error: a cell cannot reserve 2 CPUs and 0 GPUs: the cluster's largest node has 1 and "
        "0; lower --cpus-per-cell or --gpus-per-cell"
    )
    assert not (tmp_path / "too-big" / "runs").exists()

    ran_on = [_nodes_in(tmp_path / "ray" / "logs" / f"{cell}.log") for cell in cells]
    assert sorted(nodes[0] for nodes in ran_on) == sorted(node_ids)  # one cell on each node
    for cell in cells:
        _assert_same_results(cell, tmp_path / "ray", tmp_path / "local")
    for report in ("fig5a.csv", "table3.csv", "separability.csv"):
        written = [(tmp_path / out / report).read_bytes() for out in ("ray", "local")]
        assert written[0] == written[1], report


def _wait_for(condition, what: str, timeout_s: float = TIMEOUT_S):
    deadline = time.monotonic() + timeout_s
    while not (value := condition()):
        assert time.monotonic() < deadline, f"no {what} after {timeout_s} s"
        time.sleep(0.2)
    return value


@pytest.mark.slow  # 200 iterations twice and a third node: the suite's slowest test (2 min)
def test_sweep_on_ray_resumes_a_cell_whose_node_was_lost(tmp_path):
    """The node running a cell is killed after the cell's first checkpoint (iteration 50): Ray
    retries the cell on the other node, which resumes it from that checkpoint, and the cell's
    outputs are those of an uninterrupted run."""
    cell, iterations = "driver-r20-gail", 200
    run_dir = tmp_path / "ray" / "runs" / cell
    log = tmp_path / "ray" / "logs" / f"{cell}.log"
    output = tmp_path / "sweep.out"
    with _cluster(0, (1, 1)) as cluster, output.open("w") as sweep_output:
        command = _sweep(tmp_path / "ray", cell, iterations, "--engine", "ray")
        sweep = subprocess.Popen(
            [*command, "--ray-address", cluster.address],
            env=ENV, stdout=sweep_output, stderr=subprocess.STDOUT,
        )  # fmt: skip
        try:
            first = _wait_for(lambda: log.exists() and _nodes_in(log), "Ray node in the log")[0]
            _wait_for(lambda: latest_iteration(str(run_dir)), "checkpoint")
            summary = json.loads((run_dir / "summary.json").read_text())
            assert summary["status"] == "running", "the cell ended before its node was lost"
            (node,) = [n for n in cluster.worker_nodes if n.node_id == first]
            cluster.remove_node(node, allow_graceful=False)
            sweep.wait(timeout=TIMEOUT_S)
        finally:
            if sweep.poll() is None:
                sweep.kill()
                sweep.wait(timeout=60)
    assert sweep.returncode == 0, output.read_text()[-3000:]
    nodes = _nodes_in(log)
    assert len(nodes) == 2 and nodes[0] == first != nodes[1]
    retried = log.read_text().split(f"# on Ray node {nodes[1]}")[1]
    assert f"--resume {run_dir} --iterations {iterations}" in retried

    _run(_sweep(tmp_path / "local", cell, iterations))
    _assert_same_results(cell, tmp_path / "ray", tmp_path / "local")
