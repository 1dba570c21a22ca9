"""The sweep's cells: the paper's grid of runs (Tables 2-3, Figures 4-6) and, beyond the paper,
K chosen from the demonstrations; each cell an ordinary run directory, and where that directory
stands."""

from __future__ import annotations

import dataclasses
import enum
import fnmatch
import os

from emgail_jax.host.run_spec import RunError, read_summary

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

# Separability 0.06 to 0.93 (docs/environments.md, "The driver and its separability").
DRIVER_RADII = (4.0, 5.0, 6.0, 7.0, 8.0, 10.0, 15.0, 20.0)
ALGOS = ("emgail", "infogail", "gail")


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
FIGURES = ("fig4a", "fig4b", "fig5a", "fig5b", "fig6", "table2", "table3", "choosing-k")


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
    """``emgail``, ``emgail-onehot``: a key of the report's ALGO_LABELS and PAPER_TABLE3."""
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


def summary_or_none(run_dir: str) -> dict | None:
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
    summary = summary_or_none(run_dir)
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


def on_driver_radius(cell: Cell) -> bool:
    """Figure 5a's cells: the driver at one radius of path 2."""
    return cell.radius is not None


def robotics_default(cell: Cell) -> bool:
    """Figure 6's cells (and 5b's of K >= 2): a robotics env with the defaults."""
    return cell.env != "driver" and cell.variant == Variant.DEFAULT


def robotics_many(cell: Cell) -> bool:
    """Figure 5b's cells: a robotics env with the defaults and more than one intention."""
    return robotics_default(cell) and cell.intentions >= 2


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
