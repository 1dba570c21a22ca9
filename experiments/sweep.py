"""The paper's experiments in one command: Tables 2-3 and Figures 4-6, cell by cell, resumable.

    python experiments/sweep.py [--seeds 4] [--iterations 400] [--only PATTERN] [--out results]
        [--engine ray [--ray-address HOST:PORT]] [--check-processes N]
    make sweep SEEDS=4 [ONLY=PATTERN] [ITERATIONS=400] [OUT=results] [ENGINE=ray [RAY_ADDRESS=..]]

Every cell is a normal run directory, ``OUT/runs/<cell>`` (``ENV-K-ALGO``, ``-onehot`` for
EM-GAIL with the paper's one-network architecture, ``-pair`` for EM-GAIL with the paper's
per-pair E-step, ``driver-rRADIUS-ALGO``), trained by
``python -m emgail_jax.run`` with the defaults. A finished cell is skipped, an interrupted one
resumed from its last checkpoint, so the sweep can be stopped (Ctrl-C) and started again at will.
``--only`` takes comma-separated patterns, each a figure or table (fig4a, fig4b, fig5a, fig5b,
fig6, table2, table3) or a part of cell names (``halfcheetah``, ``reacher-2``, ``driver-r*-gail``).
From whatever cells are finished it writes ``OUT/table2.md``, ``OUT/table3.md`` and ``.csv``,
``OUT/fig5a.csv``, ``OUT/fig6.csv``, ``OUT/separability.csv`` and the figures
``fig4a.png`` ... ``fig6.png``; ``--report-only`` writes them without training anything.
Every EM-GAIL cell of Figure 6, and its GAIL and Info/IntentionGAIL cells at K = 2, also gets two
reward checks (``python -m emgail_jax.reoptimize``, every seed, beside the true-reward baseline,
which ``OUT/true-reward-baselines`` keeps for every cell of an env and K): the paper's, on the
run's own reward (``reoptimize.json``), and the refit's, on the reward ``reoptimize --refit``
learns after the run, the best of 3 draws kept by the learned reward (``reoptimize-refit.json``);
these cells train with a snapshot every 10 iterations, which the refit learns from. A check's
seeds run at once, a process per seed on a core of its own, then ``reoptimize --merge`` joins
them (``--check-processes N``; 1: every seed in one process).
``--engine ray`` runs every cell as a Ray task, several at once, on a Ray started here or on the
cluster at ``--ray-address`` (docs/reproducing-the-paper.md, "The sweep on Ray").

This file runs the cells (training, reward checks, time estimates, engines, command line); the
grid of cells is ``sweep_cells.py``, the reward checks' definitions ``sweep_checks.py``, and the
tables and figures ``sweep_report.py``.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import functools
import math
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
import traceback
from collections.abc import Callable, Iterator

import numpy as np

from emgail_jax.host.command_line import ArgumentParser
from sweep_cells import (
    Cell,
    Status,
    SweepError,
    all_cells,
    cell_status,
    select,
    summary_or_none,
    write_demonstrations,
)
from sweep_checks import (
    CHECKED_SNAPSHOT_EVERY,
    PAPER_CHECK,
    REFIT_CHECK,
    REWARD_CHECKS,
    RewardCheck,
    baseline_computers,
    check_iterations,
    check_part_path,
    checked_seeds,
    checks_draws_done,
    checks_to_do,
    part_is_current,
    reward_check,
    reward_check_command,
    seed_numbers,
)
from sweep_report import write_report

# For the time estimate before any cell of an env has finished: seconds per seed, iteration
# and intention with the seeds on both cores, and seconds to compile (warm cache), measured
# here with `python -m emgail_jax.run` at the defaults.
MEASURED_SECONDS = {  # env: (per seed-iteration-intention, compile)
    "driver": (0.020, 10.0),
    "swimmer": (0.21, 60.0),
    "hopper": (0.28, 80.0),
    "halfcheetah": (0.35, 100.0),
    "reacher": (0.29, 80.0),
}


def sweep_status(cell: Cell, run_dir: str, seeds: int, iterations: int) -> Status:
    """:func:`cell_status`, and CHECK for a trained cell whose reward check is still to do
    (RETRAIN where the networks to check are not kept)."""
    from emgail_jax.host.checkpoints import latest_iteration

    status = cell_status(run_dir, seeds, iterations)
    if status == Status.DONE and cell.reoptimized and checks_to_do(run_dir, seeds):
        return Status.CHECK if latest_iteration(run_dir) is not None else Status.RETRAIN
    return status


def run_command(command: list[str], log_path: str) -> int:
    """Runs one child process, its output to ``log_path``. Ctrl-C (SIGINT, which the child
    receives too) or SIGTERM (forwarded to it) lets the child checkpoint its chunk first, then
    stops the sweep."""
    return run_commands([command], log_path, processes=1)


CHILD_POLL_S = 0.5  # between looks at the checks' child processes


def run_commands(commands: list[list[str]], log_path: str, processes: int) -> int:
    """Runs ``commands`` as child processes, at most ``processes`` at once, each pinned to its
    own core of those this process may use when there are several (one alone keeps them all:
    a training shards its seeds over them), their output to ``log_path``; returns the first
    non-zero exit, once the others have stopped (SIGTERM: a check keeps its last save, at most
    two minutes old). Ctrl-C or SIGTERM stops them all, then the sweep."""
    pinning = processes > 1 and hasattr(os, "sched_getaffinity")
    cores = sorted(os.sched_getaffinity(0)) if pinning else []
    waiting, running, failed = list(commands), {}, 0

    def forward(signum, frame):
        for child in running:
            child.send_signal(signum)
        raise KeyboardInterrupt

    def start(command: list[str], slot: int) -> subprocess.Popen:
        log.write(f"\n$ {' '.join(command)}\n")
        log.flush()
        child = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT)
        if cores:  # pinned before its interpreter starts threads, which then inherit the core
            with contextlib.suppress(OSError):  # gone already
                os.sched_setaffinity(child.pid, {cores[slot % len(cores)]})
        return child

    with open(log_path, "a") as log:
        previous = signal.signal(signal.SIGTERM, forward)
        try:
            while waiting or running:
                free = sorted(set(range(processes)) - set(running.values()))
                while waiting and free and not failed:
                    slot = free.pop(0)
                    running[start(waiting.pop(0), slot)] = slot
                time.sleep(CHILD_POLL_S)
                for child in [c for c in running if c.poll() is not None]:
                    del running[child]
                    if child.returncode and not failed:
                        failed = child.returncode
                        for other in running:
                            other.terminate()
                if failed and not running:
                    break
            return failed
        except KeyboardInterrupt:
            for child in running:
                child.wait()
            raise
        finally:
            signal.signal(signal.SIGTERM, previous)


def run_in_process(args: list[str], log_path: str) -> int:
    """``python -m emgail_jax.run ARGS`` in this process, its output to ``log_path``. Ctrl-C or
    SIGTERM lets the run checkpoint its chunk, then stops the sweep."""
    from emgail_jax import run

    with (
        open(log_path, "a") as log,
        contextlib.redirect_stdout(log),
        contextlib.redirect_stderr(log),
    ):
        print(f"\n$ python -m emgail_jax.run {' '.join(args)}", flush=True)
        try:
            code = run.main(args)
        except Exception:  # a crash fails this cell as a crashed child process would
            traceback.print_exc()
            code = 1
    if code == 130:
        raise KeyboardInterrupt
    return code


def train_cell(
    cell: Cell,
    out: str,
    seeds: int,
    iterations: int,
    settings: tuple[str, ...] = (),
    check_processes: int = 1,
) -> None:
    """Trains, resumes or skips ``cell``, then runs its reward checks (every seed, beside the
    true-reward baseline) if the sweep checks it and has not yet, its seeds spread over
    ``check_processes`` processes (:func:`run_reward_check`)."""
    run_dir = os.path.join(out, "runs", cell.name)
    log_path = cell.log_path(out)
    os.makedirs(os.path.dirname(log_path), exist_ok=True)
    python = [sys.executable, "-m"]
    status = sweep_status(cell, run_dir, seeds, iterations)
    new_args = [*cell.run_args(settings, out), "--seeds", str(seeds)]
    new_args += ["--iterations", str(iterations)]
    if cell.reoptimized:
        new_args += ["--snapshot-every", str(CHECKED_SNAPSHOT_EVERY)]
    if status == Status.DAMAGED:
        status = repair_cell(cell.name, run_dir, new_args, log_path)
    if status == Status.RESUME:
        args = ["--resume", run_dir, "--iterations", str(iterations)]
    elif status in (Status.NEW, Status.RETRAIN):
        args = list(new_args)
        write_demonstrations(cell, out)
        args += ["--out", run_dir, "--overwrite"]  # with the checks of the networks replaced
    if status not in (Status.DONE, Status.CHECK):
        if cell.shares_programs:
            code = run_in_process([*args, "--quiet"], log_path)
        else:
            code = run_command([*python, "emgail_jax.run", *args, "--quiet"], log_path)
        if code != 0:
            raise SweepError(f"cell {cell.name} failed (exit {code}): see {log_path}")
    for check in checks_to_do(run_dir, seeds) if cell.reoptimized else ():
        code = run_reward_check(run_dir, out, check, log_path, check_processes)
        if code != 0:
            raise SweepError(f"re-optimising {cell.name} failed (exit {code}): see {log_path}")


def repair_cell(name: str, run_dir: str, run_args: list[str], log_path: str) -> Status:
    """A cell whose ``summary.json`` is damaged: the file is kept beside as
    ``summary.json.damaged``, said so on stderr and in the cell's log, and the cell continues
    from its last good checkpoint under a summary rebuilt from its own options (``run_args``);
    without a checkpoint it starts anew. Returns the status to go on with."""
    from emgail_jax import run
    from emgail_jax.host import records
    from emgail_jax.host.checkpoints import latest_iteration

    path = os.path.join(run_dir, "summary.json")
    kept = f"{path}.damaged"
    os.replace(path, kept)
    done = latest_iteration(run_dir)
    if done is None:
        after = "no checkpoint to continue from: it starts anew"
    else:
        after = f"it continues from its checkpoint of iteration {done}"
        spec = run.spec_from_args(run.parse_args([*run_args, "--out", run_dir]))
        records.write_json(path, {**spec.to_summary(), "status": "running"})
    message = f"cell {name}: its summary.json is damaged (kept as {kept}); {after}"
    print(message, file=sys.stderr)
    with open(log_path, "a") as log:
        log.write(f"\n{message}\n")
    return Status.NEW if done is None else Status.RESUME


def run_reward_check(
    run_dir: str, out: str, check: RewardCheck, log_path: str, processes: int = 1
) -> int:
    """Runs ``check`` on the cell in ``run_dir``; returns its exit code. With ``processes`` > 1
    each seed is checked in a process of its own, one per core (the last seed's computes the
    baseline, and starts first), then ``reoptimize --merge`` writes the check of every seed; a
    part of the networks checked already is kept, and the parts go once merged."""
    summary = summary_or_none(run_dir)
    numbers = seed_numbers(summary)
    command = reward_check_command(run_dir, out, check)
    if processes < 2 or len(numbers) < 2:
        return run_command(command, log_path)
    parts, to_do = [check_part_path(run_dir, check, n) for n in numbers], []
    for seed, part in zip(numbers, parts, strict=True):
        if not part_is_current(part, summary, check):
            one_seed = ["--seed", str(seed), *([] if seed == numbers[-1] else ["--no-baseline"])]
            to_do.append([*reward_check_command(run_dir, out, check, part), *one_seed])
    # The part with the baseline, the longest, first: the others fill the other cores meanwhile.
    to_do.sort(key=lambda command: "--no-baseline" in command)
    code = run_commands(to_do, log_path, processes)
    if code == 0:
        code = run_command([*command, "--merge", *parts], log_path)
    if code == 0:
        shutil.rmtree(os.path.dirname(parts[0]))
    return code


# Seconds per seed of a refit (4000 steps), for the estimate until a refit of the env has
# recorded its own.
REFIT_SECONDS_PER_SEED = 200.0


@dataclasses.dataclass(frozen=True)
class Timings:
    """Per env, seconds per seed-iteration-intention and seconds to compile, of training and
    of the reward checks' fresh TRPO, and seconds per seed of a refit, from the finished cells'
    own timings."""

    training: dict[str, tuple[float, float]]
    checks: dict[str, tuple[float, float]]
    refits: dict[str, float] = dataclasses.field(default_factory=dict)

    def of_training(self, env: str) -> tuple[float, float]:
        return self.training.get(env, MEASURED_SECONDS[env])

    def of_checks(self, env: str) -> tuple[float, float]:
        # Until a check of the env has finished: about training's, since the check runs every
        # seed on one device and skips only the discriminator and posterior.
        return self.checks.get(env, self.of_training(env))

    def of_refit(self, env: str) -> float:
        return self.refits.get(env, REFIT_SECONDS_PER_SEED)


def training_seconds(cell: Cell, seeds: int, iterations: int, timings: Timings) -> float:
    per_unit, compile_s = timings.of_training(cell.env)
    return compile_s + per_unit * seeds * iterations * cell.learned_intentions


def check_seconds(
    cell: Cell,
    seeds: int,
    iterations: int,
    timings: Timings,
    with_baseline: bool,
    *,
    check: RewardCheck = PAPER_CHECK,
    processes: int = 1,
) -> float:
    """A reward check's: per draw, fresh TRPO on every seed's K learned rewards in one
    program, and ``with_baseline`` K more policies on the true rewards in another; and the
    refit of every seed's reward first if the check refits. Over several ``processes`` (at
    most one per seed), what the busiest does: its share of the seeds, each its own program,
    and the baseline (:func:`run_reward_check`)."""
    per_unit, compile_s = timings.of_checks(cell.env)
    lanes = max(1, min(processes, seeds))
    programs = 1 if lanes == 1 else math.ceil(seeds / lanes)
    rows = math.ceil(seeds / lanes) + int(with_baseline)
    work = rows * check_iterations(cell.env, iterations, check) * cell.intentions
    refits = math.ceil(seeds / lanes) if "--refit" in check.options else 0
    refit = timings.of_refit(cell.env) * refits
    compiles = programs + int(with_baseline)
    return refit + check.draws * (compile_s * compiles + per_unit * work)


def estimate_seconds(
    cell: Cell,
    status: Status,
    seeds: int,
    iterations: int,
    timings: Timings,
    *,
    computing_baselines: tuple[RewardCheck, ...] = REWARD_CHECKS,
    checks: tuple[RewardCheck, ...] = REWARD_CHECKS,
    draws_done: dict[RewardCheck, float] | None = None,
    check_processes: int = 1,
) -> float:
    """What ``cell`` still needs: its training (unless trained), then its reward ``checks``
    (those still to do, less the ``draws_done`` of each check stopped part-way), those of
    ``computing_baselines`` with the true-reward baseline, over ``check_processes``."""
    seconds = 0.0 if status == Status.CHECK else training_seconds(cell, seeds, iterations, timings)
    for check in checks if cell.reoptimized else ():
        with_baseline = check in computing_baselines
        left = 1.0 - (draws_done or {}).get(check, 0.0) / check.draws
        seconds += left * check_seconds(
            cell, seeds, iterations, timings, with_baseline, check=check, processes=check_processes
        )
    return seconds


def measured_seconds(runs_dir: str) -> Timings:
    """Per env, from finished cells' own timings and their reward checks': seconds per
    seed-iteration-intention (the median over cells) and seconds to compile; seconds per seed of
    a refit (the median over the seeds of the refit checks that recorded theirs)."""
    found = {"training": {}, "checks": {}}
    refits = {}
    for name in sorted(os.listdir(runs_dir)) if os.path.isdir(runs_dir) else ():
        run_dir = os.path.join(runs_dir, name)
        summary = summary_or_none(run_dir)
        if not summary or summary.get("status") != "completed":
            continue
        timings = {
            "training": _training_timing(summary),
            "checks": _check_timing(reward_check(run_dir), summary["intentions"]),
        }
        for kind, timing in timings.items():
            if timing is not None:
                found[kind].setdefault(summary["env"], []).append(timing)
        refits.setdefault(summary["env"], []).extend(
            _refit_seconds(reward_check(run_dir, REFIT_CHECK))
        )
    median = lambda per_env: {env: tuple(np.median(t, 0).tolist()) for env, t in per_env.items()}
    refit_medians = {env: float(np.median(seconds)) for env, seconds in refits.items() if seconds}
    return Timings(median(found["training"]), median(found["checks"]), refit_medians)


def _training_timing(summary: dict) -> tuple[float, float] | None:
    """A finished run's seconds per seed-iteration-intention and to compile."""
    timings = summary["timings"]
    work = timings["iterations"] * summary["seeds"] * summary["intentions"]
    return (timings["train_time_s"] / work, timings["compile_time_s"]) if work else None


def _check_timing(check: dict | None, intentions: int) -> tuple[float, float] | None:
    """A reward check's seconds per seed-iteration-intention and to compile (of the learned
    rewards' fresh policies; the baseline's are not recorded)."""
    if check is None or "train_time_s" not in check:
        return None
    # Its budget's iterations; the files of seed 0 alone held them as "iterations".
    iterations = (check.get("budget") or {}).get("iterations", check.get("iterations"))
    work = len(checked_seeds(check)) * (iterations or 0) * intentions
    return (check["train_time_s"] / work, check["compile_time_s"]) if work else None


def _refit_seconds(check: dict | None) -> list[float]:
    """Each seed's refit seconds in a refit check (none in checks written before they were
    recorded)."""
    seeds = (check or {}).get("consolidation") or ()
    return [seed["seconds"] for seed in seeds if isinstance(seed, dict) and "seconds" in seed]


@dataclasses.dataclass(frozen=True)
class CellJob:
    """What every cell of one sweep is trained with (:func:`train_cell` but the cell)."""

    out: str
    seeds: int
    iterations: int
    settings: tuple[str, ...] = ()
    # A reward check's seeds spread over this many processes (None: on Ray, the cell's CPUs).
    check_processes: int | None = 1

    def __call__(self, cell: Cell) -> None:
        processes = self.check_processes or 1
        train_cell(cell, self.out, self.seeds, self.iterations, self.settings, processes)


# An engine trains ``cells`` with ``job`` and yields each cell as it finishes; a cell that fails
# raises SweepError (the Ray engine: once the others have finished).
Engine = Callable[[list[Cell], CellJob], Iterator[Cell]]


def train_here(cells: list[Cell], job: CellJob) -> Iterator[Cell]:
    """The local engine: one cell after the other, from this process."""
    for cell in cells:
        job(cell)
        yield cell


RAY_EXTRA = "pip install -e '.[ray]'"

# Retries of a cell whose worker or node was lost (a failing cell is not retried: its error
# would recur); each retry resumes the cell from its last checkpoint.
RAY_MAX_RETRIES = 3
RAY_WAIT_S = 5.0  # between looks at the cells, so that Ctrl-C is seen at once


def import_ray():
    try:
        import ray
    except ImportError:
        raise SweepError(f"--engine ray needs Ray: {RAY_EXTRA}") from None
    return ray


@contextlib.contextmanager
def ray_engine(
    address: str | None, seeds: int, cpus: int | None = None, gpus: int | None = None
) -> Iterator[Engine]:
    """The Ray engine: every cell a Ray task, on the cluster at ``address`` (``None``: a Ray
    started here for the sweep). A cell reserves ``cpus`` (default: a core per seed, as many as
    the largest node has) and ``gpus`` (default: one if the cluster has any). Every node runs
    the sweep's checkout and sees ``out`` at the same path."""
    ray = import_ray()
    # The workers cannot import the experiments' files: the cells and jobs go by value.
    by_value = [sys.modules[name] for name in ("sweep_cells", "sweep_checks")]
    if __name__ != "__main__":  # imported (the tests)
        by_value.append(sys.modules[__name__])
    for module in by_value:
        ray.cloudpickle.register_pickle_by_value(module)
    if address is not None:
        _check_reachable(address)
    local = {"include_dashboard": False} if address is None else {}
    try:
        ray.init(address=address or "local", log_to_driver=False, **local)
    except ConnectionError as error:  # address "auto" and no Ray running here
        raise SweepError(f"cannot join Ray at {address}: {str(error).splitlines()[0]}") from None
    previous = signal.signal(signal.SIGTERM, _interrupt)  # not ray.init's exit: as Ctrl-C
    try:
        nodes = [node["Resources"] for node in ray.nodes() if node["Alive"]]
        most = {key: max(node.get(key, 0) for node in nodes) for key in ("CPU", "GPU")}
        cpus = cpus or max(1, min(seeds, int(most["CPU"])))
        gpus = (1 if most["GPU"] else 0) if gpus is None else gpus
        if cpus > most["CPU"] or gpus > most["GPU"]:
            raise SweepError(
                f"a cell cannot reserve {cpus} CPUs and {gpus} GPUs: the cluster's largest "
                f"node has {most['CPU']:g} and {most['GPU']:g}; lower --cpus-per-cell or "
                f"--gpus-per-cell"
            )
        task = ray.remote(
            num_cpus=cpus, num_gpus=gpus, max_retries=RAY_MAX_RETRIES, retry_exceptions=False
        )(train_cell_task)
        yield functools.partial(_train_on_ray, ray, task, cpus)
    finally:
        signal.signal(signal.SIGTERM, previous)
        ray.shutdown()


def _interrupt(signum, frame):
    raise KeyboardInterrupt


def _check_reachable(address: str, timeout_s: float = 10.0) -> None:
    """A HOST:PORT that nothing answers at is refused here: Ray would wait for it forever."""
    host, _, port = address.rpartition(":")
    if not host or not port.isdigit():
        return  # "auto", "ray://...": Ray's own forms, which fail by themselves
    try:
        socket.create_connection((host, int(port)), timeout=timeout_s).close()
    except OSError as error:
        raise SweepError(
            f"no Ray cluster answers at {address} ({error.strerror or error}): start one "
            f"(ray start --head) or leave out the address for a Ray started here"
        ) from None


def _train_on_ray(ray, task, cpus: int, cells: list[Cell], job: CellJob) -> Iterator[Cell]:
    job = dataclasses.replace(job, out=os.path.abspath(job.out))  # workers have other cwds
    if job.check_processes is None:  # a check's seeds over the cores the cell reserves
        job = dataclasses.replace(job, check_processes=cpus)
    code = code_fingerprint()
    pending = {task.options(name=cell.name).remote(job, cell, code): cell for cell in cells}
    failures = []
    try:
        while pending:
            finished, _ = ray.wait(list(pending), num_returns=1, timeout=RAY_WAIT_S)
            for ref in finished:
                cell = pending.pop(ref)
                try:
                    error = ray.get(ref, timeout=RAY_WAIT_S)
                except ray.exceptions.RayTaskError:  # a crash, not a lost worker: its traceback
                    raise
                except ray.exceptions.RayError as lost:
                    error = f"cell {cell.name} was lost ({type(lost).__name__}) after "
                    error += f"{RAY_MAX_RETRIES} retries: see {cell.log_path(job.out)}"
                if error is None:
                    yield cell
                else:
                    failures.append(error)
    finally:  # stopped (Ctrl-C): the cells still running resume from their last checkpoints
        for ref in pending:
            ray.cancel(ref, force=True)
    if failures:
        raise SweepError("; ".join(failures))


def train_cell_task(job: CellJob, cell: Cell, code: str) -> str | None:
    """One cell on a Ray worker; returns the cell's error, or None. ``code`` is the sweep's
    :func:`code_fingerprint`: a node on other code would give other results."""
    import ray

    node = ray.get_runtime_context().get_node_id()
    log_path = cell.log_path(job.out)
    os.makedirs(os.path.dirname(log_path), exist_ok=True)
    with open(log_path, "a") as log:
        log.write(f"\n# on Ray node {node}\n")
    if code_fingerprint() != code:
        return (
            f"cell {cell.name}: Ray node {node} runs other emgail_jax code than the sweep; start "
            f"every node from the sweep's checkout"
        )
    try:
        job(cell)
    except SweepError as error:
        return str(error)
    return None


def code_fingerprint() -> str:
    """A hash of the training code this process imports: the files of the emgail_jax and envs
    packages (sources and shipped demonstrations)."""
    import hashlib
    import importlib.util
    import pathlib

    digest = hashlib.sha256()
    for package in ("emgail_jax", "envs"):
        root = pathlib.Path(importlib.util.find_spec(package).origin).parent
        for path in sorted(root.rglob("*")):
            if path.is_file() and "__pycache__" not in path.parts:
                digest.update(str(path.relative_to(root)).encode())
                digest.update(path.read_bytes())
    return digest.hexdigest()


def _format_duration(seconds: float) -> str:
    hours, rest = divmod(int(seconds), 3600)
    return f"{hours}h{rest // 60:02d}m" if hours else f"{rest // 60}m{rest % 60:02d}s"


def parse_args(argv=None) -> argparse.Namespace:
    parser = ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--iterations", type=int, default=400)
    parser.add_argument("--only", default=None, help="comma-separated figures or cell names")
    parser.add_argument("--out", default="results")
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a hyper-parameter for every new cell, as `run --set` (repeatable)",
    )
    parser.add_argument(
        "--engine",
        choices=("local", "ray"),
        default="local",
        help="local: one cell after the other here; ray: every cell a Ray task",
    )
    parser.add_argument(
        "--ray-address",
        default=os.environ.get("RAY_ADDRESS"),
        metavar="HOST:PORT",
        help="the Ray cluster of --engine ray (default RAY_ADDRESS, else a Ray started here)",
    )
    parser.add_argument("--cpus-per-cell", type=int, default=None, help="default: one per seed")
    parser.add_argument(
        "--check-processes",
        type=int,
        default=None,
        metavar="N",
        help="a reward check's seeds in N processes at once, each on its own core, then merged "
        "(default: a cell's cores, at most one per seed; 1: every seed in one process)",
    )
    parser.add_argument("--gpus-per-cell", type=int, default=None, help="default: 1 if any")
    parser.add_argument("--list", action="store_true", help="list the cells and stop")
    parser.add_argument("--report-only", action="store_true", help="tables and figures only")
    return parser.parse_args(argv)


def local_check_processes(args: argparse.Namespace) -> int:
    """A reward check's processes here: ``--check-processes``, else one per core this process
    may use, at most one per seed."""
    usable = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else None
    cores = len(usable) if usable else os.cpu_count() or 1
    return args.check_processes or min(args.seeds, cores)


@dataclasses.dataclass(frozen=True)
class Plan:
    """The cells a sweep covers, where each stands, and the seconds each still needs."""

    cells: list[Cell]
    statuses: dict[Cell, Status]
    estimates: dict[Cell, float]  # of the cells to run alone

    @property
    def todo(self) -> list[Cell]:
        return [cell for cell in self.cells if self.statuses[cell] != Status.DONE]


def plan_sweep(args: argparse.Namespace) -> Plan:
    """The options checked, the cells chosen, their run directories read; raises SweepError."""
    if args.seeds < 1 or args.iterations < 1:
        raise SweepError("--seeds and --iterations must be at least 1")
    below = lambda given, least: given is not None and given < least  # None: not given
    if below(args.cpus_per_cell, 1) or below(args.gpus_per_cell, 0):
        raise SweepError("--cpus-per-cell must be at least 1, --gpus-per-cell at least 0")
    if below(args.check_processes, 1):
        raise SweepError("--check-processes must be at least 1")
    if args.engine == "ray":
        import_ray()
    cells = select(all_cells(), args.only)
    runs_dir = os.path.join(args.out, "runs")
    statuses = {
        c: sweep_status(c, os.path.join(runs_dir, c.name), args.seeds, args.iterations)
        for c in cells
    }
    timings = measured_seconds(runs_dir)
    todo = [c for c in cells if statuses[c] != Status.DONE]
    computers = baseline_computers(todo, args.out, args.iterations)

    def still_to_check(cell: Cell) -> tuple[RewardCheck, ...]:
        if statuses[cell] != Status.CHECK:
            return REWARD_CHECKS
        return tuple(checks_to_do(os.path.join(runs_dir, cell.name), args.seeds))

    def computing(cell: Cell) -> tuple[RewardCheck, ...]:
        return tuple(check for check in REWARD_CHECKS if (cell, check) in computers)

    def draws_done(cell: Cell) -> dict[RewardCheck, float]:
        if statuses[cell] != Status.CHECK:  # retraining removes what a check had kept
            return {}
        return checks_draws_done(cell, os.path.join(runs_dir, cell.name), args.iterations)

    estimates = {
        c: estimate_seconds(
            c,
            statuses[c],
            args.seeds,
            args.iterations,
            timings,
            computing_baselines=computing(c),
            checks=still_to_check(c),
            draws_done=draws_done(c),
            check_processes=local_check_processes(args),
        )
        for c in todo
    }
    return Plan(cells, statuses, estimates)


def print_plan(console, plan: Plan, args: argparse.Namespace) -> None:
    """The table of cells, what each feeds, its status and estimate, and the total."""
    from rich.table import Table

    table = Table(
        title=f"sweep: {len(plan.cells)} cells, {args.seeds} seeds × {args.iterations} "
        f"iterations, in {args.out}"
    )
    for column in ("cell", "feeds", "status", "estimate"):
        table.add_column(column)
    for cell in plan.cells:
        estimate = plan.estimates.get(cell)
        estimate = "" if estimate is None else _format_duration(estimate)
        table.add_row(cell.name, ", ".join(cell.groups), plan.statuses[cell], estimate)
    console.print(table)
    total = _format_duration(sum(plan.estimates.values()))
    console.print(f"{len(plan.todo)} cells to run, estimated {total} on this machine")


def _describe(on_ray: bool, statuses: dict[Cell, Status], remaining: list[Cell]) -> str:
    """The progress bar's text: the cell in progress, or how many run on Ray."""
    if on_ray:  # the cells run at once, as the cluster has room
        return f"{len(remaining)} cells on Ray"
    return f"{remaining[0].name} ({statuses[remaining[0]]})" if remaining else ""


def run_cells(console, plan: Plan, args: argparse.Namespace) -> int | None:
    """Trains the cells to run on the engine of ``args``; an exit code if the sweep stops."""
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    columns = (
        TextColumn("{task.description}"),
        BarColumn(),
        TextColumn("{task.completed}/{task.total} cells"),
        TimeElapsedColumn(),
    )
    on_ray = args.engine == "ray"
    processes = None if on_ray and not args.check_processes else local_check_processes(args)
    job = CellJob(args.out, args.seeds, args.iterations, tuple(args.set), processes)
    engine_context = contextlib.ExitStack()
    try:  # the Ray engine starts or joins Ray here and checks what a cell can reserve
        engine = engine_context.enter_context(
            ray_engine(args.ray_address, args.seeds, args.cpus_per_cell, args.gpus_per_cell)
            if on_ray
            else contextlib.nullcontext(train_here)
        )
    except SweepError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    describe = functools.partial(_describe, on_ray, plan.statuses)
    todo, started = plan.todo, time.monotonic()
    try:
        with engine_context, Progress(*columns, console=console) as progress:
            remaining = list(todo)
            task = progress.add_task(describe(remaining), total=len(todo))
            for cell in engine(todo, job):
                remaining.remove(cell)
                progress.update(task, description=describe(remaining), advance=1)
    except SweepError as error:
        print(f"error: {error}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        kept = "the running cells keep their last checkpoints"
        kept = kept if on_ray else "the cell in progress is checkpointed"
        console.print(f"interrupted: {kept}; run the same command to resume")
        return 130
    console.print(f"ran {len(todo)} cells in {_format_duration(time.monotonic() - started)}")
    return None


def main(argv=None) -> int:
    args = parse_args(argv)
    from rich.console import Console

    console = Console(file=sys.stdout)  # not the cell logs that in-process runs print to
    try:
        plan = plan_sweep(args)
    except SweepError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    print_plan(console, plan, args)
    if args.list:
        return 0
    if not args.report_only and plan.todo:
        stopped = run_cells(console, plan, args)
        if stopped is not None:
            return stopped
    try:
        written = write_report(args.out, plan.cells, args.seeds, args.iterations)
    except SweepError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    console.print(f"wrote {', '.join(written)} in {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
