"""Smoke runs of the experiment scripts under experiments/ on tiny settings: they are not part
of the package, so nothing else would notice when one of them no longer runs."""

import csv
import importlib.util
import json
import os
import pathlib
import re
import shutil
import socket
import sys

import numpy as np
import pytest

from emgail_jax.host import checkpoints
from emgail_jax.host.check_progress import FinishedDraws

pytestmark = pytest.mark.heavy

EXPERIMENTS = pathlib.Path(__file__).resolve().parents[1] / "experiments"


def _load(name):
    spec = importlib.util.spec_from_file_location(name, EXPERIMENTS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look their module up while it executes
    spec.loader.exec_module(module)
    return module


@pytest.mark.slow  # a child process with a cold compilation cache: 60-100 s
def test_bench_measures_the_driver(capsys):
    """The benchmark's child process on the driver with few seeds and chunks: every number it
    reports is there and positive."""
    bench = _load("bench")
    assert bench.main(["--envs", "driver:2", "--seeds", "2", "--chunks", "1"]) == 0
    out = capsys.readouterr().out
    for line in ("== driver-2", "2 seed(s):", "E-step", "M-step", "B-step", "evaluation",
                 "compile (2 seeds", "warm cache", "init alone",
                 "peak resident memory"):  # fmt: skip
        assert line in out, line


@pytest.mark.slow  # two TRPO programs compiled: about 60 s
def test_the_reward_check_benchmark_times_both_ways_on_the_driver(capsys):
    """Both ways are timed and their ratio printed; 12 iterations score 10 and 12 in one."""
    bench = _load("bench_reward_check")
    assert bench.main(["--env", "driver", "--rows", "2", "--iterations", "12"]) == 0
    out = capsys.readouterr().out
    scored = [int(n) for n in re.findall(r"(\d+) iterations scored", out)]
    timed = [float(seconds) for seconds in re.findall(r"([\d.]+) s per row-iteration", out)]
    assert scored == [10, 12] and len(timed) == 2 and min(timed) > 0
    assert float(out.split("ratio every iteration / as shipped:")[1]) > 0


@pytest.mark.slow  # four processes compile a TRPO program: about 60 s
def test_the_check_processes_benchmark_times_both_ways_on_the_driver(capsys):
    bench = _load("bench_check_processes")
    assert bench.main(["--env", "driver", "--rows", "2", "--iterations", "10"]) == 0
    out = capsys.readouterr().out
    rates = [float(rate) for rate in re.findall(r"([\d.]+) row-iterations per s", out)]
    assert len(rates) == 2 and min(rates) > 0
    assert float(out.split("ratio 2 processes / one process:")[1]) > 0


def test_the_check_processes_benchmark_refuses_one_row(capsys):
    with pytest.raises(SystemExit) as stopped:
        _load("bench_check_processes").main(["--rows", "1"])
    assert stopped.value.code == 2
    assert "needs 2 or more rows" in capsys.readouterr().err


def test_draw_choice_gives_each_rules_erd_from_the_checks_file(tmp_path, capsys):
    """Learned intention 0's draw 1 out-earns the demonstrations far and misses its expert: the
    check's rule keeps it, the nearest rule and the true ERD keep draw 0."""
    draw_choice = _load("draw_choice")

    def draw(earned, erd):  # one seed, 2 intentions, a constant curve of 12 scored iterations
        earned = {"fresh_policies": earned, "demonstrations": [1.0, 1.0]}
        row = {"run_seed": 0, "matching": [0, 1], "returns": [1.0, 1.0], "erd": float(np.mean(erd)),
               "erd_per_intention": erd, "erd_curve_per_intention": [erd] * 12,
               "learned_reward_per_step": earned}  # fmt: skip
        return {"per_seed": [row]}

    check = tmp_path / "check.json"
    check.write_text(
        json.dumps({"draws": [draw([1.0, 0.9], [0.1, 0.2]), draw([1.8, 1.0], [0.9, 0.1])]})
    )
    assert draw_choice.rule_erds(json.loads(check.read_text())) == {
        0: {
            "most": pytest.approx(0.5),
            "nearest": pytest.approx(0.1),
            "by true ERD": pytest.approx(0.1),
        }
    }
    assert draw_choice.main([str(check)]) == 0
    assert capsys.readouterr().out.splitlines()[-1].split() == ["mean", "0.500", "0.100", "0.100"]
    one = tmp_path / "one.json"
    one.write_text(json.dumps({"draws": [draw([1.0, 0.9], [0.1, 0.2])]}))
    assert draw_choice.main([str(one)]) == 2
    assert "no check of several draws" in capsys.readouterr().err


def test_the_reward_check_benchmark_refuses_no_iterations(capsys):
    with pytest.raises(SystemExit) as stopped:
        _load("bench_reward_check").main(["--iterations", "0"])
    assert stopped.value.code == 2
    assert "give positive numbers" in capsys.readouterr().err


def test_driver_separability_writes_its_table(tmp_path, capsys):
    module = _load("driver_separability")
    assert module.main(["--radii", "4", "20", "--out", str(tmp_path)]) == 0
    rows = (tmp_path / "separability.csv").read_text().splitlines()
    assert rows[0].startswith("radius,destination_gap,separability")
    radii = [float(row.split(",")[0]) for row in rows[1:]]
    assert radii == pytest.approx([4.0, 20.0])
    # More overlap at the smaller radius.
    separabilities = [float(row.split(",")[2]) for row in rows[1:]]
    assert separabilities[0] < separabilities[1]


# ---- the sweep (make sweep) --------------------------------------------------------------------


def test_sweep_cells_are_the_papers_experiments():
    sweep = _load("sweep")
    cells = sweep.all_cells()
    names = [cell.name for cell in cells]
    assert len(names) == len(set(names)) == 68 + 11  # the paper's, and choosing K
    for name in ("reacher-2-emgail", "hopper-3-emgail-pair", "swimmer-1-gail", "driver-r20-gail"):
        assert name in names, name
    assert len(sweep.select(cells, "fig5a")) == 3 * len(sweep.DRIVER_RADII)
    # halfcheetah: K = 1 (GAIL) and, for K = 2 and 3, three algorithms and EM-GAIL with the
    # paper's one-hot input and with its per-pair E-step.
    assert len(sweep.select(cells, "halfcheetah")) == 1 + 2 * 5
    assert [c.name for c in sweep.select(cells, "reacher-2-emgail")] == ["reacher-2-emgail"]
    assert [c.name for c in sweep.select(cells, "reacher-2-e*")] == [
        "reacher-2-emgail",
        "reacher-2-emgail-onehot",
        "reacher-2-emgail-pair",
        "reacher-2-emgail-auto",
    ]
    # The reward check: every EM-GAIL cell of Figure 6, and at K = 2 the two it is compared with.
    reoptimized = [c.name for c in cells if c.reoptimized]
    assert reoptimized == [
        f"{e}-{k}-{algo}"
        for e, ks in sweep.ROBOTICS_INTENTIONS.items()
        for k in ks
        for algo in sweep.ALGOS
        if algo == "emgail" or k == 2
    ]
    assert "hopper-2-gail" in reoptimized and "hopper-3-gail" not in reoptimized
    with pytest.raises(sweep.SweepError, match="matches no cell"):
        sweep.select(cells, "walker")


def test_choosing_k_cells_train_auto_on_the_first_k_intentions(tmp_path):
    sweep = _load("sweep")
    cells = {c.name: c for c in sweep.select(sweep.all_cells(), "choosing-k")}
    assert sorted(cells) == sorted(
        [f"{e}-{k}-emgail-auto" for e, ks in sweep.CHOOSING_K.items() for k in ks]
        + ["driver-2-emgail", "driver-3-emgail", "driver-4-emgail"]
    )
    reacher2, reacher4 = cells["reacher-2-emgail-auto"], cells["reacher-4-emgail-auto"]
    assert reacher2.learned_intentions == reacher4.learned_intentions == 4
    args = reacher2.run_args((), str(tmp_path))
    assert args[:4] == ["--env", "reacher", "--intentions", "auto"]
    assert args[args.index("--demos") + 1] == str(tmp_path / "demos" / "reacher-2.npz")
    assert "--demos" not in reacher4.run_args((), str(tmp_path))  # the shipped set, all 4
    assert "--demos" not in cells["driver-3-emgail"].run_args((), str(tmp_path))
    sweep.write_demonstrations(cells["driver-3-emgail-auto"], str(tmp_path))
    written = np.load(tmp_path / "demos" / "driver-3.npz")
    assert sorted(set(written["intentions"].tolist())) == [0, 1, 2]


def test_choosing_k_table_sets_the_chosen_k_beside_k_given(tmp_path):
    sweep = _load("sweep")
    cells = {c.name: c for c in sweep.all_cells()}

    def result(name, accuracy, erd, chosen=None, held=None):
        return sweep.CellResult(
            cells[name], np.asarray(erd), np.asarray(accuracy), 0, 1.0, None, chosen, held
        )

    found = [
        result("reacher-2-emgail-auto", [0.9, 1.0], [0.1, 0.2], [2, 3], [4, 3]),
        result("reacher-2-emgail", [0.95, 0.95], [0.1, 0.1]),
        result("hopper-3-emgail-auto", [1.0, 1.0], [0.0, 0.0], [3, 3]),
    ]
    sweep.write_choosing_k(str(tmp_path), sweep.Results({r.cell: r for r in found}))
    table = (tmp_path / "choosing-k.md").read_text()
    row = (
        "| reacher, 2 of 4 | 2, 3 | 4, 3 | 95.0 ± 5.0 | 95.0 ± 0.0 | 0.150 ± 0.050 | 0.100 ± 0.000"
    )
    assert row + " |" in table
    assert "| hopper, 3 of 3 | 3, 3 | — | 100.0 ± 0.0 | — |" in table
    rows = list(csv.DictReader((tmp_path / "choosing-k.csv").open()))
    assert [(r["env"], r["intentions"], r["chosen"], r["held"]) for r in rows] == [
        ("hopper", "3", "3 3", "—"),
        ("reacher", "2", "2 3", "4 3"),
    ]
    assert rows[1]["given_accuracy_mean"] == "0.9500" and rows[0]["given_erd_mean"] == "nan"


def test_sweep_cells_are_records_whose_names_follow_from_their_fields():
    """A cell is its env, K, algorithm, radius and variant: its name (and run directory) and
    its data's name are made from these, and the groups it feeds do not make it another."""
    sweep = _load("sweep")
    Cell, Variant = sweep.Cell, sweep.Variant
    assert Cell("hopper", 3, "emgail", variant=Variant.PAIR).name == "hopper-3-emgail-pair"
    assert Cell("driver", 2, "gail", radius=7.0).name == "driver-r7-gail"
    assert Cell("driver", 2, "gail", radius=7.0).data.name == "driver-r7"
    assert Cell("reacher", 4, "emgail", variant=Variant.AUTO).data == sweep.DemoSet("reacher", 4)
    assert Cell("swimmer", 2, "emgail", ("table3",)) == Cell("swimmer", 2, "emgail")
    assert Cell("swimmer", 2, "emgail") != Cell("swimmer", 2, "emgail", variant=Variant.ONEHOT)
    for cell in sweep.all_cells():  # every field of the record is the one its name says
        env, where, algo, *variant = cell.name.split("-")
        assert (cell.env, cell.algo, cell.variant) == (env, algo, Variant("".join(variant)))
        expected = f"r{cell.radius:g}" if cell.radius is not None else str(cell.intentions)
        assert where == expected
    onehot = Cell("hopper", 2, "emgail", variant=Variant.ONEHOT).run_args()
    assert onehot[-2:] == ["--intention-input", "onehot"]


def test_sweep_results_are_selected_by_the_cells_fields():
    """Results.get finds the one cell of the fields asked (the default variant, no radius,
    unless asked), Results.where every cell a predicate keeps, in the sweep's order."""
    sweep = _load("sweep")
    Variant = sweep.Variant
    cells = sweep.all_cells()

    def result(cell, erd):
        return sweep.CellResult(cell, np.asarray([erd]), None, 0, 1.0, None)

    results = sweep.Results({cell: result(cell, i) for i, cell in enumerate(cells)})
    by_name = {cell.name: i for i, cell in enumerate(cells)}

    def erd_of(found):
        return None if found is None else int(found.erd[0])

    assert erd_of(results.get("hopper", 2, "emgail")) == by_name["hopper-2-emgail"]
    pair = results.get("hopper", 2, "emgail", variant=Variant.PAIR)
    assert erd_of(pair) == by_name["hopper-2-emgail-pair"]
    assert erd_of(results.get("driver", 2, "gail", radius=4.0)) == by_name["driver-r4-gail"]
    assert erd_of(results.get("driver", 2, "emgail")) == by_name["driver-2-emgail"]
    assert results.get("driver", 2, "gail") is None  # the driver's K-given cells are EM-GAIL's
    assert results.get("walker", 2, "gail") is None
    driver = results.where(sweep.on_driver_radius)
    assert [r.cell.name for r in driver] == [
        f"driver-r{radius:g}-{algo}" for radius in sweep.DRIVER_RADII for algo in sweep.ALGOS
    ]
    robotics = results.where(sweep.robotics_default)
    assert {r.cell.env for r in robotics} == set(sweep.ROBOTICS_INTENTIONS)
    assert all(r.cell.variant == Variant.DEFAULT for r in robotics)
    assert len(robotics) == 4 + 3 * 8  # K = 1, and 3 algorithms at each of the 8 K
    assert len(results.where(sweep.robotics_many)) == 3 * 8
    partial = sweep.Results({c: r for c, r in results.by_cell.items() if c.algo != "gail"})
    assert partial.get("hopper", 2, "gail") is None


def test_sweep_table3_takes_each_column_from_its_cells(tmp_path):
    """Table 3's csv rows name the env and K of the data the cell trained on, the GMM's row
    comes from the separability table, and a cell that has not finished is a dash."""
    sweep = _load("sweep")
    Cell, Variant = sweep.Cell, sweep.Variant
    found = [
        sweep.CellResult(Cell("hopper", 3, "emgail"), np.zeros(2), np.asarray([0.9, 0.8]), 0,
                         1.0, None),
        sweep.CellResult(Cell("reacher", 2, "emgail", variant=Variant.PAIR), np.zeros(1),
                         np.asarray([0.5]), 0, 1.0, None),
    ]  # fmt: skip
    separability = sweep.SeparabilityTable(
        {"hopper-3": {"gmm_accuracy": 0.7, "gmm_accuracy_std": 0.1}}
    )
    sweep.write_table3(str(tmp_path), sweep.Results({r.cell: r for r in found}), separability)
    rows = [line.split(",") for line in (tmp_path / "table3.csv").read_text().splitlines()]
    assert rows[1:] == [
        ["hopper", "3", "gmm", "0.7000", "0.1000", "5"],
        ["hopper", "3", "emgail", "0.8500", "0.0500", "2"],
        ["reacher", "2", "emgail-pair", "0.5000", "0.0000", "1"],
    ]
    table = (tmp_path / "table3.md").read_text().splitlines()
    pair = next(line for line in table if line.startswith("| EM-GAIL (per-pair E-step) |"))
    columns = [c.strip() for c in pair.split("|")[2:-1]]
    names = [data.name for data in sweep.robotics_sets()]
    assert columns[names.index("reacher-2")] == "50.0 ± 0.0"
    assert columns[names.index("hopper-3")] == "—"


def test_sweep_table2_says_on_how_many_cores_each_cell_ran(tmp_path):
    sweep = _load("sweep")
    one = sweep.CellResult(
        sweep.Cell("hopper", 2, "emgail"), np.zeros(4), None, 35_983, 1.6, None, devices=1
    )
    sweep.write_table2(str(tmp_path), sweep.Results({one.cell: one}), seeds=4)
    rows = (tmp_path / "table2.md").read_text().splitlines()
    assert "| hopper | EM-GAIL | 35,983 | 21.2K | 1.60 (1) | 0.40 | 15.6 |" in rows
    assert "| hopper | GAIL | — | 15.3K | — | — | 12.4 |" in rows


def test_sweep_draws_the_figures_whose_cells_have_finished(tmp_path):
    """Each figure takes its cells by field: swimmer's default cells alone draw Figure 6, and
    with the separability of their data Figures 4a and 5b; the driver's none."""
    sweep = _load("sweep")
    Cell = sweep.Cell
    found = [
        sweep.CellResult(Cell("swimmer", k, algo), np.asarray([0.2, 0.4]), None, 0, 1.0, None)
        for k in (1, 2)
        for algo in sweep.ALGOS
        if k > 1 or algo == "gail"
    ]
    results = sweep.Results({r.cell: r for r in found})
    empty = sweep.SeparabilityTable({})
    assert sweep.draw_figures(str(tmp_path), results, empty) == ["fig6.png"]
    row = {"separability": 0.5, "separability_std": 0.1}
    known = sweep.SeparabilityTable({"swimmer-2": row})
    written = sweep.draw_figures(str(tmp_path), results, known)
    assert written == ["fig4a.png", "fig5b.png", "fig6.png"]
    assert sorted(p.name for p in tmp_path.iterdir()) == written


# A finished cell's reward check as reoptimize writes it now (every seed, the baseline), and as
# it wrote it when the check took seed 0 alone.
CHECK_OF_EVERY_SEED = {
    "iteration": 4,
    "budget": {"iterations": 4, "gamma": 0.995},
    "seeds": [0, 1],
    "erd": [0.5, 0.7],
    "erd_mean": 0.6,
    "erd_std": 0.1,
    "baseline": {"erd": 0.03, "cache": "hopper-k2-4it-g0.995-0123456789ab.json"},
    "compile_time_s": 5.0,
    "train_time_s": 16.0,
}
CHECK_OF_SEED_0 = {"run_seed": 0, "iterations": 4, "erd": 0.49, "compile_time_s": 3.0,
                   "train_time_s": 6.0}  # fmt: skip
REFIT_OF_EVERY_SEED = {**CHECK_OF_EVERY_SEED, "erd": [0.1, 0.2], "baseline": {"erd": 0.02}}


def finished_cell(out, cell, erd, check=None, refit=None):
    """``out/runs/<cell>`` as a finished 4-iteration run leaves it: its ``summary.json`` (ERD
    ``erd`` per seed, 1 s per seed-iteration-intention, 10 s to compile), ``check`` as
    ``reoptimize.json`` and ``refit`` as ``reoptimize-refit.json``."""
    from emgail_jax.host.final_results import FinalResults

    k, seeds = cell.intentions, len(erd)
    final = FinalResults(
        erd=erd, erd_per_intention=[[e] * k for e in erd], cluster_accuracy=None,
        expert_returns=[1.0] * k, returns=[[0.0] * k] * seeds, random_returns=[0.0] * k,
        compile_time_s=10.0, train_time_s=4.0 * seeds * k, iteration_time_s=1.0, env_steps=1,
    )  # fmt: skip
    summary = {
        "env": cell.env, "intentions": k, "seeds": seeds, "status": "completed",
        "iterations_done": 4, "parameters": {"total": 1}, "final": final.to_summary(),
        "timings": {"compile_time_s": 10.0, "train_time_s": 4.0 * seeds * k, "iterations": 4},
        "config": {"iterations": 4, "gamma": 0.995, "gae_lambda": 0.97},
    }  # fmt: skip
    run_dir = out / "runs" / cell.name
    run_dir.mkdir(parents=True)
    (run_dir / "summary.json").write_text(json.dumps(summary))
    if check is not None:
        (run_dir / "reoptimize.json").write_text(json.dumps(check))
    if refit is not None:
        (run_dir / "reoptimize-refit.json").write_text(json.dumps(refit))
    return run_dir


@pytest.fixture
def hopper_cells(tmp_path):
    """The sweep's finished hopper cells, their reward checks of either form or none; its
    results and OUT."""
    sweep = _load("sweep")
    Cell = sweep.Cell
    out = tmp_path / "results"
    finished_cell(out, Cell("hopper", 1, "gail"), [0.01, 0.01])
    finished_cell(
        out, Cell("hopper", 2, "emgail"), [0.01, 0.01], CHECK_OF_EVERY_SEED, REFIT_OF_EVERY_SEED
    )
    finished_cell(out, Cell("hopper", 2, "infogail"), [0.02, 0.04])  # its checks are to do
    gail_check = {**CHECK_OF_EVERY_SEED, "erd": [0.9, 1.1], "erd_mean": 1.0}
    finished_cell(out, Cell("hopper", 2, "gail"), [0.5, 0.6], gail_check)  # its refit's to do
    finished_cell(out, Cell("hopper", 3, "emgail"), [0.03, 0.05], CHECK_OF_SEED_0)
    finished_cell(out, Cell("hopper", 3, "gail"), [0.4, 0.4])
    return sweep, sweep.collect(str(out), sweep.all_cells(), 2, 4), out


def test_sweep_fig6_csv_sets_the_reward_check_beside_the_joint_erd(hopper_cells):
    """fig6.csv keeps its columns and appends the reward check's: the mean and std of the
    re-optimised ERD over the seeds checked, the true-reward baseline and how many seeds; a
    check of seed 0 alone has no std and no baseline; a cell without a check, empty columns;
    then the refit's check: its mean, std and baseline."""
    sweep, results, out = hopper_cells
    sweep.write_erd_csvs(str(out), results, sweep.SeparabilityTable({}))
    lines = (out / "fig6.csv").read_text().splitlines()
    assert lines[0] == (
        "env,intentions,algo,separability,erd_mean,erd_std,reoptimized_erd,seeds,"
        "reoptimized_erd_std,true_reward_erd,reoptimized_seeds,"
        "refit_erd,refit_erd_std,refit_true_reward_erd"
    )
    assert lines[1:] == [
        "hopper,1,gail,,0.0100,0.0000,,2,,,,,,",
        "hopper,2,emgail,,0.0100,0.0000,0.6000,2,0.1000,0.0300,2,0.1500,0.0500,0.0200",
        "hopper,2,infogail,,0.0300,0.0100,,2,,,,,,",
        "hopper,2,gail,,0.5500,0.0500,1.0000,2,0.1000,0.0300,2,,,",
        "hopper,3,emgail,,0.0400,0.0100,0.4900,2,,,1,,,",
        "hopper,3,gail,,0.4000,0.0000,,2,,,,,,",
    ]
    rows = list(csv.DictReader((out / "fig6.csv").open()))  # as readers of the columns see it
    assert [r["reoptimized_erd"] for r in rows if r["algo"] == "emgail"] == ["0.6000", "0.4900"]
    assert [r["refit_erd"] for r in rows if r["algo"] == "emgail"] == ["0.1500", ""]


def keep_checkpoints(monkeypatch, iteration=4):
    """The finished cells' run directories as if they kept their final checkpoints."""
    from emgail_jax.host import checkpoints

    monkeypatch.setattr(checkpoints, "latest_iteration", lambda run_dir: iteration)


def test_sweep_a_cell_is_checked_until_every_seed_and_the_baseline_are(hopper_cells, monkeypatch):
    """A trained cell whose checks are missing, or the paper's took seed 0 alone, or the refit's
    is missing, has its checks to do (and only those); one the sweep does not check, or whose
    checks are complete, is done."""
    sweep, _, out = hopper_cells
    keep_checkpoints(monkeypatch)
    status = {
        name: sweep.sweep_status(cell, str(out / "runs" / name), 2, 4)
        for name, cell in ((c.name, c) for c in sweep.select(sweep.all_cells(), "hopper"))
        if (out / "runs" / name).exists()
    }
    assert status == {
        "hopper-1-gail": "done",
        "hopper-2-emgail": "done",
        "hopper-2-infogail": "reward check",
        "hopper-2-gail": "reward check",
        "hopper-3-emgail": "reward check",
        "hopper-3-gail": "done",
    }
    resumed = json.loads((out / "runs" / "hopper-2-emgail" / "summary.json").read_text())
    (out / "runs" / "hopper-2-emgail" / "summary.json").write_text(
        json.dumps({**resumed, "iterations_done": 6})
    )  # trained further than its check: checked again
    assert not sweep.reward_check_done(str(out / "runs" / "hopper-2-emgail"), 2)
    gail = str(out / "runs" / "hopper-2-gail")
    assert sweep.checks_to_do(gail, 2) == [sweep.REFIT_CHECK]
    # A check written before lambda was in the budget trained at the run's: done; one at a
    # budget the env no longer has (its lambda changed since): to do again.
    assert sweep.reward_check_done(gail, 2)
    monkeypatch.setitem(sweep.BUDGETS, "hopper", {"gae_lambda": 0.995})
    assert not sweep.reward_check_done(gail, 2)
    check = json.loads((out / "runs" / "hopper-2-gail" / "reoptimize.json").read_text())
    check["budget"]["gae_lambda"] = 0.995
    (out / "runs" / "hopper-2-gail" / "reoptimize.json").write_text(json.dumps(check))
    assert sweep.reward_check_done(gail, 2)
    # Likewise scaling: a check recorded without it trained unscaled, as the run's config.
    monkeypatch.setitem(
        sweep.BUDGETS, "hopper", {"gae_lambda": 0.995, "value_target_scaling": True}
    )
    assert not sweep.reward_check_done(gail, 2)
    check["budget"]["value_target_scaling"] = True
    (out / "runs" / "hopper-2-gail" / "reoptimize.json").write_text(json.dumps(check))
    assert sweep.reward_check_done(gail, 2)


def test_sweep_halfcheetahs_refit_check_scales_the_value_targets_and_no_other_check_does():
    sweep = _load("sweep")
    config = {"iterations": 400, "gamma": 0.995, "gae_lambda": 0.97}
    budget = lambda env, check: sweep.check_budget(env, config, check)
    refit = budget("halfcheetah", sweep.REFIT_CHECK)
    assert refit.value_target_scaling and refit.iterations == 1000
    assert not budget("halfcheetah", sweep.PAPER_CHECK).value_target_scaling
    assert not budget("hopper", sweep.REFIT_CHECK).value_target_scaling


def test_sweep_reward_check_command_is_every_seed_beside_the_cached_baseline(
    hopper_cells, monkeypatch
):
    """A trained cell whose checks are to do runs reoptimize on every seed (no --seed), with the
    baseline (no --no-baseline) cached under OUT, where every cell of the env and K finds it:
    once on the run's reward into reoptimize.json, once with --refit, best of 3 draws, into
    reoptimize-refit.json."""
    from emgail_jax import reoptimize

    sweep, _, out = hopper_cells
    keep_checkpoints(monkeypatch)
    ran = []
    monkeypatch.setattr(sweep, "run_command", lambda command, log: ran.append(command) or 0)
    cell = sweep.Cell("hopper", 2, "infogail")
    sweep.train_cell(cell, str(out), 2, 4)
    command, refit_command = ran  # trained already: the checks alone
    assert command[:3] == [sys.executable, "-m", "emgail_jax.reoptimize"]
    args = reoptimize.parse_args(command[3:])
    assert args.run_dir == str(out / "runs" / "hopper-2-infogail")
    assert args.seed is None and args.baseline and args.snapshot is None
    assert args.cache == str(out / "true-reward-baselines")
    assert (args.iterations, args.gamma, args.env_set) == (None, None, [])  # the env's budget
    assert not args.refit and args.draws == 1 and args.out is None  # reoptimize.json
    refit = reoptimize.parse_args(refit_command[3:], env="hopper")
    assert refit.refit and refit.draws == 3 and refit.consolidate_ranking == 10
    assert refit.out == str(out / "runs" / "hopper-2-infogail" / "reoptimize-refit.json")
    assert (refit.seed, refit.baseline, refit.cache) == (None, True, args.cache)
    ran.clear()
    sweep.train_cell(sweep.Cell("hopper", 2, "gail"), str(out), 2, 4)
    (gail_refit,) = ran  # its paper's check is done: the refit's alone
    gail_dir = out / "runs" / "hopper-2-gail"
    assert gail_refit[3] == str(gail_dir) and "--refit" in gail_refit
    assert gail_refit[-1] == str(gail_dir / "reoptimize-refit.json")
    ran.clear()
    sweep.train_cell(sweep.Cell("hopper", 2, "emgail"), str(out), 2, 4)
    assert ran == []  # its check is complete


def test_sweep_a_check_over_two_processes_is_one_per_seed_then_merged(hopper_cells, monkeypatch):
    """With two check processes each seed is checked in its own (the last seed's with the
    baseline), then merged into the check's file, and the parts go; a part already made of
    these networks at this budget is kept, and the merge runs again on it."""
    from emgail_jax import reoptimize

    sweep, _, out = hopper_cells
    keep_checkpoints(monkeypatch)
    parallel, ran = [], []

    def run_commands(commands, log, processes):
        for command in commands:  # each writes its part
            part = command[command.index("--out") + 1]
            os.makedirs(os.path.dirname(part), exist_ok=True)
            seed = int(command[command.index("--seed") + 1])
            budget = {"iterations": 4, "gamma": 0.995, "gae_lambda": 0.97}
            budget["value_target_scaling"] = False
            with open(part, "w") as f:
                json.dump({"iteration": 4, "budget": budget, "seeds": [seed]}, f)
        parallel.append((commands, processes))
        return 0

    monkeypatch.setattr(sweep, "run_commands", run_commands)
    monkeypatch.setattr(sweep, "run_command", lambda command, log: ran.append(command) or 0)
    sweep.train_cell(sweep.Cell("hopper", 2, "gail"), str(out), 2, 4, check_processes=2)
    run_dir = out / "runs" / "hopper-2-gail"
    ((parts, processes),) = parallel  # its paper's check is done: the refit's alone
    assert processes == 2 and len(parts) == 2
    args = [reoptimize.parse_args(command[3:], env="hopper") for command in parts]
    assert [(a.seed, a.baseline, a.refit, a.draws) for a in args] == [
        (0, False, True, 3),
        (1, True, True, 3),
    ]
    parts_dir = run_dir / "reoptimize-refit.parts"
    assert [a.out for a in args] == [str(parts_dir / f"seed-{s}.json") for s in (0, 1)]
    (merge,) = ran
    merged = reoptimize.parse_args(merge[3:], env="hopper")
    assert merged.merge == [a.out for a in args] and merged.seed is None
    assert merged.out == str(run_dir / "reoptimize-refit.json") and merged.baseline
    assert not parts_dir.exists()  # merged: the parts go
    # A merge that fails keeps the parts; the next sweep reuses them and merges again.
    parallel.clear()
    monkeypatch.setattr(sweep, "run_command", lambda command, log: 2)
    code = sweep.run_reward_check(str(run_dir), str(out), sweep.REFIT_CHECK, "log", 2)
    assert code == 2 and sorted(p.name for p in parts_dir.iterdir()) == [
        "seed-0.json",
        "seed-1.json",
    ]
    assert sweep.run_reward_check(str(run_dir), str(out), sweep.REFIT_CHECK, "log", 2) == 2
    assert parallel[-1][0] == []  # both parts kept


def test_sweep_check_processes_run_at_once_each_on_a_core_and_a_failure_stops_them(tmp_path):
    """Two children that each wait for the other finish only if they run at once; with more
    cores than one each is pinned to its own. A child that fails stops the one still running
    (it would wait for a minute) and its exit code is returned."""
    sweep = _load("sweep")
    wait_for = (
        "import os, sys, time; d = sys.argv[1]; open(os.path.join(d, sys.argv[2]), 'w').close()\n"
        "print('cores', sorted(os.sched_getaffinity(0)), flush=True)\n"
        "for _ in range(600):\n"
        "    if os.path.exists(os.path.join(d, sys.argv[3])): sys.exit(0)\n"
        "    time.sleep(0.05)\n"
        "sys.exit(3)"
    )
    commands = [[sys.executable, "-c", wait_for, str(tmp_path), a, b] for a, b in ("ab", "ba")]
    log = tmp_path / "log"
    assert sweep.run_commands(commands, str(log), 2) == 0
    pinned = [line for line in log.read_text().splitlines() if line.startswith("cores")]
    if len(os.sched_getaffinity(0)) > 1:
        assert len(pinned) == 2 and len(set(pinned)) == 2 and all("," not in p for p in pinned)
    fails = [[sys.executable, "-c", "import sys; sys.exit(5)"]]
    long = [[sys.executable, "-c", "import time; time.sleep(60)"]]
    assert sweep.run_commands([*long, *fails, *long], str(log), 2) == 5


def test_sweep_a_cell_without_its_networks_is_trained_again_then_checked(hopper_cells, monkeypatch):
    """A trained cell whose check is to do but whose checkpoints are not kept (results/ keeps
    none) cannot be checked as it is: it is trained again over its directory, then checked
    (every check: those it had scored the networks replaced), and its estimate counts both."""
    from emgail_jax.host import checkpoints
    from emgail_jax.host.run_directory import prepare_output

    sweep, _, out = hopper_cells
    monkeypatch.setattr(checkpoints, "latest_iteration", lambda run_dir: None)
    cell, run_dir = sweep.Cell("hopper", 2, "gail"), out / "runs" / "hopper-2-gail"
    assert sweep.sweep_status(cell, str(run_dir), 2, 4) == sweep.Status.RETRAIN
    assert sweep.checks_to_do(str(run_dir), 2) == [sweep.REFIT_CHECK]  # the paper's is done
    complete = sweep.Cell("hopper", 2, "emgail")
    assert sweep.sweep_status(complete, str(out / "runs" / complete.name), 2, 4) == "done"
    timings = sweep.measured_seconds(str(out / "runs"))
    retrain = sweep.estimate_seconds(cell, sweep.Status.RETRAIN, 2, 4, timings)
    assert retrain == sweep.estimate_seconds(cell, sweep.Status.NEW, 2, 4, timings)
    ran = []

    def run_command(command, log):
        if "--overwrite" in command:  # what the run starts with
            prepare_output(command[command.index("--out") + 1], overwrite=True)
        return ran.append(command) or 0

    monkeypatch.setattr(sweep, "run_command", run_command)
    monkeypatch.setattr(sweep, "write_demonstrations", lambda cell, out: None)
    sweep.train_cell(cell, str(out), 2, 4)
    # The run's --overwrite removed the paper's check of the networks it replaced: both run.
    training, check, refit = ran
    assert training[:3] == [sys.executable, "-m", "emgail_jax.run"]
    assert training[training.index("--out") + 1] == str(run_dir) and "--overwrite" in training
    assert training[training.index("--snapshot-every") + 1] == "10"  # what the refit learns from
    assert check[:3] == refit[:3] == [sys.executable, "-m", "emgail_jax.reoptimize"]


def test_sweep_estimates_every_seeds_check_and_each_baseline_once(hopper_cells):
    """A check costs every seed's fresh policies at the env's budget, and the true-reward
    baseline's K policies in the first cell of an env and K that finds none cached; the
    seconds per unit come from the finished cells and checks."""
    sweep, _, out = hopper_cells
    Cell, Status = sweep.Cell, sweep.Status
    timings = sweep.measured_seconds(str(out / "runs"))
    assert timings.training == {"hopper": (1.0, 10.0)}
    # The medians of the checks' 16 s over 2 seeds x 4 iterations x 2 intentions (twice) and,
    # seed 0 alone, 6 s over 4 x 3; and of their compiles, 5, 5 and 3 s.
    assert timings.checks == {"hopper": (1.0, 5.0)}
    infogail, swimmer = Cell("hopper", 2, "infogail"), Cell("swimmer", 2, "emgail")
    # (2 seeds + the baseline) x 4 iterations x 2 intentions at 1 s, and two compiles; the
    # refit's check 3 draws of the same after 2 seeds' refits.
    check = 2 * 5.0 + 3 * 4 * 2
    refit = 2 * sweep.REFIT_SECONDS_PER_SEED + 3 * check
    paper_only = (sweep.PAPER_CHECK,)
    both = sweep.REWARD_CHECKS
    assert sweep.estimate_seconds(infogail, Status.CHECK, 2, 4, timings, both, paper_only) == check
    assert sweep.estimate_seconds(infogail, Status.CHECK, 2, 4, timings) == check + refit
    without_baseline = sweep.estimate_seconds(infogail, Status.CHECK, 2, 4, timings, ())
    assert without_baseline == 5.0 + 2 * 4 * 2 + 2 * sweep.REFIT_SECONDS_PER_SEED + 3 * (
        5.0 + 2 * 4 * 2
    )
    trained = 10.0 + 1.0 * 2 * 4 * 2
    assert sweep.estimate_seconds(infogail, Status.NEW, 2, 4, timings) == trained + check + refit
    # Over two processes a seed each, the baseline's beside the last: a seed and the baseline.
    check_2 = 2 * 5.0 + 2 * 4 * 2
    refit_2 = sweep.REFIT_SECONDS_PER_SEED + 3 * check_2
    over_two = sweep.estimate_seconds(infogail, Status.CHECK, 2, 4, timings, check_processes=2)
    assert over_two == check_2 + refit_2
    # A check stopped part-way costs what it has left: its finished draw and half the next.
    run_dir = out / "runs" / infogail.name
    finished = FinishedDraws(str(run_dir / sweep.REFIT_CHECK.file), {})
    finished.write(0, {"erd": [0.5, 0.5]})
    finished.partial(1).write(2, {"w": np.zeros(3)}, np.zeros((2, 1)), np.zeros((2, 1)), 1.0)
    done = sweep.checks_draws_done(infogail, str(run_dir), 4)
    assert done == {sweep.PAPER_CHECK: 0.0, sweep.REFIT_CHECK: 1.5}
    # Spread over processes, its seeds' parts: seed 0's written (3 draws), seed 1's one draw.
    parts = [sweep.check_part_path(str(run_dir), sweep.REFIT_CHECK, seed) for seed in (0, 1)]
    os.makedirs(os.path.dirname(parts[0]))
    pathlib.Path(parts[0]).write_text("{}")
    FinishedDraws(parts[1], {}).write(0, {"erd": [0.5]})
    assert sweep.checks_draws_done(infogail, str(run_dir), 4)[sweep.REFIT_CHECK] == 2.0
    shutil.rmtree(os.path.dirname(parts[0]))  # gone: the whole check's draws count again
    assert sweep.estimate_seconds(
        infogail, Status.CHECK, 2, 4, timings, draws_done=done
    ) == pytest.approx(check + refit / 2)
    per_unit, compile_s = sweep.MEASURED_SECONDS["swimmer"]  # no swimmer cell finished
    check = 2 * compile_s + per_unit * 3 * 1500 * 2  # the swimmer's experts' budget
    estimate = sweep.estimate_seconds(swimmer, Status.CHECK, 2, 4, timings, both, paper_only)
    assert estimate == pytest.approx(check)
    # Halfcheetah's refit check trains its fresh agents 1000 iterations, as its recipe says.
    cheetah = Cell("halfcheetah", 2, "emgail")
    assert sweep.check_iterations("halfcheetah", 4, sweep.PAPER_CHECK) == 4
    assert sweep.check_iterations("halfcheetah", 4, sweep.REFIT_CHECK) == 1000
    per_unit, compile_s = sweep.MEASURED_SECONDS["halfcheetah"]
    refit_check = sweep.estimate_seconds(
        cheetah, Status.CHECK, 2, 4, timings, (), (sweep.REFIT_CHECK,)
    )
    assert refit_check == pytest.approx(
        2 * sweep.REFIT_SECONDS_PER_SEED + 3 * (compile_s + per_unit * 2 * 1000 * 2)
    )
    # One baseline per env, K and budget: the paper's check computes it where the refit's
    # check has the same budget, each its own where not.
    paper, refit = sweep.PAPER_CHECK, sweep.REFIT_CHECK
    hopper = [Cell("hopper", 2, "infogail"), Cell("hopper", 2, "gail"), Cell("hopper", 3, "emgail")]
    assert sweep.baseline_computers(hopper, str(out), 4) == {(hopper[0], paper), (hopper[2], paper)}
    cache = out / "true-reward-baselines"
    cache.mkdir()
    (cache / CHECK_OF_EVERY_SEED["baseline"]["cache"]).write_text("{}")
    assert sweep.baseline_computers(hopper, str(out), 4) == {(hopper[2], paper)}
    assert sweep.baseline_computers([cheetah], str(out), 4) == {(cheetah, paper), (cheetah, refit)}


def test_sweep_fig6_draws_the_reward_checks_dashed_and_the_baseline_dotted(
    hopper_cells, monkeypatch
):
    sweep, results, out = hopper_cells
    drawn = {}

    def keep(fig, out, name):
        drawn[name] = fig
        return name

    monkeypatch.setattr(sweep, "_save", keep)
    assert sweep.draw_fig6(str(out), results) == "fig6.png"
    axes = drawn["fig6.png"].axes
    hopper = axes[list(sweep.ROBOTICS_INTENTIONS).index("hopper")]
    styled = lambda style: [
        (line.get_color(), line.get_xydata().tolist())
        for line in hopper.lines
        if line.get_linestyle() == style
    ]
    # The mean over the seeds checked, per algorithm; seed 0 alone where that is all there is.
    assert styled("--") == [("tab:red", [[2, 0.6], [3, 0.49]]), ("tab:green", [[2, 1.0]])]
    assert styled(":") == [("black", [[2, 0.03]])]
    assert styled("-.") == [("tab:red", [[2, pytest.approx(0.15)]])]  # the refit's check
    legend = [text.get_text() for text in axes[-1].get_legend().get_texts()]
    assert legend == [
        "EM-GAIL", "Info/IntentionGAIL", "GAIL", "jointly trained policies",
        "fresh TRPO on the learned reward (§5.2)",
        "the same on the refitted reward, best of 3 (reoptimize --refit)",
        "fresh TRPO on the true reward",
    ]  # fmt: skip


def test_sweep_cell_status_reads_the_run_directory(tmp_path):
    sweep = _load("sweep")

    def summary(**fields):
        (tmp_path / "summary.json").write_text(json.dumps(fields))

    assert sweep.cell_status(str(tmp_path), 4, 400) == "new"
    summary(seeds=4, status="completed", iterations_done=400)
    assert sweep.cell_status(str(tmp_path), 4, 400) == "done"
    summary(seeds=4, status="interrupted", iterations_done=150)
    assert sweep.cell_status(str(tmp_path), 4, 400) == "new"  # no checkpoint to resume from
    (tmp_path / "checkpoints").mkdir()
    assert sweep.cell_status(str(tmp_path), 4, 400) == "new"  # nor in an empty directory
    checkpoints.save(str(tmp_path), 150, {"w": np.zeros(2)}, {"erd": np.zeros((2, 150))})
    assert sweep.cell_status(str(tmp_path), 4, 400) == "resume"
    # A killed run (no signal handler ran) left "running" and no iterations: resumed all the same.
    summary(seeds=4, status="running")
    assert sweep.cell_status(str(tmp_path), 4, 400) == "resume"
    summary(seeds=4, status="completed", iterations_done=400)
    assert sweep.cell_status(str(tmp_path), 4, 600) == "resume"  # a longer sweep continues it
    with pytest.raises(sweep.SweepError, match="run with 4 seeds, not 2"):
        sweep.cell_status(str(tmp_path), 2, 400)


def test_sweep_runs_skips_and_reports_driver_cells(tmp_path, capsys):
    """End to end on two tiny driver cells (the sizes of the other tiny driver runs): trained in
    this process, the second radius on the first one's compiled programs, reported, then
    skipped."""
    from emgail_jax.host.program_cache import SHARED

    sweep = _load("sweep")
    SHARED.clear()
    out = tmp_path / "results"
    args = [
        *("--only", "driver-r4-emgail,driver-r20-emgail", "--seeds", "2", "--iterations", "4"),
        *("--set", "num_envs=2", "--set", "rollout_length=20", "--set", "chunk_size=2"),
        *("--out", str(out)),
    ]
    assert sweep.main(args) == 0
    assert len(SHARED) == 1  # both radii ran one set of programs
    for name in ("table2.md", "table3.md", "table3.csv", "fig6.csv", "fig4b.png", "fig5a.png"):
        assert (out / name).exists(), name
    rows = {float(row["radius"]): row for row in csv.DictReader((out / "fig5a.csv").open())}
    assert sorted(rows) == [4.0, 20.0]
    assert (rows[4.0]["algo"], rows[4.0]["seeds"]) == ("emgail", "2")
    for radius in (4, 20):
        run_dir = out / "runs" / f"driver-r{radius}-emgail"
        summary = json.loads((run_dir / "summary.json").read_text())
        assert summary["env_options"]["radius"] == radius
        assert summary["config"]["num_envs"] == 2  # --set reached the run
        erd_mean = float(rows[radius]["erd_mean"])
        assert erd_mean == pytest.approx(np.mean(summary["final"]["erd"]), abs=1e-4)
        assert "wrote" in (out / "logs" / f"driver-r{radius}-emgail.log").read_text()

    stamp = (out / "runs" / "driver-r4-emgail" / "summary.json").stat().st_mtime_ns
    capsys.readouterr()
    assert sweep.main(args) == 0
    assert "0 cells to run" in capsys.readouterr().out
    assert (out / "runs" / "driver-r4-emgail" / "summary.json").stat().st_mtime_ns == stamp


def test_sweep_engine_ray_is_refused_without_ray_or_a_cluster(tmp_path, monkeypatch, capsys):
    """Before anything is written: a missing Ray names the extra; an address nothing answers
    at is refused at once (Ray would wait for it forever). The two-node cluster runs are in
    test_sweep_ray.py."""
    sweep = _load("sweep")
    args = ["--only", "driver-r20-gail", "--seeds", "1", "--out", str(tmp_path / "out")]
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` fails as if not installed
    assert sweep.main([*args, "--engine", "ray"]) == 2
    assert capsys.readouterr().err == "error: --engine ray needs Ray: pip install -e '.[ray]'\n"
    monkeypatch.undo()

    pytest.importorskip("ray")
    with socket.socket() as closed:  # bound, never listening: connections are refused
        closed.bind(("127.0.0.1", 0))
        address = f"127.0.0.1:{closed.getsockname()[1]}"
        assert sweep.main([*args, "--engine", "ray", "--ray-address", address]) == 2
    error = capsys.readouterr().err.strip().splitlines()[-1]
    assert error.startswith(f"error: no Ray cluster answers at {address} (")
    assert not (tmp_path / "out").exists()


def test_sweep_check_processes_below_one_are_refused(tmp_path, capsys):
    sweep = _load("sweep")
    out = tmp_path / "out"
    args = ["--only", "driver-r20-gail", "--check-processes", "0", "--out", str(out)]
    assert sweep.main(args) == 2
    assert capsys.readouterr().err == "error: --check-processes must be at least 1\n"
    cpus = ["--only", "driver-r20-gail", "--cpus-per-cell", "0", "--out", str(out)]
    assert sweep.main(cpus) == 2
    assert "--cpus-per-cell must be at least 1" in capsys.readouterr().err
    assert not out.exists()
    given = sweep.parse_args(["--seeds", "4", "--check-processes", "3"])
    assert sweep.local_check_processes(given) == 3
    assert sweep.local_check_processes(sweep.parse_args(["--seeds", "1"])) == 1


def test_sweep_separability_of_the_driver_falls_with_the_radius(tmp_path):
    sweep = _load("sweep")
    cells = sweep.select(sweep.all_cells(), "driver-r4-gail,driver-r20-gail")
    table = sweep.separability_table(str(tmp_path), cells)
    near, far = (sweep.DemoSet("driver", 2, radius) for radius in (4.0, 20.0))
    assert table.of(near)["separability"] < 0.2 < 0.9 < table.of(far)["separability"]
    assert sorted(table.rows) == ["driver-r20", "driver-r4"]
    # Kept in separability.csv and read back rather than recomputed.
    again = sweep.separability_table(str(tmp_path), cells)
    for data in (near, far):
        assert again.of(data) == pytest.approx(table.of(data), abs=1e-4)


@pytest.mark.slow  # its own compile of the RL update: 30-90 s
def test_rl_floor_trains_on_the_true_reward(capsys):
    rl_floor = _load("rl_floor")
    args = ["--env", "driver", "--intentions", "2", "--iterations", "10"]
    assert rl_floor.main([*args, "--set", "num_envs=2", "--set", "hidden=8,"]) == 0
    (line,) = capsys.readouterr().out.splitlines()
    assert line.startswith("iteration 10: returns ") and "ERD" in line and "entropy" in line


def test_unequal_shares_writes_the_asked_episodes(tmp_path, capsys):
    from emgail_jax.host import demonstration_files

    module = _load("unequal_shares")
    out = tmp_path / "driver-41.npz"
    assert module.main(["--env", "driver", "--episodes", "4", "1", "--out", str(out)]) == 0
    assert "shares 0.800, 0.200" in capsys.readouterr().out
    demos = demonstration_files.load(str(out))
    assert np.bincount(demos.intentions).tolist() == [400, 100]
    bare = tmp_path / "bare.npz"
    assert (
        module.main(
            ["--env", "driver", "--episodes", "1", "1", "--out", str(bare), "--drop-labels"]
        )
        == 0
    )
    assert demonstration_files.load(str(bare)).intentions is None
    assert np.load(f"{bare}.labels.npy").tolist() == [0] * 100 + [1] * 100
    assert module.main(["--env", "driver", "--episodes", "9", "1", "--out", str(out)]) == 2
    assert "has 5 episodes, not 9" in capsys.readouterr().err


@pytest.mark.slow  # a supervised classifier trained per step of the reacher's demonstrations
def test_posterior_ceiling_scores_the_demonstrations_by_step(capsys):
    """The supervised posterior on a few fresh reacher episodes: an accuracy for the whole set
    and for each shown step, all of them fractions."""
    module = _load("posterior_ceiling")
    assert module.main(["--env", "reacher", "--intentions", "2", "--episodes", "3"]) == 0
    out = capsys.readouterr().out
    overall = float(out.split("posterior scores ")[1].split()[0])
    assert 0.5 <= overall <= 1.0  # two intentions: better than chance on shipped demos
    per_step = out.split("accuracy by step:")[1].splitlines()[0].split()
    steps, values = per_step[0::2], [float(v) for v in per_step[1::2]]
    assert steps == [f"{s}:" for s in module.STEPS_SHOWN if s < 50]  # reacher: 50 steps
    assert all(0.0 <= v <= 1.0 for v in values)


def test_intention_signals_describe_every_demonstration_of_every_seed(tiny_run, capsys):
    module = _load("intention_signals")
    from emgail_jax.host.saved_run import SavedRun

    run = SavedRun.open(str(tiny_run), snapshot=2)
    found = module.signals(run, seed=1)
    episodes, k = run.demonstration_pairs.episodes, run.num_intentions
    assert found["holder"].shape == found["true"].shape == found["agree"].shape == (episodes,)
    assert found["logit"].shape == found["log_pi"].shape == (episodes, k)
    assert np.all((found["agree"] >= 0) & (found["agree"] <= 1))
    held = np.bincount(found["holder"], minlength=k)
    np.testing.assert_array_equal(held, run.demonstrations_held(1))
    assert module.main([str(tiny_run), "--snapshot", "2"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [line for line in lines if line.startswith("seed")] == [
        "seed 0, iteration 2:",
        "seed 1, iteration 2:",
    ]
    assert module.main([str(tiny_run / "missing")]) == 2
    assert capsys.readouterr().err.startswith("error: ")


def test_posterior_ceiling_of_the_driver_at_a_radius(capsys):
    """The supervised posterior on a few fresh noisy driver episodes at radius 20 (paths far
    apart) labels the generated demonstrations well, with and without the step; the driver's
    options and the other envs' are refused in one line."""
    from emgail_jax.host.problem import make_problem

    module = _load("posterior_ceiling")
    problem = make_problem("driver", 2, env_options={"radius": 20.0})
    env, demos = problem.env, problem.demos
    right = module.supervised_ceiling("driver", env, demos, env.expert_policy, 10, with_step=True)
    assert sorted(right) == ["pair", "pair and step"]
    for seen in right.values():
        assert seen.shape == (1000,) and seen.dtype == bool  # 2 x 5 demonstrations x 100 steps
        assert seen.mean() > 0.9
        assert seen[demos.step_in_episode >= 50].all()  # by mid-episode the paths are apart
    out = capsys.readouterr().out
    assert "2000 fresh expert pairs; on the 1000 demonstration pairs" in out
    tenths = out.split("by tenth of the episode:")[1].splitlines()[0].split()
    assert tenths[0::2] == [f"{a}-{a + 9}:" for a in range(0, 100, 10)]
    refused = {
        ("--env", "reacher", "--radius", "4"): "--radius applies to the driver env only",
        ("--env", "driver", "--radius", "0.1"): "tighter than the car can turn",
        ("--env", "driver", "--episodes", "0"): "--episodes must be at least 1; got 0",
    }
    for argv, message in refused.items():
        assert module.main([*argv, "--intentions", "2"]) == 2
        assert message in capsys.readouterr().err


def test_posterior_ceiling_actions_apart_is_the_mean_over_pairs_of_intentions():
    module = _load("posterior_ceiling")
    still, one, two = np.zeros((3, 2)), np.ones((3, 2)), np.full((3, 2), 2.0)
    np.testing.assert_allclose(module.mean_pairwise_distance([still, one]), np.sqrt(2))
    # pairs (0, 1), (0, 2), (1, 2): sqrt 2, 2 sqrt 2, sqrt 2
    apart = module.mean_pairwise_distance([still, one, two])
    np.testing.assert_allclose(apart, np.full(3, 4 * np.sqrt(2) / 3))


def test_posterior_ceiling_scores_a_driver_runs_own_posterior_by_tenth(tiny_run, capsys):
    """A driver run's posterior, matched by its trajectory labels, by step and by tenth of the
    episode for every seed; in place of the expert's actions (it acts on whole states), each
    intention's mean demonstrated action and how far apart the policies' mean actions are."""
    from emgail_jax.host.problem import make_problem

    module = _load("posterior_ceiling")
    module.compare_run(str(tiny_run), make_problem("driver", 2).demos)
    lines = capsys.readouterr().out.splitlines()
    assert [line.split(":")[0].strip() for line in lines if "run seed" in line] == [
        "run seed 0",
        "run seed 1",
    ]
    tenths = [line.split("by tenth:")[1].split() for line in lines if "by tenth:" in line]
    assert len(tenths) == 2 and all(len(t) == 20 for t in tenths)
    assert all(0.0 <= float(v) <= 1.0 for t in tenths for v in t[1::2])
    demonstrated = [line.split("(mean):")[1].split() for line in lines if "demonstrated" in line]
    assert len(demonstrated) == 2 and all(len(t) == 20 for t in demonstrated)
    apart = [line.split("apart:")[1].split() for line in lines if "mean actions apart" in line]
    assert len(apart) == 2 and all(float(v) >= 0.0 for t in apart for v in t[1::2])
    noise = [float(line.split(":")[1]) for line in lines if "action noise" in line]
    assert len(noise) == 2 and all(0.0 < v < 10.0 for v in noise)
    assert not any("|policy" in line or "experts' actions apart" in line for line in lines)


def test_sweep_a_damaged_cell_is_named_and_continues_from_its_checkpoint(
    tmp_path, tiny_run, capsys
):
    import shutil

    from emgail_jax import run

    sweep = _load("sweep")
    run_dir = tmp_path / "cell"
    shutil.copytree(tiny_run, run_dir)
    intact = (run_dir / "summary.json").read_text()
    (run_dir / "summary.json").write_text(intact[: len(intact) // 2])  # cut short
    assert sweep.cell_status(str(run_dir), 2, 6) == "damaged"
    options = [
        *("--env", "driver", "--seeds", "2", "--iterations", "6", "--num-envs", "2"),
        *("--rollout-length", "20", "--chunk-size", "2"),
    ]
    log = tmp_path / "cell.log"
    assert sweep.repair_cell("cell", str(run_dir), options, str(log)) == "resume"
    message = "cell cell: its summary.json is damaged (kept as"
    assert message in capsys.readouterr().err and message in log.read_text()
    assert (run_dir / "summary.json.damaged").read_text() == intact[: len(intact) // 2]
    assert sweep.cell_status(str(run_dir), 2, 6) == "resume"
    assert run.main(["--resume", str(run_dir), "--quiet"]) == 0
    summary = json.loads((run_dir / "summary.json").read_text())
    assert (summary["status"], summary["iterations_done"]) == ("completed", 6)
    before = (tiny_run / "metrics.csv").read_text()
    assert (run_dir / "metrics.csv").read_text().startswith(before)  # iterations 1-4 kept


def test_sweep_a_damaged_cell_without_a_checkpoint_starts_anew(tmp_path, capsys):
    sweep = _load("sweep")
    (tmp_path / "summary.json").write_text("{not json")
    assert sweep.cell_status(str(tmp_path), 4, 400) == "damaged"
    status = sweep.repair_cell("c", str(tmp_path), [], str(tmp_path / "c.log"))
    assert status == "new" and "starts anew" in capsys.readouterr().err
    assert (tmp_path / "summary.json.damaged").read_text() == "{not json"


@pytest.mark.slow  # a fresh agent's TRPO compiled and trained (the run's 4 iterations)
def test_fresh_agent_drive_traces_each_learned_intentions_episode(tiny_run, capsys):
    module = _load("fresh_agent_drive")
    assert module.main([str(tiny_run), "--seed", "1", "--every", "50"]) == 0
    out = capsys.readouterr().out
    for intention in (0, 1):
        assert f"learned intention {intention}: true returns [" in out
    # the driver's episodes are 100 steps: its x, y at steps 1 and 51 of each
    assert out.count("  step 1: x ") == 2 and out.count("  step 51: x ") == 2
    assert out.count("  observation dimensions at the clip ±5: ") == 2
    assert out.count("  learned reward per step: own actions ") == 2


def test_reward_generalisation_scores_every_seed_and_true_intention(tiny_run, capsys):
    module = _load("reward_generalisation")
    assert module.main([str(tiny_run), "--episodes", "2"]) == 0
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("seed ")]
    assert len(lines) == 4  # 2 seeds x 2 true intentions
    for line in lines:
        values = [float(v) for v in line.split(": ")[1].split(" / ")]
        # The driver has its experts; a tiny run's intention may hold no demonstration (nan).
        assert len(values) == 5 and all(np.isfinite(values[1:]))


def test_reward_generalisation_scores_the_runs_snapshots_along_training(tiny_run, capsys):
    module = _load("reward_generalisation")
    assert module.main([str(tiny_run), "--episodes", "2", "--along-training", "2"]) == 0
    out = capsys.readouterr().out
    rows = [line.split() for line in out.splitlines() if line.startswith("  ")]
    assert [int(r[0]) for r in rows] == [2, 4, 2, 4]  # the snapshots, per seed
    for row in rows:
        earned = [float(v) for v in row[1::3]]
        assert len(earned) == 2 and all(np.isfinite(earned))
    assert out.count("rank correlation") == 4  # 2 seeds x 2 true intentions
    # Opened at a snapshot: its own policies and reward, and no later snapshot's.
    assert (
        module.main([str(tiny_run), "--episodes", "2", "--along-training", "2", "--snapshot", "2"])
        == 0
    )
    rows = [line.split() for line in capsys.readouterr().out.splitlines() if line.startswith("  ")]
    assert [int(r[0]) for r in rows] == [2, 2]

    import jax

    from emgail_jax.host.saved_run import SavedRun

    run = SavedRun.open(str(tiny_run))
    found = module.along_training(run, 1, run.reward_parameters(1), 4, 2, jax.random.PRNGKey(0))
    logged = np.asarray(run.history["eval/returns"][1])
    last = max(i for i in range(4) if np.isfinite(logged[i]).all())
    assert [f[0] for f in found] == [4]
    np.testing.assert_array_equal(found[0][2], logged[last])


def test_reward_generalisation_matches_intentions_where_the_run_was_opened(tiny_run, monkeypatch):
    from emgail_jax.host import reward_check
    from emgail_jax.host.saved_run import SavedRun

    module = _load("reward_generalisation")
    asked = []
    matching = reward_check.run_matching
    monkeypatch.setattr(
        reward_check, "run_matching", lambda run, seed, i: asked.append(i) or matching(run, seed, i)
    )
    for snapshot, iteration in ((2, 2), (None, 4)):
        run = SavedRun.open(str(tiny_run), snapshot=snapshot)
        module.matched_reward(run, 0, run.reward_parameters(0))
        assert asked[-1] == iteration


def test_reward_generalisation_scores_a_refit_with_absorbing_states(tiny_run, tmp_path, capsys):
    import shutil

    import jax

    from emgail_jax.host import consolidation
    from emgail_jax.host.saved_run import SavedRun

    copy = tmp_path / "run"
    shutil.copytree(tiny_run, copy, ignore=shutil.ignore_patterns("rewards"))
    run = SavedRun.open(str(copy)).with_absorbing_states()
    refit = consolidation.Refit(steps=3, fresh=True, absorbing=True)
    for seed in range(2):
        parameters, losses = consolidation.consolidated_parameters(
            run, seed, refit, jax.random.PRNGKey(seed)
        )
        description = consolidation.refit_description(refit, None, run.iteration)
        consolidation.save_refitted(
            str(copy), "falls", seed, parameters["discriminator"], description, losses
        )
    module = _load("reward_generalisation")
    assert module.main([str(copy), "--episodes", "2", "--refit", "falls"]) == 0
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("seed ")]
    assert len(lines) == 4
    for line in lines:
        values = [float(v) for v in line.split(": ")[1].split(" / ")]
        assert len(values) == 5 and all(np.isfinite(values[1:]))


def test_reward_generalisation_refuses_bad_input_in_one_line(tiny_run, tmp_path, capsys):
    module = _load("reward_generalisation")
    assert module.main([str(tiny_run), "--episodes", "0"]) == 2
    assert "--episodes must be at least 1" in capsys.readouterr().err
    for wrong in ([str(tmp_path / "no-run")], [str(tiny_run), "--snapshot", "3"]):
        assert module.main(wrong) == 2
        err = capsys.readouterr().err
        assert err.startswith("error: ") and err.count("\n") == 1


def test_learned_reward_per_step_is_the_mean_over_each_rows_steps():
    """Row p's reward is p + 1 on every step: its mean per step is p + 1, whatever the
    actions."""
    import jax
    import jax.numpy as jnp

    import envs

    module = _load("reward_generalisation")
    env = envs.make("driver", intentions=2)
    act = lambda state, key: jax.random.uniform(key, (*state.obs.shape[:-1], env.action_size))
    reward = lambda obs, action, rows: rows + 1.0 + 0.0 * action[..., 0]
    per_step = module.learned_reward_per_step(
        env, act, reward, jax.random.PRNGKey(0), jnp.arange(2), 3
    )
    np.testing.assert_allclose(np.asarray(per_step), [1.0, 2.0])
