"""The sweep's cells (experiments/sweep_cells.py): the paper's grid, the cells' names and
options, and where a cell's run directory stands."""

import json

import numpy as np
import pytest

import sweep_cells
from emgail_jax.host import checkpoints


def test_sweep_cells_are_the_papers_experiments():
    cells = sweep_cells.all_cells()
    names = [cell.name for cell in cells]
    assert len(names) == len(set(names)) == 68 + 11  # the paper's, and choosing K
    for name in ("reacher-2-emgail", "hopper-3-emgail-pair", "swimmer-1-gail", "driver-r20-gail"):
        assert name in names, name
    assert len(sweep_cells.select(cells, "fig5a")) == 3 * len(sweep_cells.DRIVER_RADII)
    # halfcheetah: K = 1 (GAIL) and, for K = 2 and 3, three algorithms and EM-GAIL with the
    # paper's one-hot input and with its per-pair E-step.
    assert len(sweep_cells.select(cells, "halfcheetah")) == 1 + 2 * 5
    assert [c.name for c in sweep_cells.select(cells, "reacher-2-emgail")] == ["reacher-2-emgail"]
    assert [c.name for c in sweep_cells.select(cells, "reacher-2-e*")] == [
        "reacher-2-emgail",
        "reacher-2-emgail-onehot",
        "reacher-2-emgail-pair",
        "reacher-2-emgail-auto",
    ]
    # The reward check: every EM-GAIL cell of Figure 6, and at K = 2 the two it is compared with.
    reoptimized = [c.name for c in cells if c.reoptimized]
    assert reoptimized == [
        f"{e}-{k}-{algo}"
        for e, ks in sweep_cells.ROBOTICS_INTENTIONS.items()
        for k in ks
        for algo in sweep_cells.ALGOS
        if algo == "emgail" or k == 2
    ]
    assert "hopper-2-gail" in reoptimized and "hopper-3-gail" not in reoptimized
    with pytest.raises(sweep_cells.SweepError, match="matches no cell"):
        sweep_cells.select(cells, "walker")


def test_choosing_k_cells_train_auto_on_the_first_k_intentions(tmp_path):
    cells = {c.name: c for c in sweep_cells.select(sweep_cells.all_cells(), "choosing-k")}
    assert sorted(cells) == sorted(
        [f"{e}-{k}-emgail-auto" for e, ks in sweep_cells.CHOOSING_K.items() for k in ks]
        + ["driver-2-emgail", "driver-3-emgail", "driver-4-emgail"]
    )
    reacher2, reacher4 = cells["reacher-2-emgail-auto"], cells["reacher-4-emgail-auto"]
    assert reacher2.learned_intentions == reacher4.learned_intentions == 4
    args = reacher2.run_args((), str(tmp_path))
    assert args[:4] == ["--env", "reacher", "--intentions", "auto"]
    assert args[args.index("--demos") + 1] == str(tmp_path / "demos" / "reacher-2.npz")
    assert "--demos" not in reacher4.run_args((), str(tmp_path))  # the shipped set, all 4
    assert "--demos" not in cells["driver-3-emgail"].run_args((), str(tmp_path))
    sweep_cells.write_demonstrations(cells["driver-3-emgail-auto"], str(tmp_path))
    written = np.load(tmp_path / "demos" / "driver-3.npz")
    assert sorted(set(written["intentions"].tolist())) == [0, 1, 2]


def test_sweep_cells_are_records_whose_names_follow_from_their_fields():
    """A cell is its env, K, algorithm, radius and variant: its name (and run directory) and
    its data's name are made from these, and the groups it feeds do not make it another."""
    Cell, Variant = sweep_cells.Cell, sweep_cells.Variant
    assert Cell("hopper", 3, "emgail", variant=Variant.PAIR).name == "hopper-3-emgail-pair"
    assert Cell("driver", 2, "gail", radius=7.0).name == "driver-r7-gail"
    assert Cell("driver", 2, "gail", radius=7.0).data.name == "driver-r7"
    assert Cell("reacher", 4, "emgail", variant=Variant.AUTO).data == sweep_cells.DemoSet(
        "reacher", 4
    )
    assert Cell("swimmer", 2, "emgail", ("table3",)) == Cell("swimmer", 2, "emgail")
    assert Cell("swimmer", 2, "emgail") != Cell("swimmer", 2, "emgail", variant=Variant.ONEHOT)
    for cell in sweep_cells.all_cells():  # every field of the record is the one its name says
        env, where, algo, *variant = cell.name.split("-")
        assert (cell.env, cell.algo, cell.variant) == (env, algo, Variant("".join(variant)))
        expected = f"r{cell.radius:g}" if cell.radius is not None else str(cell.intentions)
        assert where == expected
    onehot = Cell("hopper", 2, "emgail", variant=Variant.ONEHOT).run_args()
    assert onehot[-2:] == ["--intention-input", "onehot"]


def test_sweep_cell_status_reads_the_run_directory(tmp_path):

    def summary(**fields):
        (tmp_path / "summary.json").write_text(json.dumps(fields))

    assert sweep_cells.cell_status(str(tmp_path), 4, 400) == "new"
    summary(seeds=4, status="completed", iterations_done=400)
    assert sweep_cells.cell_status(str(tmp_path), 4, 400) == "done"
    summary(seeds=4, status="interrupted", iterations_done=150)
    assert sweep_cells.cell_status(str(tmp_path), 4, 400) == "new"  # no checkpoint to resume from
    (tmp_path / "checkpoints").mkdir()
    assert sweep_cells.cell_status(str(tmp_path), 4, 400) == "new"  # nor in an empty directory
    checkpoints.save(str(tmp_path), 150, {"w": np.zeros(2)}, {"erd": np.zeros((2, 150))})
    assert sweep_cells.cell_status(str(tmp_path), 4, 400) == "resume"
    # A killed run (no signal handler ran) left "running" and no iterations: resumed all the same.
    summary(seeds=4, status="running")
    assert sweep_cells.cell_status(str(tmp_path), 4, 400) == "resume"
    summary(seeds=4, status="completed", iterations_done=400)
    assert sweep_cells.cell_status(str(tmp_path), 4, 600) == "resume"  # a longer sweep continues it
    with pytest.raises(sweep_cells.SweepError, match="run with 4 seeds, not 2"):
        sweep_cells.cell_status(str(tmp_path), 2, 400)
