"""The sweep's report (experiments/sweep_report.py): tables, CSVs and figures from the
finished cells."""

import csv

import numpy as np
import pytest

import sweep_cells
import sweep_report

pytestmark = pytest.mark.heavy


def test_choosing_k_table_sets_the_chosen_k_beside_k_given(tmp_path):
    cells = {c.name: c for c in sweep_cells.all_cells()}

    def result(name, accuracy, erd, chosen=None, held=None):
        return sweep_report.CellResult(
            cells[name], np.asarray(erd), np.asarray(accuracy), 0, 1.0, None, chosen, held
        )

    found = [
        result("reacher-2-emgail-auto", [0.9, 1.0], [0.1, 0.2], [2, 3], [4, 3]),
        result("reacher-2-emgail", [0.95, 0.95], [0.1, 0.1]),
        result("hopper-3-emgail-auto", [1.0, 1.0], [0.0, 0.0], [3, 3]),
    ]
    sweep_report.write_choosing_k(str(tmp_path), sweep_report.Results({r.cell: r for r in found}))
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


def test_sweep_results_are_selected_by_the_cells_fields():
    """Results.get finds the one cell of the fields asked (the default variant, no radius,
    unless asked), Results.where every cell a predicate keeps, in the sweep's order."""
    Variant = sweep_cells.Variant
    cells = sweep_cells.all_cells()

    def result(cell, erd):
        return sweep_report.CellResult(cell, np.asarray([erd]), None, 0, 1.0, None)

    results = sweep_report.Results({cell: result(cell, i) for i, cell in enumerate(cells)})
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
    driver = results.where(sweep_cells.on_driver_radius)
    assert [r.cell.name for r in driver] == [
        f"driver-r{radius:g}-{algo}"
        for radius in sweep_cells.DRIVER_RADII
        for algo in sweep_cells.ALGOS
    ]
    robotics = results.where(sweep_cells.robotics_default)
    assert {r.cell.env for r in robotics} == set(sweep_cells.ROBOTICS_INTENTIONS)
    assert all(r.cell.variant == Variant.DEFAULT for r in robotics)
    assert len(robotics) == 4 + 3 * 8  # K = 1, and 3 algorithms at each of the 8 K
    assert len(results.where(sweep_cells.robotics_many)) == 3 * 8
    partial = sweep_report.Results({c: r for c, r in results.by_cell.items() if c.algo != "gail"})
    assert partial.get("hopper", 2, "gail") is None


def test_sweep_table3_takes_each_column_from_its_cells(tmp_path):
    """Table 3's csv rows name the env and K of the data the cell trained on, the GMM's row
    comes from the separability table, and a cell that has not finished is a dash."""
    Cell, Variant = sweep_cells.Cell, sweep_cells.Variant
    found = [
        sweep_report.CellResult(Cell("hopper", 3, "emgail"), np.zeros(2), np.asarray([0.9, 0.8]), 0,
                         1.0, None),
        sweep_report.CellResult(Cell("reacher", 2, "emgail", variant=Variant.PAIR), np.zeros(1),
                         np.asarray([0.5]), 0, 1.0, None),
    ]  # fmt: skip
    separability = sweep_report.SeparabilityTable(
        {"hopper-3": {"gmm_accuracy": 0.7, "gmm_accuracy_std": 0.1}}
    )
    sweep_report.write_table3(
        str(tmp_path), sweep_report.Results({r.cell: r for r in found}), separability
    )
    rows = [line.split(",") for line in (tmp_path / "table3.csv").read_text().splitlines()]
    assert rows[1:] == [
        ["hopper", "3", "gmm", "0.7000", "0.1000", "5"],
        ["hopper", "3", "emgail", "0.8500", "0.0500", "2"],
        ["reacher", "2", "emgail-pair", "0.5000", "0.0000", "1"],
    ]
    table = (tmp_path / "table3.md").read_text().splitlines()
    pair = next(line for line in table if line.startswith("| EM-GAIL (per-pair E-step) |"))
    columns = [c.strip() for c in pair.split("|")[2:-1]]
    names = [data.name for data in sweep_report.robotics_sets()]
    assert columns[names.index("reacher-2")] == "50.0 ± 0.0"
    assert columns[names.index("hopper-3")] == "—"


def test_sweep_table2_says_on_how_many_cores_each_cell_ran(tmp_path):
    one = sweep_report.CellResult(
        sweep_cells.Cell("hopper", 2, "emgail"), np.zeros(4), None, 35_983, 1.6, None, devices=1
    )
    sweep_report.write_table2(str(tmp_path), sweep_report.Results({one.cell: one}), seeds=4)
    rows = (tmp_path / "table2.md").read_text().splitlines()
    assert "| hopper | EM-GAIL | 35,983 | 21.2K | 1.60 (1) | 0.40 | 15.6 |" in rows
    assert "| hopper | GAIL | — | 15.3K | — | — | 12.4 |" in rows


def test_sweep_draws_the_figures_whose_cells_have_finished(tmp_path):
    """Each figure takes its cells by field: swimmer's default cells alone draw Figure 6, and
    with the separability of their data Figures 4a and 5b; the driver's none."""
    Cell = sweep_cells.Cell
    found = [
        sweep_report.CellResult(
            Cell("swimmer", k, algo), np.asarray([0.2, 0.4]), None, 0, 1.0, None
        )
        for k in (1, 2)
        for algo in sweep_cells.ALGOS
        if k > 1 or algo == "gail"
    ]
    results = sweep_report.Results({r.cell: r for r in found})
    empty = sweep_report.SeparabilityTable({})
    assert sweep_report.draw_figures(str(tmp_path), results, empty) == ["fig6.png"]
    row = {"separability": 0.5, "separability_std": 0.1}
    known = sweep_report.SeparabilityTable({"swimmer-2": row})
    written = sweep_report.draw_figures(str(tmp_path), results, known)
    assert written == ["fig4a.png", "fig5b.png", "fig6.png"]
    assert sorted(p.name for p in tmp_path.iterdir()) == written


def test_sweep_fig6_csv_sets_the_reward_check_beside_the_joint_erd(hopper_cells):
    """fig6.csv keeps its columns and appends the reward check's: the mean and std of the
    re-optimised ERD over the seeds checked, the true-reward baseline and how many seeds; a
    check of seed 0 alone has no std and no baseline; a cell without a check, empty columns;
    then the refit's check: its mean, std and baseline."""
    results, out = hopper_cells
    sweep_report.write_erd_csvs(str(out), results, sweep_report.SeparabilityTable({}))
    lines = (out / "fig6.csv").read_text().splitlines()
    assert lines[0] == (
        "env,intentions,algo,separability,erd_mean,erd_std,reoptimized_erd,seeds,"
        "reoptimized_erd_std,true_reward_erd,reoptimized_seeds,"
        "refit_erd,refit_erd_std,refit_true_reward_erd,"
        "refit_erd_draws_mean,refit_erd_draws_std,true_reward_erd_lowest,"
        "refit_success_rate,true_reward_success_rate"
    )
    # The refit's record holds three alike draws of 2 seeds (0.1, 0.2), no agents' success and
    # one baseline draw: its 6 single draws' mean and sample sd, the baseline's one draw as its
    # lowest.
    assert lines[1:] == [
        "hopper,1,gail,,0.0100,0.0000,,2,,,,,,,,,,,",
        "hopper,2,emgail,,0.0100,0.0000,0.6000,2,0.1000,0.0300,2,0.1500,0.0500,0.0200,"
        "0.1500,0.0548,0.0200,,",
        "hopper,2,infogail,,0.0300,0.0100,,2,,,,,,,,,,,",
        "hopper,2,gail,,0.5500,0.0500,1.0000,2,0.1000,0.0300,2,,,,,,,,",
        "hopper,3,emgail,,0.0400,0.0100,0.4900,2,,,1,,,,,,,,",
        "hopper,3,gail,,0.4000,0.0000,,2,,,,,,,,,,,",
    ]
    rows = list(csv.DictReader((out / "fig6.csv").open()))  # as readers of the columns see it
    assert [r["reoptimized_erd"] for r in rows if r["algo"] == "emgail"] == ["0.6000", "0.4900"]
    assert [r["refit_erd"] for r in rows if r["algo"] == "emgail"] == ["0.1500", ""]


def test_sweep_fig6_draws_the_reward_checks_dashed_and_the_baseline_dotted(
    hopper_cells, monkeypatch
):
    results, out = hopper_cells
    drawn = {}

    def keep(fig, out, name):
        drawn[name] = fig
        return name

    monkeypatch.setattr(sweep_report, "_save", keep)
    assert sweep_report.draw_fig6(str(out), results) == "fig6.png"
    axes = drawn["fig6.png"].axes
    hopper = axes[list(sweep_cells.ROBOTICS_INTENTIONS).index("hopper")]
    styled = lambda style: [
        (line.get_color(), line.get_xydata().tolist())
        for line in hopper.lines
        if line.get_linestyle() == style
    ]
    # The mean over the seeds checked, per algorithm; seed 0 alone where that is all there is.
    assert styled("--") == [("tab:red", [[2, 0.6], [3, 0.49]]), ("tab:green", [[2, 1.0]])]
    assert styled(":") == [("black", [[2, 0.03]])]
    # The refit's check: the mean of its single draws.
    assert styled("-.") == [("tab:red", [[2, pytest.approx(0.15)]])]
    legend = [text.get_text() for text in axes[-1].get_legend().get_texts()]
    assert legend == [
        "EM-GAIL", "Info/IntentionGAIL", "GAIL", "jointly trained policies",
        "fresh TRPO on the learned reward (§5.2)",
        "the same on the refitted reward, mean of 3 draws x seeds (reoptimize --refit)",
        "fresh TRPO on the true reward",
    ]  # fmt: skip


def _reacher_draw(erds, distances):
    """One draw of a refit check as committed: per seed its ERD and its agents' success, each
    ending ``distances`` from its ball in its 10 episodes (reached: within 0.02)."""
    success = lambda d: {"final_distance": float(np.mean(d)), "reached": float(np.mean(d < 0.02))}
    pairs = zip(erds, distances, strict=True)
    per_seed = [{"erd": e, "success": [success(np.asarray(d))]} for e, d in pairs]
    return {"erd": list(erds), "per_seed": per_seed}


def test_sweep_reads_a_refits_single_draws_and_its_baselines_lowest_draw():
    """From a check recorded before it summed them up: the mean and sample sd over every seed x
    draw, the share of episodes ending at the ball (the reacher's bar, episode by episode), the
    baseline's lowest-ERD draw; its success over every draw is not recorded: none."""
    near, far = [0.01] * 7 + [0.05] * 3, [0.03] * 10
    draws = [_reacher_draw([0.1, 0.3], [near, far]), _reacher_draw([0.2, 0.6], [near, near])]
    baseline = {"erd": 0.8, "draws_erd": [0.8, 0.1, 0.4], "success": [{"reached": 1.0}]}
    read = sweep_report.refit_draws_read({"erd": [0.1, 0.2], "draws": draws, "baseline": baseline})
    found = read["refit_draws"]
    assert found["erd_draws_mean"] == pytest.approx(0.3) and found["erd_draws_n"] == 4
    # sample sd of 0.1 0.3 0.2 0.6: deviations -0.2 0 -0.1 0.3, squares sum 0.14, / 3
    assert found["erd_draws_std"] == pytest.approx(np.sqrt(0.14 / 3))
    assert found["success_rate"] == pytest.approx((0.7 + 0 + 0.7 + 0.7) / 4)
    assert read["true_reward_erd_lowest"] == 0.1 and read["true_reward_success_rate"] is None
    summed = {**draws[0], **found, "baseline": {**baseline, "erd_lowest": 0.1, "success_rate": 1}}
    assert sweep_report.refit_draws_read(summed)["refit_draws"] == found  # read, not summed
    assert sweep_report.refit_draws_read(summed)["true_reward_success_rate"] == 1


def test_sweep_separability_of_the_driver_falls_with_the_radius(tmp_path):
    cells = sweep_cells.select(sweep_cells.all_cells(), "driver-r4-gail,driver-r20-gail")
    table = sweep_report.separability_table(str(tmp_path), cells)
    near, far = (sweep_cells.DemoSet("driver", 2, radius) for radius in (4.0, 20.0))
    assert table.of(near)["separability"] < 0.2 < 0.9 < table.of(far)["separability"]
    assert sorted(table.rows) == ["driver-r20", "driver-r4"]
    # Kept in separability.csv and read back rather than recomputed.
    again = sweep_report.separability_table(str(tmp_path), cells)
    for data in (near, far):
        assert again.of(data) == pytest.approx(table.of(data), abs=1e-4)
