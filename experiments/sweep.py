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
cluster at ``--ray-address`` (README, "The sweep on Ray").
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import dataclasses
import enum
import fnmatch
import functools
import json
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

from emgail_jax.host.final_results import FinalResults
from emgail_jax.host.reward_check import BUDGETS, Budget, baseline_prefix, env_budget
from emgail_jax.host.run_spec import RunError, read_summary
from emgail_jax.reoptimize import given_budget
from emgail_jax.reoptimize import parse_args as reoptimize_args

ROBOTICS_INTENTIONS = {
    "swimmer": (2,),
    "hopper": (2, 3),
    "halfcheetah": (2, 3),
    "reacher": (2, 3, 4),
}
# Beyond the paper: K chosen from the demonstrations (`--intentions auto`, starting from the
# env's maximum) on sets of K true intentions, the first K of each env's (the driver's paths
# at its default radius), beside the same cell with K given.
CHOOSING_K = {"driver": (2, 3, 4), "swimmer": (2,), "hopper": (3,), "reacher": (2, 3, 4)}
# Separability 0.06 to 0.93 (README, "The driver and its separability").
DRIVER_RADII = (4.0, 5.0, 6.0, 7.0, 8.0, 10.0, 15.0, 20.0)
ALGOS = ("emgail", "infogail", "gail")
ALGO_LABELS = {
    "emgail": "EM-GAIL",
    "emgail-onehot": "EM-GAIL (one-hot input)",
    "emgail-pair": "EM-GAIL (per-pair E-step)",
    "emgail-auto": "EM-GAIL, K chosen (--intentions auto)",
    "infogail": "Info/IntentionGAIL",
    "gail": "GAIL",
    "gmm": "GMM",
}


class Variant(enum.StrEnum):
    """EM-GAIL with one of the paper's own choices where the default departs from it (README,
    "Departures from the paper"), for Table 3; or with K chosen from the demonstrations."""

    DEFAULT = ""
    ONEHOT = "onehot"
    PAIR = "pair"
    AUTO = "auto"  # K chosen from demonstrations of ``intentions`` true ones


VARIANT_OPTIONS = {
    Variant.ONEHOT: ("--intention-input", "onehot"),
    Variant.PAIR: ("--responsibilities", "pair"),
}
# Table 3's learned methods (algorithm, variant), after the GMM of the separability table.
TABLE3_METHODS = (
    ("infogail", Variant.DEFAULT),
    ("emgail", Variant.DEFAULT),
    ("emgail", Variant.ONEHOT),
    ("emgail", Variant.PAIR),
)
FIGURES = ("fig4a", "fig4b", "fig5a", "fig5b", "fig6", "table2", "table3", "choosing-k")

# The paper's Table 3 (clustering accuracy, %) and Table 2 (EM-GAIL seconds per iteration on
# an RTX 2080 Ti; learnable parameters of GAIL / Info/IntentionGAIL / EM-GAIL).
PAPER_TABLE3 = {
    "gmm": {"hopper-2": 95.8, "hopper-3": 81.6, "halfcheetah-2": 97.8, "halfcheetah-3": 68.3,
            "swimmer-2": 82.5, "reacher-2": 88.9, "reacher-3": 62.8, "reacher-4": 52.6},
    "infogail": {"hopper-2": 99.3, "hopper-3": 96.3, "halfcheetah-2": 99.9,
                 "halfcheetah-3": 79.5, "swimmer-2": 89.1, "reacher-2": 98.3, "reacher-3": 72.0,
                 "reacher-4": 52.4},
    "emgail": {"hopper-2": 99.2, "hopper-3": 98.1, "halfcheetah-2": 99.8, "halfcheetah-3": 96.5,
               "swimmer-2": 97.3, "reacher-2": 99.2, "reacher-3": 97.1, "reacher-4": 96.8},
}  # fmt: skip
PAPER_TABLE2 = {  # env: {algo: (parameters, seconds per iteration)}
    "swimmer": {"gail": ("14.6K", 8.5), "infogail": ("19.9K", 10.2), "emgail": ("20.0K", 10.3)},
    "hopper": {"gail": ("15.3K", 12.4), "infogail": ("21.1K", 15.3), "emgail": ("21.2K", 15.6)},
    "halfcheetah": {"gail": ("16.9K", 13.3), "infogail": ("23.2K", 16.1),
                    "emgail": ("23.4K", 16.5)},
    "reacher": {"gail": ("18.1K", 5.5), "infogail": ("24.9K", 8.4), "emgail": ("25.1K", 8.7)},
}  # fmt: skip

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


class SweepError(RuntimeError):
    """The sweep cannot go on; the message says what to change."""


@dataclasses.dataclass(frozen=True)
class DemoSet:
    """The demonstrations a cell trains on: a row of the separability table."""

    env: str
    intentions: int
    radius: float | None = None  # the driver's path-2 radius

    @property
    def name(self) -> str:
        """Its key in ``separability.csv``: ``hopper-3``, ``driver-r10``."""
        if self.radius is not None:
            return f"{self.env}-r{self.radius:g}"
        return f"{self.env}-{self.intentions}"


def method_name(algo: str, variant: Variant) -> str:
    """``emgail``, ``emgail-onehot``: a key of ALGO_LABELS and of PAPER_TABLE3."""
    return algo + (f"-{variant}" if variant else "")


@dataclasses.dataclass(frozen=True)
class Cell:
    """One run of the sweep and the figures and tables it feeds. A cell is its env,
    intentions, algorithm, radius and variant: ``groups`` says where it is drawn, not which
    run it is, so ``Cell("hopper", 2, "emgail")`` finds the cell of any groups."""

    env: str
    intentions: int
    algo: str  # "emgail" | "infogail" | "gail"
    groups: tuple[str, ...] = dataclasses.field(default=(), compare=False)
    radius: float | None = None  # the driver's path-2 radius
    variant: Variant = Variant.DEFAULT

    @property
    def name(self) -> str:
        where = f"r{self.radius:g}" if self.radius is not None else str(self.intentions)
        return f"{self.env}-{where}-{self.method}"

    @property
    def method(self) -> str:
        return method_name(self.algo, self.variant)

    @property
    def data(self) -> DemoSet:
        return DemoSet(self.env, self.intentions, self.radius)

    def log_path(self, out: str) -> str:
        return os.path.join(out, "logs", f"{self.name}.log")

    @property
    def shares_programs(self) -> bool:
        """The driver's cells of one algorithm differ only in data (the radius), so they run in
        the sweep's own process, where the second compiles nothing (emgail_jax.host.seed_runner)."""
        return self.radius is not None

    @property
    def reoptimized(self) -> bool:
        """The paper's reward check (§5.2) runs on every EM-GAIL cell of Figure 6 and, to
        compare it with, on GAIL's and Info/IntentionGAIL's at K = 2."""
        return robotics_many(self) and (self.algo == "emgail" or self.intentions == 2)

    @property
    def learned_intentions(self) -> int:
        """K trained: the env's maximum when K is chosen from the data."""
        if self.variant == Variant.AUTO:
            import envs

            return len(envs.env_class(self.env).intention_names)
        return self.intentions

    def demonstrations(self, out: str) -> str | None:
        """The demonstrations file of an auto cell whose true K is not all the env has (and of
        every driver cell of it, whose demonstrations are generated): written by
        :func:`write_demonstrations` under ``out/demos``; None for the default ones."""
        if self.variant != Variant.AUTO or (
            self.env != "driver" and self.intentions == self.learned_intentions
        ):
            return None
        return os.path.join(out, "demos", f"{self.env}-{self.intentions}.npz")

    def run_args(self, settings: tuple[str, ...] = (), out: str = "results") -> list[str]:
        """``python -m emgail_jax.run`` options of a new run; ``settings`` go to ``--set``."""
        intentions = "auto" if self.variant == Variant.AUTO else str(self.intentions)
        args = ["--env", self.env, "--intentions", intentions, "--algo", self.algo]
        demos = self.demonstrations(out)
        if demos is not None:
            args += ["--demos", os.path.abspath(demos)]
        for setting in settings:
            args += ["--set", setting]
        if self.radius is not None:
            args += ["--radius", f"{self.radius:g}"]
        return args + list(VARIANT_OPTIONS.get(self.variant, ()))


def all_cells() -> list[Cell]:
    cells = []
    for env, ks in ROBOTICS_INTENTIONS.items():
        # K = 1: the three algorithms are GAIL on one expert, the floor each env allows.
        cells.append(Cell(env, 1, "gail", ("fig6",)))
        for k in ks:
            for algo in ALGOS:
                groups = ("fig4a", "fig6", "fig5b") + (("table3",) if algo != "gail" else ())
                groups += ("table2",) if k == 2 else ()
                cells.append(Cell(env, k, algo, groups))
            cells.append(Cell(env, k, "emgail", ("table3",), variant=Variant.ONEHOT))
    for radius in DRIVER_RADII:
        for algo in ALGOS:
            cells.append(Cell("driver", 2, algo, ("fig4b", "fig5a"), radius=radius))
    for env, ks in ROBOTICS_INTENTIONS.items():  # the paper's E-step, for comparison
        cells += [Cell(env, k, "emgail", ("table3",), variant=Variant.PAIR) for k in ks]
    for env, ks in CHOOSING_K.items():  # last: beyond the paper
        for k in ks:
            cells.append(Cell(env, k, "emgail", ("choosing-k",), variant=Variant.AUTO))
            if env == "driver":  # the robotics envs' K-given cells are Table 3's
                cells.append(Cell(env, k, "emgail", ("choosing-k",)))
    return cells


def select(cells: list[Cell], only: str | None) -> list[Cell]:
    """The cells matching any comma-separated pattern: a figure/table name, a whole cell name
    (that cell alone), or part of names (``reacher-2``: every reacher-2 cell)."""
    if not only:
        return cells
    patterns = [p.strip() for p in only.split(",") if p.strip()]
    names = {cell.name for cell in cells}

    def matches(cell: Cell, pattern: str) -> bool:
        if pattern in names:
            return cell.name == pattern
        return pattern in cell.groups or fnmatch.fnmatch(cell.name, f"*{pattern}*")

    chosen = [cell for cell in cells if any(matches(cell, p) for p in patterns)]
    if not chosen:
        raise SweepError(
            f"--only {only!r} matches no cell: use a figure or table ({', '.join(FIGURES)}) "
            f"or part of a cell name, e.g. hopper-3 or driver-r10"
        )
    return chosen


# ---- running cells -----------------------------------------------------------------------------


def _summary_or_none(run_dir: str) -> dict | None:
    """The run's ``summary.json`` (:func:`emgail_jax.host.run_spec.read_summary`), or None where
    it is missing, unreadable or no JSON: the sweep tells these apart by the file's presence."""
    try:
        return read_summary(run_dir)
    except (RunError, OSError):
        return None


class Status(enum.StrEnum):
    """Where a cell's run directory stands (the status column of the sweep's table)."""

    DONE = "done"
    RESUME = "resume"  # a checkpointed run short of the sweep's iterations
    DAMAGED = "damaged"  # a summary.json that is not a run's, e.g. cut short
    NEW = "new"
    CHECK = "reward check"  # trained; its reward check is still to do
    # Trained, its reward check to do, but its networks not kept (results/ keeps no
    # checkpoints): trained again, then checked.
    RETRAIN = "retrain, check"


def cell_status(run_dir: str, seeds: int, iterations: int) -> Status:
    """What the sweep does with the run in ``run_dir``: skip, resume, repair it or start it."""
    summary = _summary_or_none(run_dir)
    if summary is None:
        path = os.path.join(run_dir, "summary.json")
        return Status.DAMAGED if os.path.exists(path) else Status.NEW
    if not isinstance(summary, dict) or "seeds" not in summary:
        return Status.DAMAGED
    if summary.get("seeds") != seeds:
        raise SweepError(
            f"{run_dir} was run with {summary.get('seeds')} seeds, not {seeds}: pass the same "
            f"SEEDS, or another OUT for a new sweep"
        )
    if summary.get("status") == "completed" and summary.get("iterations_done", 0) >= iterations:
        return Status.DONE
    # A killed run never wrote its iterations to summary.json ("running"): its checkpoints
    # are what it has done.
    from emgail_jax.host.checkpoints import latest_iteration

    return Status.RESUME if latest_iteration(run_dir) else Status.NEW


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


def write_demonstrations(cell: Cell, out: str) -> None:
    """The demonstrations of an auto cell's K true intentions, when they are not the default
    ones: the first K of the env's shipped set (the driver's: generated, as ``train`` does)."""
    path = cell.demonstrations(out)
    if path is None or os.path.exists(path):
        return
    from emgail_jax.host import demonstration_files
    from emgail_jax.host.problem import make_problem

    os.makedirs(os.path.dirname(path), exist_ok=True)
    demonstration_files.save(make_problem(cell.env, cell.intentions).demos, path)


# ---- the reward checks: python -m emgail_jax.reoptimize -----------------------------------------

BASELINES_DIR = "true-reward-baselines"  # under OUT, which every node of a Ray sweep sees


@dataclasses.dataclass(frozen=True)
class RewardCheck:
    """One reward check of a cell: ``reoptimize`` with ``options``, written to ``file`` in the
    cell's run directory."""

    file: str
    options: tuple[str, ...] = ()
    draws: int = 1


# The paper's check (§5.2) of the run's own reward; then the reward refitted after the run with
# the recipe measured best per env, each intention's best of 3 draws kept by the learned reward
# (docs/rewards-that-reoptimise.md, experiments 53 and 66).
PAPER_CHECK = RewardCheck("reoptimize.json")
REFIT_DRAWS = 3
REFIT_CHECK = RewardCheck(
    "reoptimize-refit.json", ("--refit", "--draws", str(REFIT_DRAWS)), REFIT_DRAWS
)
REWARD_CHECKS = (PAPER_CHECK, REFIT_CHECK)
# The refit learns from the run's snapshots: one every 10 iterations (the default 50 gave
# reacher-2 a worse refit, README "Known limitations").
CHECKED_SNAPSHOT_EVERY = 10
# Seconds per seed of a refit (4000 steps), for the estimate until a refit check has finished.
REFIT_SECONDS_PER_SEED = 200.0


def reward_check_command(
    run_dir: str, out: str, check: RewardCheck = PAPER_CHECK, path: str | None = None
) -> list[str]:
    """The ``check`` of the cell in ``run_dir``: every seed re-optimised, beside the
    true-reward baseline, cached where every cell of the env and K finds it; written to
    ``path`` (default the check's file)."""
    cache = os.path.join(out, BASELINES_DIR)
    command = [sys.executable, "-m", "emgail_jax.reoptimize", run_dir, *check.options]
    command += ["--cache", cache, "--quiet"]
    if path is not None or check != PAPER_CHECK:
        command += ["--out", path or os.path.join(run_dir, check.file)]
    return command


def seed_numbers(summary: dict | None) -> list[int]:
    """The run seeds of a cell's ``summary`` (none without one), as ``reoptimize --seed``
    numbers them."""
    return [summary.get("first_seed", 0) + s for s in range(summary["seeds"])] if summary else []


def check_part_path(run_dir: str, check: RewardCheck, seed: int) -> str:
    """Where run seed ``seed``'s part of a ``check`` spread over processes is written."""
    stem = os.path.splitext(check.file)[0]
    return os.path.join(run_dir, f"{stem}.parts", f"seed-{seed}.json")


def run_reward_check(
    run_dir: str, out: str, check: RewardCheck, log_path: str, processes: int = 1
) -> int:
    """Runs ``check`` on the cell in ``run_dir``; returns its exit code. With ``processes`` > 1
    each seed is checked in a process of its own, one per core (the last seed's computes the
    baseline), then ``reoptimize --merge`` writes the check of every seed; a part of the
    networks checked already is kept, and the parts go once merged."""
    summary = _summary_or_none(run_dir)
    numbers = seed_numbers(summary)
    command = reward_check_command(run_dir, out, check)
    if processes < 2 or len(numbers) < 2:
        return run_command(command, log_path)
    budget = dataclasses.asdict(check_budget(summary["env"], summary["config"], check))
    parts, to_do = [check_part_path(run_dir, check, n) for n in numbers], []
    for seed, part in zip(numbers, parts, strict=True):
        found = _json_or_none(part) or {}
        if (found.get("iteration"), found.get("budget")) != (summary["iterations_done"], budget):
            one_seed = ["--seed", str(seed), *([] if seed == numbers[-1] else ["--no-baseline"])]
            to_do.append([*reward_check_command(run_dir, out, check, part), *one_seed])
    code = run_commands(to_do, log_path, processes)
    if code == 0:
        code = run_command([*command, "--merge", *parts], log_path)
    if code == 0:
        shutil.rmtree(os.path.dirname(parts[0]))
    return code


def reward_check(run_dir: str, check: RewardCheck = PAPER_CHECK) -> dict | None:
    """The cell's ``check`` file, or None where it is missing or unreadable."""
    return _json_or_none(os.path.join(run_dir, check.file))


def _json_or_none(path: str) -> dict | None:
    try:
        with open(path) as f:
            found = json.load(f)
    except (OSError, ValueError):
        return None
    return found if isinstance(found, dict) else None


def checked_seeds(check: dict) -> list[int]:
    """The run seeds a reward check re-optimised: its ``seeds``, or the one ``run_seed`` of the
    files written when the check took seed 0 alone."""
    return list(check.get("seeds", [check.get("run_seed", 0)]))


def reward_check_done(run_dir: str, seeds: int, check: RewardCheck = PAPER_CHECK) -> bool:
    """The cell's ``check`` covers its ``seeds``, took their final networks (a run resumed to
    more iterations is checked again), trained at the env's budget as it is now, and has the
    true-reward baseline beside them."""
    found, summary = reward_check(run_dir, check), _summary_or_none(run_dir)
    if found is None or summary is None:
        return False
    every_seed = set(range(seeds)) <= set(checked_seeds(found))
    final = found.get("iteration") == summary.get("iterations_done")
    config = summary.get("config", {})
    # A check written before lambda or scaling were part of the budget trained at the run's.
    before = {"gae_lambda": config.get("gae_lambda"), "value_target_scaling": False}
    recorded = {**before, **(found.get("budget") or {})}
    at_budget = recorded == dataclasses.asdict(check_budget(summary["env"], config, check))
    return every_seed and final and at_budget and bool(found.get("baseline"))


def check_budget(env: str, config: dict, check: RewardCheck = PAPER_CHECK) -> Budget:
    """The fresh agents' budget in ``check`` of a run of ``env`` with ``config`` (its
    summary's), as ``reoptimize`` resolves the check's options (``--refit``'s recipe too)."""
    scaling = config.get("value_target_scaling", False)
    own = env_budget(env, config["iterations"], config["gamma"], config["gae_lambda"], scaling)
    return given_budget(reoptimize_args(["RUN", *check.options], env), own)


def checks_to_do(run_dir: str, seeds: int) -> list[RewardCheck]:
    """The reward checks of a checked cell not yet done, in :data:`REWARD_CHECKS`' order."""
    return [check for check in REWARD_CHECKS if not reward_check_done(run_dir, seeds, check)]


def check_iterations(env: str, iterations: int, check: RewardCheck = PAPER_CHECK) -> int:
    """The fresh policies' TRPO iterations in ``check`` as ``reoptimize`` resolves its options
    (``--refit``'s recipe for the env included): the run's, unless the env's experts needed
    more or the options give another."""
    given = reoptimize_args(["RUN", *check.options], env).iterations
    return given or BUDGETS.get(env, {}).get("iterations", iterations)


def baseline_cached(out: str, env: str, intentions: int, check_iterations: int) -> bool:
    """A true-reward baseline of the env and K at ``check_iterations`` is in the cache."""
    prefix = baseline_prefix(env, intentions, check_iterations)
    cache = os.path.join(out, BASELINES_DIR)
    names = os.listdir(cache) if os.path.isdir(cache) else ()
    return any(name.startswith(prefix) for name in names)


def baseline_computers(
    cells: list[Cell], out: str, iterations: int
) -> set[tuple[Cell, RewardCheck]]:
    """Of the ``cells`` whose reward checks are to do, the first check of each env, K and
    budget whose true-reward baseline is not cached: it computes the baseline, the others
    read it."""
    first = {}
    for cell in cells:
        for check in REWARD_CHECKS if cell.reoptimized else ():
            budget = check_iterations(cell.env, iterations, check)
            first.setdefault((cell.env, cell.intentions, budget), (cell, check))
    return {pair for (env, k, its), pair in first.items() if not baseline_cached(out, env, k, its)}


# ---- time estimates -----------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Timings:
    """Per env, seconds per seed-iteration-intention and seconds to compile, of training and
    of the reward checks' fresh TRPO, from the finished cells' own timings."""

    training: dict[str, tuple[float, float]]
    checks: dict[str, tuple[float, float]]

    def of_training(self, env: str) -> tuple[float, float]:
        return self.training.get(env, MEASURED_SECONDS[env])

    def of_checks(self, env: str) -> tuple[float, float]:
        # Until a check of the env has finished: about training's, since the check runs every
        # seed on one device and skips only the discriminator and posterior.
        return self.checks.get(env, self.of_training(env))


def training_seconds(cell: Cell, seeds: int, iterations: int, timings: Timings) -> float:
    per_unit, compile_s = timings.of_training(cell.env)
    return compile_s + per_unit * seeds * iterations * cell.learned_intentions


def check_seconds(
    cell: Cell,
    seeds: int,
    iterations: int,
    timings: Timings,
    with_baseline: bool,
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
    refit = REFIT_SECONDS_PER_SEED * math.ceil(seeds / lanes) if "--refit" in check.options else 0.0
    compiles = programs + int(with_baseline)
    return refit + check.draws * (compile_s * compiles + per_unit * work)


def estimate_seconds(
    cell: Cell,
    status: Status,
    seeds: int,
    iterations: int,
    timings: Timings,
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
            cell, seeds, iterations, timings, with_baseline, check, check_processes
        )
    return seconds


def checks_draws_done(cell: Cell, run_dir: str, iterations: int) -> dict[RewardCheck, float]:
    """Per reward check of a trained cell, the draws a check stopped part-way has done; of one
    spread over processes, the mean of its seeds' parts (a part written: every draw)."""
    from emgail_jax.host.check_progress import draws_done

    done, numbers = {}, seed_numbers(_summary_or_none(run_dir))
    for check in REWARD_CHECKS:
        check_its = check_iterations(cell.env, iterations, check)
        parts = [check_part_path(run_dir, check, n) for n in numbers]
        if parts and os.path.isdir(os.path.dirname(parts[0])):
            per_part = [
                check.draws if os.path.exists(part) else draws_done(part, check.draws, check_its)
                for part in parts
            ]
            done[check] = float(np.mean(per_part))
        else:
            done[check] = draws_done(os.path.join(run_dir, check.file), check.draws, check_its)
    return done


def measured_seconds(runs_dir: str) -> Timings:
    """Per env, from finished cells' own timings and their reward checks': seconds per
    seed-iteration-intention (the median over cells) and seconds to compile."""
    found = {"training": {}, "checks": {}}
    for name in sorted(os.listdir(runs_dir)) if os.path.isdir(runs_dir) else ():
        run_dir = os.path.join(runs_dir, name)
        summary = _summary_or_none(run_dir)
        if not summary or summary.get("status") != "completed":
            continue
        timings = {
            "training": _training_timing(summary),
            "checks": _check_timing(reward_check(run_dir), summary["intentions"]),
        }
        for kind, timing in timings.items():
            if timing is not None:
                found[kind].setdefault(summary["env"], []).append(timing)
    median = lambda per_env: {env: tuple(np.median(t, 0).tolist()) for env, t in per_env.items()}
    return Timings(median(found["training"]), median(found["checks"]))


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


# ---- engines: where the cells run ---------------------------------------------------------------


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
    if __name__ != "__main__":  # imported (the tests): the workers cannot import this file
        ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])
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


# ---- separability -------------------------------------------------------------------------------

SEPARABILITY_COLUMNS = ("separability", "separability_std", "gmm_accuracy", "gmm_accuracy_std")


@dataclasses.dataclass(frozen=True)
class SeparabilityTable:
    """``separability.csv``: the separability and the Gaussian mixture's accuracy of each set
    of demonstrations (SEPARABILITY_COLUMNS), as :func:`measure_separability` makes them."""

    rows: dict[str, dict[str, float]]  # by DemoSet.name, the file's key

    def of(self, data: DemoSet) -> dict[str, float] | None:
        return self.rows.get(data.name)


def separability_table(out: str, cells: list[Cell]) -> SeparabilityTable:
    """The separability of the demonstrations the cells train on, computed once and kept in
    ``OUT/separability.csv`` (with what it held before)."""
    path = os.path.join(out, "separability.csv")
    table = {}
    if os.path.exists(path):
        with open(path) as f:
            table = {
                row.pop("data"): {k: float(v) for k, v in row.items()} for row in csv.DictReader(f)
            }
    wanted = {c.data.name: c.data for c in cells if c.intentions >= 2}
    missing = [name for name in wanted if name not in table]
    for name in missing:
        table[name] = measure_separability(wanted[name])
    if missing:
        with open(path, "w") as f:
            f.write(",".join(["data", *SEPARABILITY_COLUMNS]) + "\n")
            for name in sorted(table):
                row = [f"{table[name][c]:.4f}" for c in SEPARABILITY_COLUMNS]
                f.write(",".join([name, *row]) + "\n")
    return SeparabilityTable(table)


def measure_separability(data: DemoSet) -> dict[str, float]:
    """A row of :func:`separability_table`: the Gaussian mixture's accuracy on ``data``'s pairs
    (over its mixture seeds) and the separability normalised from it."""
    from emgail_jax.host.problem import make_problem
    from emgail_jax.method.metrics import gaussian_mixture_accuracies, separability_of

    options = {"radius": data.radius} if data.radius is not None else {}
    demos = make_problem(data.env, data.intentions, None, options).demos
    accuracies = gaussian_mixture_accuracies(
        demos.observations, demos.actions, demos.intentions, data.intentions
    )
    normalised = separability_of(accuracies, data.intentions)
    return {
        "separability": float(normalised.mean()),
        "separability_std": float(normalised.std()),
        "gmm_accuracy": float(accuracies.mean()),
        "gmm_accuracy_std": float(accuracies.std()),
    }


def robotics_sets() -> list[DemoSet]:
    """Table 3's columns: every robotics env at each K of the paper's."""
    return [DemoSet(env, k) for env, ks in ROBOTICS_INTENTIONS.items() for k in ks]


def driver_sets() -> list[DemoSet]:
    """Figure 4b's points: the driver at each radius of path 2."""
    return [DemoSet("driver", 2, radius) for radius in DRIVER_RADII]


# ---- results, selected by the cells' fields ----------------------------------------------------


@dataclasses.dataclass(frozen=True)
class CellResult:
    cell: Cell
    erd: np.ndarray  # [seeds]
    accuracy: np.ndarray | None  # [seeds]; None for GAIL
    parameters: int
    seconds_per_iteration: float
    reoptimized_erd: np.ndarray | None  # [seeds checked], fresh agents on the learned reward
    intentions_chosen: np.ndarray | None = None  # [seeds], --intentions auto
    intentions_held: np.ndarray | None = None  # [seeds], by the weights alone
    true_reward_erd: float | None = None  # the reward check's true-reward baseline
    devices: int = 2  # the XLA devices (cores) training ran on
    refit_erd: np.ndarray | None = None  # [seeds checked], the refit's check (REFIT_CHECK)
    refit_true_reward_erd: float | None = None  # its baseline, the best of its draws


@dataclasses.dataclass(frozen=True)
class Results:
    """The finished cells' results in the sweep's order (:func:`all_cells`)."""

    by_cell: dict[Cell, CellResult]

    def get(
        self,
        env: str,
        intentions: int,
        algo: str,
        *,
        variant: Variant = Variant.DEFAULT,
        radius: float | None = None,
    ) -> CellResult | None:
        """The result of the one cell of these fields, if it has finished."""
        return self.by_cell.get(Cell(env, intentions, algo, radius=radius, variant=variant))

    def where(self, chosen: Callable[[Cell], bool]) -> list[CellResult]:
        """The results of the cells ``chosen`` keeps, in the sweep's order."""
        return [result for cell, result in self.by_cell.items() if chosen(cell)]


def on_driver_radius(cell: Cell) -> bool:
    """Figure 5a's cells: the driver at one radius of path 2."""
    return cell.radius is not None


def robotics_default(cell: Cell) -> bool:
    """Figure 6's cells (and 5b's of K >= 2): a robotics env with the defaults."""
    return cell.env != "driver" and cell.variant == Variant.DEFAULT


def robotics_many(cell: Cell) -> bool:
    """Figure 5b's cells: a robotics env with the defaults and more than one intention."""
    return robotics_default(cell) and cell.intentions >= 2


def collect(out: str, cells: list[Cell], seeds: int, iterations: int) -> Results:
    """The results of the cells that have finished."""
    results = {}
    for cell in cells:
        run_dir = os.path.join(out, "runs", cell.name)
        if cell_status(run_dir, seeds, iterations) == Status.DONE:
            results[cell] = read_cell_result(cell, run_dir)
    return Results(results)


def read_cell_result(cell: Cell, run_dir: str) -> CellResult:
    """A finished cell's final numbers, from its ``summary.json`` and ``reoptimize.json``."""
    summary = read_summary(run_dir)
    final = FinalResults.from_summary(summary)
    accuracy = final.cluster_accuracy
    check, refit = reward_check(run_dir), reward_check(run_dir, REFIT_CHECK)
    timings = summary["timings"]
    return CellResult(
        cell=cell,
        erd=np.asarray(final.erd, float),
        accuracy=None if accuracy is None else np.asarray(accuracy, float),
        parameters=int(summary["parameters"]["total"]),
        seconds_per_iteration=timings["train_time_s"] / timings["iterations"],
        reoptimized_erd=None if check is None else reoptimized_erds(check),
        intentions_chosen=final.intentions_chosen,
        intentions_held=final.intentions_held,
        true_reward_erd=None if check is None else true_reward_erd(check),
        devices=len(summary.get("devices", ())) or 2,
        refit_erd=None if refit is None else reoptimized_erds(refit),
        refit_true_reward_erd=None if refit is None else true_reward_erd(refit),
    )


def reoptimized_erds(check: dict) -> np.ndarray:
    """``[seeds checked]`` a reward check's ERD per seed: its list, or the one float of the
    files written when the check took seed 0 alone; NaN for a seed without one."""
    return np.atleast_1d(np.asarray(check.get("erd"), float))


def true_reward_erd(check: dict) -> float | None:
    """The ERD of a reward check's true-reward baseline; None if it has none."""
    erd = (check.get("baseline") or {}).get("erd")
    return None if erd is None else float(erd)


# ---- tables -------------------------------------------------------------------------------------


def _mean_std(values) -> str:
    return f"{np.mean(values):.1f} ± {np.std(values):.1f}"


def table3_rows(
    results: Results, separability: SeparabilityTable
) -> list[tuple[str, DemoSet, float, float, int]]:
    """Table 3's accuracies: (method, demonstrations, mean %, std %, seeds) of the GMM and of
    every finished cell of TABLE3_METHODS."""
    rows = []
    for data in robotics_sets():
        gmm = separability.of(data)
        if gmm is not None:
            rows.append(("gmm", data, 100 * gmm["gmm_accuracy"], 100 * gmm["gmm_accuracy_std"], 5))
        for algo, variant in TABLE3_METHODS:
            result = results.get(data.env, data.intentions, algo, variant=variant)
            if result is not None and result.accuracy is not None:
                acc = 100 * result.accuracy
                rows.append((result.cell.method, data, acc.mean(), acc.std(), len(acc)))
    return rows


def write_table3(out: str, results: Results, separability: SeparabilityTable) -> None:
    rows = table3_rows(results, separability)
    with open(os.path.join(out, "table3.csv"), "w") as f:
        f.write("env,intentions,method,accuracy_mean,accuracy_std,seeds\n")
        for method, data, mean, std, n in rows:
            f.write(f"{data.env},{data.intentions},{method},{mean / 100:.4f},{std / 100:.4f},{n}\n")
    found = {(method, data): (mean, std) for method, data, mean, std, _ in rows}
    columns = robotics_sets()
    lines = [
        "Clustering accuracy (%) of the expert pairs, mean ± std over seeds (GMM: over 5 "
        "mixture seeds); the paper's value in brackets.",
        "",
        "| method | " + " | ".join(data.name for data in columns) + " |",
        "|---|" + "---:|" * len(columns),
    ]
    for method in ("gmm", *(method_name(algo, variant) for algo, variant in TABLE3_METHODS)):
        cells = []
        for data in columns:
            value = found.get((method, data))
            text = "—" if value is None else f"{value[0]:.1f} ± {value[1]:.1f}"
            paper = PAPER_TABLE3.get(method, {}).get(data.name)
            cells.append(text + (f" [{paper}]" if paper is not None else ""))
        lines.append(f"| {ALGO_LABELS[method]} | " + " | ".join(cells) + " |")
    _write_text(os.path.join(out, "table3.md"), lines)


def write_choosing_k(out: str, results: Results) -> None:
    """``choosing-k.md`` and ``.csv``: the K ``--intentions auto`` chose on every seed of each
    set of K true intentions, and its accuracy and ERD beside the same cell with K given."""
    rows = []
    for env, ks in CHOOSING_K.items():
        for k in ks:
            auto = results.get(env, k, "emgail", variant=Variant.AUTO)
            if auto is not None:
                rows.append((env, k, auto, results.get(env, k, "emgail")))
    with open(os.path.join(out, "choosing-k.csv"), "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(
            ["env", "intentions", "chosen", "held", "accuracy_mean", "accuracy_std", "erd_mean",
             "erd_std", "given_accuracy_mean", "given_erd_mean", "seeds"]
        )  # fmt: skip
        for env, k, auto, given in rows:
            numbers = [auto.accuracy.mean(), auto.accuracy.std(), auto.erd.mean(), auto.erd.std()]
            numbers += (
                [math.nan, math.nan] if given is None else [given.accuracy.mean(), given.erd.mean()]
            )
            counts = [_per_seed(auto.intentions_chosen, " "), _per_seed(auto.intentions_held, " ")]
            writer.writerow([env, k, *counts, *(f"{v:.4f}" for v in numbers), len(auto.erd)])
    lines = [
        "K chosen by `--intentions auto` (from the env's maximum) on demonstrations of K true "
        "intentions, per seed (and before the seeds' consensus, by the weights alone); its "
        "clustering accuracy (%) and ERD, mean ± std over seeds, beside the same cell with K "
        "given.",
        "",
        "| demonstrations | K chosen (per seed) | held by weights | accuracy, K chosen "
        "| accuracy, K given | ERD, K chosen | ERD, K given |",
        "|---|---|---|---:|---:|---:|---:|",
    ]
    for env, k, auto, given in rows:
        erd = lambda r: "—" if r is None else f"{r.erd.mean():.3f} ± {r.erd.std():.3f}"
        accuracy = lambda r: "—" if r is None else _mean_std(100 * r.accuracy)
        lines.append(
            f"| {env}, {k} of {auto.cell.learned_intentions} | "
            f"{_per_seed(auto.intentions_chosen)} | {_per_seed(auto.intentions_held)} | "
            f"{accuracy(auto)} | {accuracy(given)} | {erd(auto)} | {erd(given)} |"
        )
    _write_text(os.path.join(out, "choosing-k.md"), lines)


def _per_seed(counts, separator: str = ", ") -> str:
    return "—" if counts is None else separator.join(str(c) for c in counts)


def write_table2(out: str, results: Results, seeds: int) -> None:
    lines = [
        f"Learnable parameters (policy, value, discriminator and posterior, as `summary.json` "
        f"counts them) and seconds per iteration of the K = 2 cells on this machine's CPU "
        f"({seeds} seeds over the cores in brackets, 2 or 1; per seed in the last column), "
        f"beside the paper's (one seed, "
        f"RTX 2080 Ti). The seconds are each cell's training wall time as it ran, with whatever "
        f"else shared the cores (the committed sweep mostly ran two cells at a time, and paused "
        f"for test-suite measurements): an upper bound, not a benchmark; `make bench` measures "
        f"on a quiet machine (README, Speed).",
        "",
        "| env | algorithm | parameters | paper | s / iteration (cores) | per seed | paper (GPU) |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    for env in ROBOTICS_INTENTIONS:
        for algo in ALGOS:
            result = results.get(env, 2, algo)
            params, paper_seconds = PAPER_TABLE2[env][algo]
            if result is None:
                ours, seconds, per_seed = "—", "—", "—"
            else:
                ours = f"{result.parameters:,}"
                seconds = f"{result.seconds_per_iteration:.2f} ({result.devices})"
                per_seed = f"{result.seconds_per_iteration / seeds:.2f}"
            lines.append(
                f"| {env} | {ALGO_LABELS[algo]} | {ours} | {params} | {seconds} | {per_seed} "
                f"| {paper_seconds} |"
            )
    _write_text(os.path.join(out, "table2.md"), lines)


# fig6.csv: the jointly trained policies' ERD (what the paper's code scored), then the reward
# check's (the paper's text's ERD, §5.2), after ``seeds`` so that every older column keeps its
# place, then the refit's check (REFIT_CHECK).
FIG6_COLUMNS = (
    "env", "intentions", "algo", "separability", "erd_mean", "erd_std", "reoptimized_erd",
    "seeds", "reoptimized_erd_std", "true_reward_erd", "reoptimized_seeds",
    "refit_erd", "refit_erd_std", "refit_true_reward_erd",
)  # fmt: skip


def write_erd_csvs(out: str, results: Results, separability: SeparabilityTable) -> None:
    with open(os.path.join(out, "fig5a.csv"), "w") as f:
        f.write("algo,radius,separability,erd_mean,erd_std,seeds\n")
        for result in results.where(on_driver_radius):
            cell = result.cell
            sep = (separability.of(cell.data) or {}).get("separability", math.nan)
            f.write(f"{cell.algo},{cell.radius:g},{sep:.4f},{result.erd.mean():.4f},"
                    f"{result.erd.std():.4f},{len(result.erd)}\n")  # fmt: skip
    with open(os.path.join(out, "fig6.csv"), "w", newline="") as f:
        writer = csv.writer(f, lineterminator="\n")
        writer.writerow(FIG6_COLUMNS)
        for result in results.where(robotics_default):
            cell = result.cell
            sep = (separability.of(cell.data) or {}).get("separability")
            checked = np.asarray([] if result.reoptimized_erd is None else result.reoptimized_erd)
            refit = np.asarray([] if result.refit_erd is None else result.refit_erd)
            writer.writerow(
                [cell.env, cell.intentions, cell.algo, _decimal(sep),
                 f"{result.erd.mean():.4f}", f"{result.erd.std():.4f}",
                 _decimal(checked.mean() if len(checked) else None), len(result.erd),
                 _decimal(checked.std() if len(checked) > 1 else None),
                 _decimal(result.true_reward_erd), len(checked) or "",
                 _decimal(refit.mean() if len(refit) else None),
                 _decimal(refit.std() if len(refit) > 1 else None),
                 _decimal(result.refit_true_reward_erd)]
            )  # fmt: skip


def _decimal(value: float | None) -> str:
    """A number of a CSV, or empty where there is none."""
    return "" if value is None or not np.isfinite(value) else f"{value:.4f}"


def _write_text(path: str, lines: list[str]) -> None:
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")


# ---- figures: the paper's Figures 4-6, means as lines, ± std as shading -------------------------

COLORS = {"emgail": "tab:red", "infogail": "tab:blue", "gail": "tab:green"}
ERD_TOP = 1.05  # the top of the ERD axis: 1 is random actions


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, out: str, name: str) -> str:
    fig.tight_layout()
    fig.savefig(os.path.join(out, name), dpi=120, bbox_inches="tight")
    _pyplot().close(fig)
    return name


def _save_drawn(fig, out: str, name: str, legend_on, **legend) -> str | None:
    """``fig`` saved as ``name`` with a legend on the axes ``legend_on``, if any of its axes
    has a line (a point finished); otherwise dropped."""
    if not any(ax.lines for ax in fig.axes):
        _pyplot().close(fig)
        return None
    legend_on.legend(**legend)
    return _save(fig, out, name)


def _band(ax, x, mean, std, **style) -> None:
    order = np.argsort(x)
    x, mean, std = (np.asarray(v)[order] for v in (x, mean, std))
    (line,) = ax.plot(x, mean, marker="o", **style)
    ax.fill_between(x, mean - std, mean + std, alpha=0.2, color=line.get_color())


def _erd_axis(ax) -> None:
    """The paper's ERD scale, 0 to 1 (random actions); a mean beyond it (a policy worse than
    random on some intention) is marked at the top edge with its value."""
    ax.set_ylim(0, ERD_TOP)
    ax.set_ylabel("normalised ERD")
    marked = {}  # values marked at one x, each under the one before, so that none hides another
    for line in list(ax.lines):
        for x, y in zip(*line.get_data(), strict=True):
            if y > ERD_TOP:
                ax.plot(x, ERD_TOP, marker="^", color=line.get_color(), clip_on=False)
                below = marked[x] = marked.get(x, -1) + 1
                ax.annotate(
                    f"{y:.2f}", (x, ERD_TOP), xytext=(-6, -3 - 10 * below),
                    textcoords="offset points", ha="right", va="top", color=line.get_color(),
                    fontsize=8,
                )  # fmt: skip


def _erd_band(ax, points: list[tuple[float, np.ndarray]], algo: str) -> None:
    """One algorithm's line of (x, ERD per seed) points."""
    x, erds = zip(*points, strict=True)
    mean, std = [e.mean() for e in erds], [e.std() for e in erds]
    _band(ax, x, mean, std, color=COLORS[algo], label=ALGO_LABELS[algo])


def draw_fig4a(out: str, separability: SeparabilityTable) -> str | None:
    """The separability of the shipped demonstrations against K, per env."""
    fig, ax = _pyplot().subplots(figsize=(5, 3.5))
    for env, ks in ROBOTICS_INTENTIONS.items():
        points = [(k, separability.of(DemoSet(env, k))) for k in ks]
        points = [(k, row) for k, row in points if row is not None]
        if points:
            ks_, rows = zip(*points, strict=True)
            mean = [r["separability"] for r in rows]
            _band(ax, ks_, mean, [r["separability_std"] for r in rows], label=env)
    ax.set(xlabel="number of intentions", ylabel="separability", ylim=(0, 1.05), xticks=(2, 3, 4))
    return _save_drawn(fig, out, "fig4a.png", ax)


def draw_fig4b(out: str, separability: SeparabilityTable) -> str | None:
    """The driver's separability against the radius of path 2."""
    found = [(data.radius, separability.of(data)) for data in driver_sets()]
    driver = sorted((radius, row) for radius, row in found if row is not None)
    if not driver:
        return None
    fig, ax = _pyplot().subplots(figsize=(5, 3.5))
    _band(ax, [r for r, _ in driver], [v["separability"] for _, v in driver],
          [v["separability_std"] for _, v in driver], color="black")  # fmt: skip
    ax.set(xlabel="radius of path 2", ylabel="separability", ylim=(0, 1.05))
    return _save(fig, out, "fig4b.png")


def draw_erd_against_separability(
    out: str,
    results: list[CellResult],
    separability: SeparabilityTable,
    *,
    name: str,
    title: str,
) -> str | None:
    """Figures 5a and 5b: each algorithm's ERD against the separability of its cells' data."""
    fig, ax = _pyplot().subplots(figsize=(6.5, 3.5))
    for algo in ALGOS:
        found = [(separability.of(r.cell.data), r.erd) for r in results if r.cell.algo == algo]
        points = [(row["separability"], erd) for row, erd in found if row is not None]
        if points:
            _erd_band(ax, points, algo)
    ax.set(xlabel="separability", title=title)
    _erd_axis(ax)
    # The legend beside the axes, clear of the lines.
    return _save_drawn(fig, out, name, ax, loc="upper left", bbox_to_anchor=(1.02, 1))


# Figure 6's line styles: whose ERD a line is (its colour says which algorithm's run).
ERD_STYLES = {
    "-": "jointly trained policies",
    "--": "fresh TRPO on the learned reward (§5.2)",
    "-.": f"the same on the refitted reward, best of {REFIT_DRAWS} (reoptimize --refit)",
    ":": "fresh TRPO on the true reward",
}


def draw_fig6(out: str, results: Results) -> str | None:
    """ERD against K per env; K = 1 is GAIL on one expert, the start of every line. Dashed,
    the reward check of the cells that have one (mean over its seeds); dash-dotted, the refit's
    check; dotted, the true-reward baseline."""
    fig, axes = _pyplot().subplots(1, len(ROBOTICS_INTENTIONS), figsize=(14, 3.5))
    for ax, (env, ks) in zip(axes, ROBOTICS_INTENTIONS.items(), strict=True):
        floor = results.get(env, 1, "gail")
        for algo in ALGOS:
            points = [(1, floor.erd)] if floor is not None else []
            found = [(k, results.get(env, k, algo)) for k in ks]
            points += [(k, result.erd) for k, result in found if result is not None]
            if points:
                _erd_band(ax, points, algo)
            checked = [(k, r.reoptimized_erd.mean()) for k, r in found if _checked(r)]
            if checked:
                ax.plot(*zip(*checked, strict=True), linestyle="--", marker="s",
                        fillstyle="none", color=COLORS[algo])  # fmt: skip
            refit = [(k, r.refit_erd.mean()) for k, r in found if r and r.refit_erd is not None]
            if refit:
                ax.plot(*zip(*refit, strict=True), linestyle="-.", marker="^",
                        fillstyle="none", color=COLORS[algo])  # fmt: skip
        baseline = true_reward_points(results, env, ks)
        if baseline:
            ax.plot(*zip(*baseline, strict=True), linestyle=":", marker="d", color="black")
        ax.set(title=env, xlabel="number of intentions", xticks=(1, *ks))
        _erd_axis(ax)
    legend = {"handles": _fig6_legend(axes), "loc": "upper left", "bbox_to_anchor": (1.02, 1)}
    return _save_drawn(fig, out, "fig6.png", axes[-1], **legend)


def _checked(result: CellResult | None) -> bool:
    return result is not None and result.reoptimized_erd is not None


def true_reward_points(results: Results, env: str, ks: tuple[int, ...]) -> list[tuple[int, float]]:
    """``(K, ERD)`` of the env's true-reward baseline at each K a reward check has one (the
    cells of an env and K read one cached baseline)."""
    points = []
    for k in ks:
        found = [results.get(env, k, algo) for algo in ALGOS]
        erds = [r.true_reward_erd for r in found if r is not None and r.true_reward_erd is not None]
        if erds:
            points.append((k, erds[0]))
    return points


def _fig6_legend(axes) -> list:
    """Every algorithm drawn, by its colour, then the line styles drawn, by whose ERD."""
    from matplotlib.lines import Line2D

    lines = [line for ax in axes for line in ax.lines]
    algorithms = {line.get_label(): line for line in lines if not line.get_label().startswith("_")}
    drawn = {line.get_linestyle() for line in lines}
    styles = [
        Line2D([], [], color="black", linestyle=style, label=text)
        for style, text in ERD_STYLES.items()
        if style in drawn
    ]
    return [*algorithms.values(), *styles]


def draw_figures(out: str, results: Results, separability: SeparabilityTable) -> list[str]:
    """The figures that what is finished can draw; returns their file names."""
    drawn = [
        draw_fig4a(out, separability),
        draw_fig4b(out, separability),
        draw_erd_against_separability(
            out, results.where(on_driver_radius), separability, name="fig5a.png", title="driver"
        ),
        draw_erd_against_separability(
            out, results.where(robotics_many), separability, name="fig5b.png", title="robotics envs"
        ),
        draw_fig6(out, results),
    ]
    return [name for name in drawn if name is not None]


def write_report(out: str, cells: list[Cell], seeds: int, iterations: int) -> list[str]:
    """Every table, CSV and figure from every finished cell of the sweep (the separability of
    ``cells``' demonstrations is computed if not yet known); returns what was written."""
    os.makedirs(out, exist_ok=True)
    results = collect(out, all_cells(), seeds, iterations)
    separability = separability_table(out, cells)
    write_table3(out, results, separability)
    write_table2(out, results, seeds)
    write_choosing_k(out, results)
    write_erd_csvs(out, results, separability)
    figures = draw_figures(out, results, separability)
    return [
        "separability.csv",
        "table2.md",
        "table3.md",
        "table3.csv",
        "choosing-k.md",
        "choosing-k.csv",
        "fig5a.csv",
        "fig6.csv",
        *figures,
    ]


# ---- command line -------------------------------------------------------------------------------


def _format_duration(seconds: float) -> str:
    hours, rest = divmod(int(seconds), 3600)
    return f"{hours}h{rest // 60:02d}m" if hours else f"{rest // 60}m{rest % 60:02d}s"


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
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
