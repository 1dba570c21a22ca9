"""What a run leaves on disk: ``metrics.csv``, TensorBoard events and ``summary.json``, and
optionally a Weights & Biases run with the same metrics.

Metrics arrive from the device as a dict of arrays ``[seeds, iterations, ...]``; a metric with
a trailing ``[K]`` axis (returns per intention) becomes K columns ``name/0 .. name/K-1``.
TensorBoard keeps one event directory per seed (``tensorboard/seed_N``, tag ``COLUMN``); W&B one
run per training run, its keys ``seed_N/COLUMN``; both take the finite values only, at the
iteration as the step.
"""

from __future__ import annotations

import csv
import json
import math
import os
import platform
import subprocess
from importlib import metadata
from typing import Any

import numpy as np


def flatten_metrics(metrics: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """``{name: [S, L, ...]}`` -> ``{column: [S, L]}``."""
    columns = {}
    for name, values in sorted(metrics.items()):
        values = np.asarray(values)
        if values.ndim == 2:
            columns[name] = values
        else:
            for index in range(values.shape[-1]):
                columns[f"{name}/{index}"] = values[..., index]
    return columns


def _finite_scalars(columns: dict[str, np.ndarray], seed: int, step: int):
    """``(column, value)`` of one seed at one step of a chunk, where the value is finite (an
    iteration without evaluation leaves its ERD and returns NaN)."""
    for name, values in columns.items():
        value = float(values[seed, step])
        if math.isfinite(value):
            yield name, value


class MetricsLog:
    """Appends one row per iteration and seed to ``metrics.csv``, to TensorBoard and, given a
    W&B run (:func:`start_wandb`), to it."""

    def __init__(
        self,
        out_dir: str,
        tensorboard: bool = True,
        keep_until: int | None = None,
        enabled: bool = True,
        wandb_run=None,
        first_seed: int = 0,
    ):
        """``keep_until``: continue an existing log, first dropping its rows after that
        iteration (written after the checkpoint a resumed run restarts from). A log that is not
        ``enabled`` writes nothing (the processes of a multi-process run other than 0). Seeds
        are named as the run numbers them, from ``first_seed`` (``run --seed``)."""
        self.first_seed = first_seed
        self.csv_path = os.path.join(out_dir, "metrics.csv")
        self.tensorboard_dir = os.path.join(out_dir, "tensorboard")
        self._columns: list[str] | None = None
        self._writers = {}
        self._tensorboard = tensorboard
        self._wandb_run = wandb_run
        self.enabled = enabled
        if enabled and keep_until is not None and os.path.exists(self.csv_path):
            self._truncate(keep_until)

    def _truncate(self, keep_until: int) -> None:
        with open(self.csv_path, newline="") as f:
            rows = list(csv.reader(f))
        # A run killed while writing leaves a last row cut short (or a header alone); the rows
        # of a checkpointed iteration were complete before its checkpoint was written.
        header = rows[0] if rows else []
        body = [r for r in rows[1:] if len(r) == len(header) and int(r[0]) <= keep_until]
        if not body:  # nothing to keep: the log starts afresh
            os.remove(self.csv_path)
            return
        tmp = f"{self.csv_path}.tmp"
        with open(tmp, "w", newline="") as f:
            csv.writer(f).writerows([header, *body])
        os.replace(tmp, self.csv_path)
        self._columns = header[2:]

    def write(self, first_iteration: int, metrics: dict[str, np.ndarray]) -> None:
        if not self.enabled:
            return
        columns = flatten_metrics(metrics)
        seeds, length = next(iter(columns.values())).shape
        if self._columns is None:
            self._columns = list(columns)
            with open(self.csv_path, "w", newline="") as f:
                csv.writer(f).writerow(["iteration", "seed", *self._columns])
        with open(self.csv_path, "a", newline="") as f:
            out = csv.writer(f)
            for step in range(length):
                for seed in range(seeds):
                    row = [_cell(columns[c][seed, step]) for c in self._columns]
                    out.writerow([first_iteration + step + 1, self.first_seed + seed, *row])
        if self._tensorboard:
            self._write_tensorboard(first_iteration, columns, seeds, length)
        if self._wandb_run is not None:
            for step in range(length):
                row = {
                    f"seed_{self.first_seed + seed}/{name}": value
                    for seed in range(seeds)
                    for name, value in _finite_scalars(columns, seed, step)
                }
                self._wandb_run.log(row, step=first_iteration + step + 1)

    def _write_tensorboard(self, first_iteration, columns, seeds, length):
        from tensorboardX import SummaryWriter

        for seed in range(seeds):
            if seed not in self._writers:
                path = os.path.join(self.tensorboard_dir, f"seed_{self.first_seed + seed}")
                self._writers[seed] = SummaryWriter(path)
            writer = self._writers[seed]
            for step in range(length):
                for name, value in _finite_scalars(columns, seed, step):
                    writer.add_scalar(name, value, first_iteration + step + 1)
            writer.flush()

    def close(self) -> None:
        for writer in self._writers.values():
            writer.close()


WANDB_INSTALL = "pip install 'emgail-jax[wandb]'"


class WandbError(RuntimeError):
    """W&B is not installed or its run could not start; the message says what to do."""


def require_wandb():
    """The ``wandb`` module, an optional extra."""
    try:
        import wandb
    except ImportError:
        raise WandbError(f"--wandb needs the wandb package: {WANDB_INSTALL}") from None
    return wandb


def start_wandb(project: str, name: str, config: dict):
    """A W&B run in ``project`` named ``name`` holding ``config`` (the run's summary header).
    ``WANDB_MODE``, ``WANDB_DIR`` and W&B's other settings apply as W&B documents them."""
    wandb = require_wandb()
    try:
        return wandb.init(project=project, name=name, config=to_json_value(config))
    except wandb.errors.Error as error:  # not logged in, no network in online mode, ...
        message = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise WandbError(
            f"W&B could not start a run ({message}); log in with `wandb login`, or set "
            "WANDB_MODE=offline"
        ) from None


def finish_wandb(run, summary: dict) -> None:
    """The run's final metrics and status as the W&B run's summary, and its end."""
    final = to_json_value(summary.get("final", {}))
    run.summary.update(
        {"status": summary.get("status"), **{f"final/{k}": v for k, v in final.items()}}
    )
    run.finish(exit_code=0 if summary.get("status") == "completed" else 1)


# XLA:CPU compiles for the host's vector extensions, so the same code and seeds give results
# that differ in the last bits from one CPU to another; a summary names what it ran on.
_CODEGEN_FLAGS = ("sse4", "avx", "fma", "f16c", "amx")
_PACKAGES = ("jax", "jaxlib", "mujoco", "mujoco-mjx", "flax", "optax", "distrax")


def machine_facts(cpuinfo: str = "/proc/cpuinfo") -> dict:
    """What a run was computed on: the CPU and the vector extensions XLA compiles for, the
    package versions, and the project's commit (None where unknown): what a bit-for-bit re-run
    of the same seeds has to match. A resumed run records the machine it finished on."""
    model, flags = None, []
    try:
        with open(cpuinfo) as f:
            for line in f:
                key, _, value = (part.strip() for part in line.partition(":"))
                if key == "model name" and model is None:
                    model = value
                elif key == "flags":
                    flags = sorted(x for x in value.split() if x.startswith(_CODEGEN_FLAGS))
                    break
    except OSError:
        pass
    versions = {}
    for name in _PACKAGES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = None
    return {
        "cpu": model or platform.machine(),
        "cpu_features": flags,
        "python": platform.python_version(),
        "packages": versions,
        "commit": _commit(),
    }


def _commit() -> str | None:
    """``git describe --always --dirty`` of the checkout this package runs from, if any."""
    try:
        result = subprocess.run(
            ["git", "describe", "--always", "--dirty", "--abbrev=12"],
            cwd=os.path.dirname(os.path.abspath(__file__)),
            capture_output=True,
            text=True,
            timeout=10,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    if result.returncode != 0:
        return None
    return result.stdout.strip() or None


def _cell(value) -> str:
    value = float(value)
    return "" if math.isnan(value) else f"{value:.6g}"


def to_json_value(value: Any) -> Any:
    """numpy and JAX scalars/arrays -> plain JSON values; NaN and ±inf -> null (strict JSON)."""
    if isinstance(value, dict):
        return {k: to_json_value(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_json_value(v) for v in value]
    if hasattr(value, "__array__"):  # numpy's and JAX's arrays and scalars: Python's own
        return to_json_value(np.asarray(value).tolist())
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    return value


def write_json(path: str, data: dict) -> None:
    """Writes ``data`` atomically: a reader never sees a half-written file. Each writer has its
    own temporary file, so that processes writing one path at once (the sweep's cells sharing a
    true-reward baseline's cache) do not rename each other's away."""
    text = json_text(to_json_value(data))
    tmp = f"{path}.{platform.node()}-{os.getpid()}.tmp"
    with open(tmp, "w") as f:
        f.write(text + "\n")
    os.replace(tmp, path)


def json_text(value: Any, depth: int = 0) -> str:
    """Strict JSON of plain values, indented like ``indent=2`` except that a list of scalars
    stays on one line: a check's learning curves take a line each, not one per number."""
    pad, inner = "  " * depth, "  " * (depth + 1)
    if isinstance(value, dict) and value:
        items = [
            f"{inner}{json.dumps(str(k))}: {json_text(v, depth + 1)}" for k, v in value.items()
        ]
        return "{\n" + ",\n".join(items) + f"\n{pad}}}"
    if isinstance(value, list) and any(isinstance(v, (dict, list)) for v in value):
        items = [inner + json_text(v, depth + 1) for v in value]
        return "[\n" + ",\n".join(items) + f"\n{pad}]"
    return json.dumps(value, allow_nan=False)
