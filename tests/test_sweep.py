"""The sweep (experiments/sweep.py): training and checking cells, the processes of a check,
time estimates, the command line, and damaged cells."""

import csv
import json
import os
import pathlib
import shutil
import socket
import sys

import numpy as np
import pytest

import sweep
import sweep_cells
import sweep_checks
from emgail_jax.reward.progress import FinishedDraws

pytestmark = pytest.mark.heavy


def test_sweep_reward_check_command_is_every_seed_beside_the_cached_baseline(
    hopper_cells, kept_checkpoints, monkeypatch
):
    """A trained cell whose checks are to do runs reoptimize on every seed (no --seed), with the
    baseline (no --no-baseline) cached under OUT, where every cell of the env and K finds it:
    once on the run's reward into reoptimize.json, once with --refit, best of 3 draws, into
    reoptimize-refit.json."""
    from emgail_jax import reoptimize

    _, out = hopper_cells
    ran = []
    monkeypatch.setattr(sweep, "run_command", lambda command, log: ran.append(command) or 0)
    cell = sweep_cells.Cell("hopper", 2, "infogail")
    sweep.train_cell(cell, str(out), 2, 4)
    command, refit_command = ran  # trained already: the checks alone
    assert command[:3] == [sys.executable, "-m", "emgail_jax.reoptimize"]
    args = reoptimize.parse_args(command[3:])
    assert args.run_dir == str(out / "runs" / "hopper-2-infogail")
    assert args.seed is None and args.baseline and args.snapshot is None
    assert args.cache == str(out / "true-reward-baselines")
    assert (args.iterations, args.gamma, args.env_set) == (None, None, [])  # the env's budget
    assert not args.refit and args.draws == 3  # the same draws as the refit's check
    assert args.out == str(out / "runs" / "hopper-2-infogail" / "reoptimize.json")
    assert args.reward == "paper"  # the run's own, even where a refit was saved
    refit = reoptimize.parse_args(refit_command[3:], env="hopper")
    assert refit.refit and refit.draws == 3 and refit.consolidate_ranking == 10
    assert refit.out == str(out / "runs" / "hopper-2-infogail" / "reoptimize-refit.json")
    assert (refit.seed, refit.baseline, refit.cache) == (None, True, args.cache)
    ran.clear()
    sweep.train_cell(sweep_cells.Cell("hopper", 2, "gail"), str(out), 2, 4)
    (gail_refit,) = ran  # its paper's check is done: the refit's alone
    gail_dir = out / "runs" / "hopper-2-gail"
    assert gail_refit[3] == str(gail_dir) and "--refit" in gail_refit
    assert gail_refit[-1] == str(gail_dir / "reoptimize-refit.json")
    ran.clear()
    sweep.train_cell(sweep_cells.Cell("hopper", 2, "emgail"), str(out), 2, 4)
    assert ran == []  # its check is complete


def test_sweep_a_check_over_two_processes_is_one_per_seed_then_merged(
    hopper_cells, kept_checkpoints, monkeypatch
):
    """With two check processes each seed is checked in its own (the last seed's with the
    baseline, started first as the longest), then merged in the seeds' order into the check's
    file, and the parts go; a part already made of these networks at this budget is kept, and
    the merge runs again on it."""
    from emgail_jax import reoptimize

    _, out = hopper_cells
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
    sweep.train_cell(sweep_cells.Cell("hopper", 2, "gail"), str(out), 2, 4, check_processes=2)
    run_dir = out / "runs" / "hopper-2-gail"
    ((parts, processes),) = parallel  # its paper's check is done: the refit's alone
    assert processes == 2 and len(parts) == 2
    args = [reoptimize.parse_args(command[3:], env="hopper") for command in parts]
    assert [(a.seed, a.baseline, a.refit, a.draws) for a in args] == [
        (1, True, True, 3),
        (0, False, True, 3),
    ]
    parts_dir = run_dir / "reoptimize-refit.parts"
    in_order = [str(parts_dir / f"seed-{s}.json") for s in (0, 1)]
    assert [a.out for a in args] == in_order[::-1]
    (merge,) = ran
    merged = reoptimize.parse_args(merge[3:], env="hopper")
    assert merged.merge == in_order and merged.seed is None
    assert merged.out == str(run_dir / "reoptimize-refit.json") and merged.baseline
    assert not parts_dir.exists()  # merged: the parts go
    # A merge that fails keeps the parts; the next sweep reuses them and merges again.
    parallel.clear()
    monkeypatch.setattr(sweep, "run_command", lambda command, log: 2)
    code = sweep.run_reward_check(str(run_dir), str(out), sweep_checks.REFIT_CHECK, "log", 2)
    assert code == 2 and sorted(p.name for p in parts_dir.iterdir()) == [
        "seed-0.json",
        "seed-1.json",
    ]
    assert sweep.run_reward_check(str(run_dir), str(out), sweep_checks.REFIT_CHECK, "log", 2) == 2
    assert parallel[-1][0] == []  # both parts kept


def test_sweep_check_processes_run_at_once_each_on_a_core_and_a_failure_stops_them(tmp_path):
    """Two children that each wait for the other finish only if they run at once; with more
    cores than one each is pinned to its own. A child that fails stops the one still running
    (it would wait for a minute) and its exit code is returned."""
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

    _, out = hopper_cells
    monkeypatch.setattr(checkpoints, "latest_iteration", lambda run_dir: None)
    cell, run_dir = sweep_cells.Cell("hopper", 2, "gail"), out / "runs" / "hopper-2-gail"
    assert sweep.sweep_status(cell, str(run_dir), 2, 4) == sweep_cells.Status.RETRAIN
    assert sweep_checks.checks_to_do(str(run_dir), 2) == [
        sweep_checks.REFIT_CHECK
    ]  # the paper's is done
    complete = sweep_cells.Cell("hopper", 2, "emgail")
    assert sweep.sweep_status(complete, str(out / "runs" / complete.name), 2, 4) == "done"
    timings = sweep.measured_seconds(str(out / "runs"))
    retrain = sweep.estimate_seconds(cell, sweep_cells.Status.RETRAIN, 2, 4, timings)
    assert retrain == sweep.estimate_seconds(cell, sweep_cells.Status.NEW, 2, 4, timings)
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
    _, out = hopper_cells
    Cell, Status = sweep_cells.Cell, sweep_cells.Status
    timings = sweep.measured_seconds(str(out / "runs"))
    assert timings.training == {"hopper": (1.0, 10.0)}
    # The medians of the checks' 16 s over 2 seeds x 4 iterations x 2 intentions (twice) and,
    # seed 0 alone, 6 s over 4 x 3; and of their compiles, 5, 5 and 3 s.
    assert timings.checks == {"hopper": (1.0, 5.0)}
    # The median of the refit check's seeds' 30 and 50 s; an env without one, the default.
    assert timings.refits == {"hopper": 40.0}
    refit_s = timings.of_refit("hopper")
    assert timings.of_refit("halfcheetah") == sweep.REFIT_SECONDS_PER_SEED
    infogail, swimmer = Cell("hopper", 2, "infogail"), Cell("swimmer", 2, "emgail")
    # A draw: (2 seeds + the baseline) x 4 iterations x 2 intentions at 1 s, and two compiles;
    # the paper's check 3 draws of it, the refit's check the same after 2 seeds' refits.
    check = 2 * 5.0 + 3 * 4 * 2
    refit = 2 * refit_s + 3 * check
    paper_only = (sweep_checks.PAPER_CHECK,)
    both = sweep_checks.REWARD_CHECKS
    assert (
        sweep.estimate_seconds(
            infogail, Status.CHECK, 2, 4, timings, computing_baselines=both, checks=paper_only
        )
        == 3 * check
    )
    assert sweep.estimate_seconds(infogail, Status.CHECK, 2, 4, timings) == 3 * check + refit
    without_baseline = sweep.estimate_seconds(
        infogail, Status.CHECK, 2, 4, timings, computing_baselines=()
    )
    assert without_baseline == 3 * (5.0 + 2 * 4 * 2) + 2 * refit_s + 3 * (5.0 + 2 * 4 * 2)
    trained = 10.0 + 1.0 * 2 * 4 * 2
    assert sweep.estimate_seconds(infogail, Status.NEW, 2, 4, timings) == (
        trained + 3 * check + refit
    )
    # Over two processes a seed each, the baseline's beside the last: a seed and the baseline.
    check_2 = 2 * 5.0 + 2 * 4 * 2
    refit_2 = refit_s + 3 * check_2
    over_two = sweep.estimate_seconds(infogail, Status.CHECK, 2, 4, timings, check_processes=2)
    assert over_two == 3 * check_2 + refit_2
    # A check stopped part-way costs what it has left: its finished draw and half the next.
    run_dir = out / "runs" / infogail.name
    finished = FinishedDraws(str(run_dir / sweep_checks.REFIT_CHECK.file), {})
    finished.write(0, {"erd": [0.5, 0.5]})
    finished.partial(1).write(2, {"w": np.zeros(3)}, np.zeros((2, 1)), np.zeros((2, 1)), 1.0)
    done = sweep_checks.checks_draws_done(infogail, str(run_dir), 4)
    assert done == {sweep_checks.PAPER_CHECK: 0.0, sweep_checks.REFIT_CHECK: 1.5}
    # Spread over processes, its seeds' parts: seed 0's written (3 draws), seed 1's one draw.
    parts = [
        sweep_checks.check_part_path(str(run_dir), sweep_checks.REFIT_CHECK, seed)
        for seed in (0, 1)
    ]
    os.makedirs(os.path.dirname(parts[0]))
    pathlib.Path(parts[0]).write_text("{}")
    FinishedDraws(parts[1], {}).write(0, {"erd": [0.5]})
    assert (
        sweep_checks.checks_draws_done(infogail, str(run_dir), 4)[sweep_checks.REFIT_CHECK] == 2.0
    )
    shutil.rmtree(os.path.dirname(parts[0]))  # gone: the whole check's draws count again
    assert sweep.estimate_seconds(
        infogail, Status.CHECK, 2, 4, timings, draws_done=done
    ) == pytest.approx(3 * check + refit / 2)
    per_unit, compile_s = sweep.MEASURED_SECONDS["swimmer"]  # no swimmer cell finished
    check = 3 * (2 * compile_s + per_unit * 3 * 1500 * 2)  # the swimmer's experts' budget
    estimate = sweep.estimate_seconds(
        swimmer, Status.CHECK, 2, 4, timings, computing_baselines=both, checks=paper_only
    )
    assert estimate == pytest.approx(check)
    # Halfcheetah declares 1000 iterations for its fresh agents: both checks train them so long.
    cheetah = Cell("halfcheetah", 2, "emgail")
    assert sweep_checks.check_iterations("halfcheetah", 4, sweep_checks.PAPER_CHECK) == 1000
    assert sweep_checks.check_iterations("halfcheetah", 4, sweep_checks.REFIT_CHECK) == 1000
    per_unit, compile_s = sweep.MEASURED_SECONDS["halfcheetah"]
    refit_check = sweep.estimate_seconds(
        cheetah,
        Status.CHECK,
        2,
        4,
        timings,
        computing_baselines=(),
        checks=(sweep_checks.REFIT_CHECK,),
    )
    assert refit_check == pytest.approx(
        2 * sweep.REFIT_SECONDS_PER_SEED + 3 * (compile_s + per_unit * 2 * 1000 * 2)
    )
    # One baseline per env, K and budget: the paper's check computes it where the refit's
    # check has the same budget, each its own where not.
    paper, refit = sweep_checks.PAPER_CHECK, sweep_checks.REFIT_CHECK
    hopper = [Cell("hopper", 2, "infogail"), Cell("hopper", 2, "gail"), Cell("hopper", 3, "emgail")]
    assert sweep_checks.baseline_computers(hopper, str(out), 4) == {
        (hopper[0], paper),
        (hopper[2], paper),
    }
    cache = out / "true-reward-baselines"
    cache.mkdir()
    paper_check = json.loads((out / "runs" / "hopper-2-emgail" / "reoptimize.json").read_text())
    (cache / paper_check["baseline"]["cache"]).write_text("{}")
    assert sweep_checks.baseline_computers(hopper, str(out), 4) == {(hopper[2], paper)}
    # Its two checks share one budget, hence one baseline, which the paper's check computes.
    assert sweep_checks.baseline_computers([cheetah], str(out), 4) == {(cheetah, paper)}


@pytest.mark.slow  # end to end (make test-slow); cheaper tests cover its parts
def test_sweep_runs_skips_and_reports_driver_cells(tmp_path, capsys):
    """End to end on two tiny driver cells (the sizes of the other tiny driver runs): trained in
    this process, the second radius on the first one's compiled programs, reported, then
    skipped."""
    from emgail_jax.host.program_cache import SHARED

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


def test_sweep_a_damaged_cell_is_named_and_continues_from_its_checkpoint(
    tmp_path, tiny_run, capsys
):
    import shutil

    from emgail_jax import run

    run_dir = tmp_path / "cell"
    shutil.copytree(tiny_run, run_dir)
    intact = (run_dir / "summary.json").read_text()
    (run_dir / "summary.json").write_text(intact[: len(intact) // 2])  # cut short
    assert sweep_cells.cell_status(str(run_dir), 2, 6) == "damaged"
    options = [
        *("--env", "driver", "--seeds", "2", "--iterations", "6", "--num-envs", "2"),
        *("--rollout-length", "20", "--chunk-size", "2"),
    ]
    log = tmp_path / "cell.log"
    assert sweep.repair_cell("cell", str(run_dir), options, str(log)) == "resume"
    message = "cell cell: its summary.json is damaged (kept as"
    assert message in capsys.readouterr().err and message in log.read_text()
    assert (run_dir / "summary.json.damaged").read_text() == intact[: len(intact) // 2]
    assert sweep_cells.cell_status(str(run_dir), 2, 6) == "resume"
    assert run.main(["--resume", str(run_dir), "--quiet"]) == 0
    summary = json.loads((run_dir / "summary.json").read_text())
    assert (summary["status"], summary["iterations_done"]) == ("completed", 6)
    before = (tiny_run / "metrics.csv").read_text()
    assert (run_dir / "metrics.csv").read_text().startswith(before)  # iterations 1-4 kept


def test_sweep_a_damaged_cell_without_a_checkpoint_starts_anew(tmp_path, capsys):
    (tmp_path / "summary.json").write_text("{not json")
    assert sweep_cells.cell_status(str(tmp_path), 4, 400) == "damaged"
    status = sweep.repair_cell("c", str(tmp_path), [], str(tmp_path / "c.log"))
    assert status == "new" and "starts anew" in capsys.readouterr().err
    assert (tmp_path / "summary.json.damaged").read_text() == "{not json"
