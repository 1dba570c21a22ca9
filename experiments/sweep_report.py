"""The sweep's report: Tables 2-3, Figures 4-6, the choosing-K table and their CSVs, from
whatever cells have finished, beside the paper's values where it gives them."""

from __future__ import annotations

import csv
import dataclasses
import math
import os
from collections.abc import Callable

import numpy as np

from emgail_jax.host.final_results import FinalResults
from emgail_jax.host.run_spec import read_summary
from emgail_jax.reward.draws import single_draws
from sweep_cells import (
    ALGOS,
    CHOOSING_K,
    DRIVER_RADII,
    ROBOTICS_INTENTIONS,
    Cell,
    DemoSet,
    Status,
    Variant,
    all_cells,
    cell_status,
    method_name,
    on_driver_radius,
    robotics_default,
    robotics_many,
)
from sweep_checks import REFIT_CHECK, REFIT_DRAWS, reward_check

# The keys of a check's headline (draws.single_draws).
SINGLE_DRAWS = ("erd_draws_mean", "erd_draws_std", "erd_draws_n", "success_rate", "final_distance")

ALGO_LABELS = {
    "emgail": "EM-GAIL",
    "emgail-onehot": "EM-GAIL (one-hot input)",
    "emgail-pair": "EM-GAIL (per-pair E-step)",
    "emgail-auto": "EM-GAIL, K chosen (--intentions auto)",
    "infogail": "Info/IntentionGAIL",
    "gail": "GAIL",
    "gmm": "GMM",
}

# Table 3's learned methods (algorithm, variant), after the GMM of the separability table.
TABLE3_METHODS = (
    ("infogail", Variant.DEFAULT),
    ("emgail", Variant.DEFAULT),
    ("emgail", Variant.ONEHOT),
    ("emgail", Variant.PAIR),
)

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
    # The refit's check over every seed x draw (draws.single_draws): the headline.
    refit_draws: dict | None = None
    true_reward_erd_lowest: float | None = None  # the refit's baseline's lowest-ERD draw
    true_reward_success_rate: float | None = None  # over every draw of the refit's baseline


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
        **({} if refit is None else refit_draws_read(refit)),
    )


def refit_draws_read(refit: dict) -> dict:
    """What a refit's check holds of its single draws and its baseline's draws, as
    :class:`CellResult` fields; a check recorded before it summed them up is summed up from its
    ``draws`` (its baseline's success over every draw it cannot give: it kept the best's)."""
    found = {name: refit.get(name) for name in SINGLE_DRAWS}
    if found["erd_draws_n"] is None:
        found = single_draws(refit.get("draws", [refit]))
    baseline = refit.get("baseline") or {}
    erds = baseline.get("draws_erd") or [baseline.get("erd")]
    lowest = baseline.get("erd_lowest", None if None in erds else min(erds))
    return {
        "refit_draws": found,
        "true_reward_erd_lowest": lowest,
        "true_reward_success_rate": baseline.get("success_rate"),
    }


def reoptimized_erds(check: dict) -> np.ndarray:
    """``[seeds checked]`` a reward check's ERD per seed: its list, or the one float of the
    files written when the check took seed 0 alone; NaN for a seed without one."""
    return np.atleast_1d(np.asarray(check.get("erd"), float))


def true_reward_erd(check: dict) -> float | None:
    """The ERD of a reward check's true-reward baseline; None if it has none."""
    erd = (check.get("baseline") or {}).get("erd")
    return None if erd is None else float(erd)


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
        f"on a quiet machine (docs/speed.md).",
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
# place, then the refit's check (REFIT_CHECK): best of its draws, then its headline, the mean of
# every seed x draw with the sample sd, its baseline's lowest-ERD draw, and the share of
# episodes meeting the experts' bars of every seed x draw and of every baseline draw.
FIG6_COLUMNS = (
    "env", "intentions", "algo", "separability", "erd_mean", "erd_std", "reoptimized_erd",
    "seeds", "reoptimized_erd_std", "true_reward_erd", "reoptimized_seeds",
    "refit_erd", "refit_erd_std", "refit_true_reward_erd",
    "refit_erd_draws_mean", "refit_erd_draws_std", "true_reward_erd_lowest",
    "refit_success_rate", "true_reward_success_rate",
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
                 _decimal(result.refit_true_reward_erd), *_single_draws_columns(result)]
            )  # fmt: skip


def _single_draws_columns(result: CellResult) -> list[str]:
    """fig6.csv's columns of the refit's single draws and its baseline's draws."""
    found = result.refit_draws or {}
    return [
        _decimal(found.get("erd_draws_mean")),
        _decimal(found.get("erd_draws_std")),
        _decimal(result.true_reward_erd_lowest),
        _decimal(found.get("success_rate")),
        _decimal(result.true_reward_success_rate),
    ]


def _decimal(value: float | None) -> str:
    """A number of a CSV, or empty where there is none."""
    return "" if value is None or not np.isfinite(value) else f"{value:.4f}"


def _write_text(path: str, lines: list[str]) -> None:
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")


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
    "-.": f"the same on the refitted reward, mean of {REFIT_DRAWS} draws x seeds "
    "(reoptimize --refit)",
    ":": "fresh TRPO on the true reward",
}


def draw_fig6(out: str, results: Results) -> str | None:
    """ERD against K per env; K = 1 is GAIL on one expert, the start of every line. Dashed,
    the reward check of the cells that have one (mean over its seeds); dash-dotted, the refit's
    check (mean over every seed x draw); dotted, the true-reward baseline."""
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
            refit = [(k, refit_single_draws(r)) for k, r in found]
            refit = [(k, erd) for k, erd in refit if erd is not None]
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


def refit_single_draws(result: CellResult | None) -> float | None:
    """The mean ERD of every seed x draw of the cell's refit check; None without one."""
    return ((result and result.refit_draws) or {}).get("erd_draws_mean")


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
