"""The sweep's reward checks (experiments/sweep_checks.py): which a cell still needs, and at
which budget."""

import json
import pathlib

import envs
import sweep
import sweep_cells
import sweep_checks
from emgail_jax.reward.check import Budget


def test_sweep_a_cell_is_checked_until_every_seed_and_the_baseline_are(
    hopper_cells, kept_checkpoints, monkeypatch
):
    """A trained cell whose checks are missing, or the paper's took seed 0 alone, or the refit's
    is missing, has its checks to do (and only those); one the sweep does not check, or whose
    checks are complete, is done."""
    _, out = hopper_cells
    status = {
        name: sweep.sweep_status(cell, str(out / "runs" / name), 2, 4)
        for name, cell in (
            (c.name, c) for c in sweep_cells.select(sweep_cells.all_cells(), "hopper")
        )
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
    assert not sweep_checks.reward_check_done(str(out / "runs" / "hopper-2-emgail"), 2)
    gail = str(out / "runs" / "hopper-2-gail")
    assert sweep_checks.checks_to_do(gail, 2) == [sweep_checks.REFIT_CHECK]
    # A check written before lambda was in the budget trained at the run's: done; one at a
    # budget the env no longer has (its lambda changed since): to do again.
    assert sweep_checks.reward_check_done(gail, 2)
    monkeypatch.setattr(envs.env_class("hopper"), "rl_budget", {"gae_lambda": 0.995})
    assert not sweep_checks.reward_check_done(gail, 2)
    check = json.loads((out / "runs" / "hopper-2-gail" / "reoptimize.json").read_text())
    check["budget"]["gae_lambda"] = 0.995
    (out / "runs" / "hopper-2-gail" / "reoptimize.json").write_text(json.dumps(check))
    assert sweep_checks.reward_check_done(gail, 2)
    # Likewise scaling: a check recorded without it trained unscaled, as the run's config.
    monkeypatch.setattr(
        envs.env_class("hopper"), "rl_budget", {"gae_lambda": 0.995, "value_target_scaling": True}
    )
    assert not sweep_checks.reward_check_done(gail, 2)
    check["budget"]["value_target_scaling"] = True
    (out / "runs" / "hopper-2-gail" / "reoptimize.json").write_text(json.dumps(check))
    assert sweep_checks.reward_check_done(gail, 2)


def test_the_sweeps_checks_train_at_the_budget_the_env_declares_for_either_reward():
    """The paper's reward and the refit get the same budget: the env's (halfcheetah declares
    1000 iterations and scaled value targets), the run's own where it declares none."""
    config = {"iterations": 400, "gamma": 0.995, "gae_lambda": 0.97}
    budget = lambda env, check: sweep_checks.check_budget(env, config, check)
    for check in (sweep_checks.REFIT_CHECK, sweep_checks.PAPER_CHECK):
        cheetah = budget("halfcheetah", check)
        assert cheetah.value_target_scaling and cheetah.iterations == 1000
        assert sweep_checks.check_iterations("halfcheetah", 400, check) == 1000
        assert budget("hopper", check) == Budget(400, 0.995, 0.97, False)
        assert budget("swimmer", check) == Budget(1500, 0.9999, 0.995, False)
        assert budget("reacher", check) == Budget(1000, 0.995, 0.97, False)


def test_a_part_is_reused_only_if_it_checked_these_networks_at_this_budget(hopper_cells):
    """A seed's part of a check spread over processes is current when it checked the run's final
    iteration at the budget the check has now; a missing, unreadable, older or other-budget
    part is checked again."""
    _, out = hopper_cells
    run_dir = out / "runs" / "hopper-2-gail"
    summary = json.loads((run_dir / "summary.json").read_text())
    check = sweep_checks.REFIT_CHECK
    part = sweep_checks.check_part_path(str(run_dir), check, 1)
    assert part == str(run_dir / "reoptimize-refit.parts" / "seed-1.json")
    assert not sweep_checks.part_is_current(part, summary, check)  # none yet
    budget = {"iterations": 4, "gamma": 0.995, "gae_lambda": 0.97, "value_target_scaling": False}
    (run_dir / "reoptimize-refit.parts").mkdir()
    written = {"iteration": 4, "budget": budget}
    for found, current in (
        (written, True),
        ({**written, "iteration": 2}, False),  # the networks before a resumed run's last ones
        ({**written, "budget": {**budget, "gae_lambda": 0.995}}, False),
    ):
        pathlib.Path(part).write_text(json.dumps(found))
        assert sweep_checks.part_is_current(part, summary, check) == current, found
    pathlib.Path(part).write_text("{cut short")
    assert not sweep_checks.part_is_current(part, summary, check)
