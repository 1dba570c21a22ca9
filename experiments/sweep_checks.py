"""The reward checks the sweep runs on a cell (``python -m emgail_jax.reoptimize``): which
ones, with which options and budget, where their files and per-seed parts are written, and
whether a cell's are done."""

from __future__ import annotations

import dataclasses
import json
import os
import sys

import numpy as np

import envs
from emgail_jax.reoptimize import given_budget
from emgail_jax.reoptimize import parse_args as reoptimize_args
from emgail_jax.reward.baseline import baseline_prefix
from emgail_jax.reward.check import Budget, env_budget
from emgail_jax.reward.recipe import refit_parts
from sweep_cells import Cell, summary_or_none

BASELINES_DIR = "true-reward-baselines"  # under OUT, which every node of a Ray sweep sees


@dataclasses.dataclass(frozen=True)
class RewardCheck:
    """One reward check of a cell: ``reoptimize`` with ``options``, written to ``file`` in the
    cell's run directory."""

    file: str
    options: tuple[str, ...] = ()
    draws: int = 1


# The paper's check (§5.2) of the run's own reward, even where the run saved a refit; then the
# reward refitted after the run with the refit's recipe (docs/reward.md, "The refit"). Both get
# the same budget (the env's) and the same draws, each draw a single agent per seed and
# intention.
REFIT_DRAWS = 3
PAPER_CHECK = RewardCheck(
    "reoptimize.json", ("--set", "reward=paper", "--draws", str(REFIT_DRAWS)), REFIT_DRAWS
)
REFIT_CHECK = RewardCheck(
    "reoptimize-refit.json", ("--refit", "--draws", str(REFIT_DRAWS)), REFIT_DRAWS
)
REWARD_CHECKS = (PAPER_CHECK, REFIT_CHECK)

# The refit learns from the run's snapshots: one every 10 iterations (the default 50 gave
# reacher-2 a worse refit, docs/notebook/sweep-cells.md).
CHECKED_SNAPSHOT_EVERY = 10


def reward_check_command(
    run_dir: str, out: str, check: RewardCheck = PAPER_CHECK, path: str | None = None
) -> list[str]:
    """The ``check`` of the cell in ``run_dir``: every seed re-optimised, beside the
    true-reward baseline, cached where every cell of the env and K finds it; written to
    ``path`` (default the check's file)."""
    cache = os.path.join(out, BASELINES_DIR)
    command = [sys.executable, "-m", "emgail_jax.reoptimize", run_dir, *check.options]
    command += ["--cache", cache, "--quiet"]
    return [*command, "--out", path or os.path.join(run_dir, check.file)]


def seed_numbers(summary: dict | None) -> list[int]:
    """The run seeds of a cell's ``summary`` (none without one), as ``reoptimize --seed``
    numbers them."""
    return [summary.get("first_seed", 0) + s for s in range(summary["seeds"])] if summary else []


def check_part_path(run_dir: str, check: RewardCheck, seed: int) -> str:
    """Where run seed ``seed``'s part of a ``check`` spread over processes is written."""
    stem = os.path.splitext(check.file)[0]
    return os.path.join(run_dir, f"{stem}.parts", f"seed-{seed}.json")


def part_is_current(part: str, summary: dict, check: RewardCheck) -> bool:
    """The part at ``part`` checked the final networks of the run of ``summary`` at the budget
    ``check`` has now: a later sweep reuses it."""
    found = _json_or_none(part) or {}
    budget = dataclasses.asdict(check_budget(summary["env"], summary["config"], check))
    return (found.get("iteration"), found.get("budget")) == (summary["iterations_done"], budget)


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
    more iterations is checked again), trained at the env's budget as it is now, as many draws
    as the check has, of the reward it asks for now, and has the true-reward baseline beside
    them."""
    found, summary = reward_check(run_dir, check), summary_or_none(run_dir)
    if found is None or summary is None:
        return False
    every_seed = set(range(seeds)) <= set(checked_seeds(found))
    final = found.get("iteration") == summary.get("iterations_done")
    config = summary.get("config", {})
    # A check written before lambda or scaling were part of the budget trained at the run's.
    before = {"gae_lambda": config.get("gae_lambda"), "value_target_scaling": False}
    recorded = {**before, **(found.get("budget") or {})}
    at_budget = recorded == dataclasses.asdict(check_budget(summary["env"], config, check))
    drawn = len(found.get("draws") or [found]) >= check.draws
    current = at_budget and drawn and checked_reward(found, summary, check)
    return every_seed and final and current and bool(found.get("baseline"))


def checked_reward(found: dict, summary: dict, check: RewardCheck) -> bool:
    """The check ``found`` read the reward ``check`` asks for today: the refit of today's
    recipe for the run's env (its saved name), in the form the recipe reads it."""
    args = reoptimize_args(["RUN", *check.options], summary["env"])
    refit = "-".join(refit_parts(args)) or None
    form = args.reward_form or found.get("reward_form")
    return (found.get("saved_reward"), found.get("reward_form")) == (refit, form)


def check_budget(env: str, config: dict, check: RewardCheck = PAPER_CHECK) -> Budget:
    """The fresh agents' budget in ``check`` of a run of ``env`` with ``config`` (its
    summary's), as ``reoptimize`` resolves the check's options (``--refit``'s recipe too)."""
    scaling = config.get("value_target_scaling", False)
    declared = envs.env_class(env).rl_budget
    own = env_budget(declared, config["iterations"], config["gamma"], config["gae_lambda"], scaling)
    return given_budget(reoptimize_args(["RUN", *check.options], env), own)


def checks_to_do(run_dir: str, seeds: int) -> list[RewardCheck]:
    """The reward checks of a checked cell not yet done, in :data:`REWARD_CHECKS`' order."""
    return [check for check in REWARD_CHECKS if not reward_check_done(run_dir, seeds, check)]


def check_iterations(env: str, iterations: int, check: RewardCheck = PAPER_CHECK) -> int:
    """The fresh policies' TRPO iterations in ``check`` as ``reoptimize`` resolves its options
    (``--refit``'s recipe for the env included): the run's, unless the env declares another
    budget (:attr:`envs.Env.rl_budget`) or the options give another."""
    given = reoptimize_args(["RUN", *check.options], env).iterations
    return given or envs.env_class(env).rl_budget.get("iterations", iterations)


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


def checks_draws_done(cell: Cell, run_dir: str, iterations: int) -> dict[RewardCheck, float]:
    """Per reward check of a trained cell, the draws a check stopped part-way has done; of one
    spread over processes, the mean of its seeds' parts (a part written: every draw)."""
    from emgail_jax.reward.progress import draws_done

    done, numbers = {}, seed_numbers(summary_or_none(run_dir))
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
