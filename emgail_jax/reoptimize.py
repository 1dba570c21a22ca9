"""Is the learned reward a reward? Train fresh policies on it and measure their ERD (paper §5.2).

    python -m emgail_jax.reoptimize RUN_DIR [--seed S] [--rl-seed R] [--draws N]
        [--keep-draw most|nearest] [--snapshot ITER] [--iterations N] [--refit]
        [--set KEY=VALUE ...] [--no-baseline] [--cache DIR] [--env-set KEY=FACTOR ...]
        [--merge CHECK ...] [--out PATH] [--quiet]

For every run seed (or ``--seed S`` alone) and every learned intention, a new policy is trained
from scratch with TRPO on the frozen pseudo-reward R_i(s, a) of that seed: the run's saved
reward (``RUN_DIR/reward/``, written by ``python -m emgail_jax.refit``) when it has one, read
as its ``reward.json`` says and as ``load_reward`` returns it; otherwise, or with ``--set
reward=paper``, the paper's, the run's own discriminators (its final networks, or those of the
snapshot of ``--snapshot ITER``); with ``--refit``, or ``--set consolidate=STEPS``, each seed's
discriminator refitted here against every snapshot's policy, as ``python -m emgail_jax.refit``
saves it, and reused if saved before. The fresh policies never see the true reward; the seeds'
and intentions' policies are vmapped in one program (``--rl-seed R``: another draw of their
initialisation and samples, to tell a reward that fails from a search that did; ``--draws N``:
N draws, keeping per intention the agent that earns the most learned reward, as a user without
the true reward would, or with ``--keep-draw nearest`` the one nearest what the demonstrations
earn; each finished draw, and the training of the one under way every few minutes, is kept
beside the check's file until it is written, so a check stopped part-way goes on from there;
``--merge`` joins checks of one seed each, run with ``--seed S`` on other cores or machines,
into the check of them all, training no agent on the learned reward). Their deterministic
episodes (as many per iteration as training evaluates, ``num_envs``) are scored under the true
rewards; the ERD matches each true intention to the learned one the run itself matched it to
(its jointly trained policies' matching at that iteration), one matching for every number
reported. Each env's success measure (the experts' bars: velocity, upright, pitch turn, ball
reached) is reported beside it, over the experts' 10 deterministic episodes.

Every algorithm's run is checked on the reward its own policies were trained on
(:meth:`~emgail_jax.host.saved_run.SavedRun.reward_function`); every fresh policy has the same
budget whatever the algorithm, so that the algorithms' checks compare the rewards alone. An
AIRL run is checked on its state-only reward g_i(s). A reward with an absorbing state (a run
trained with absorbing states, or a refit with ``consolidate_absorbing``) pays a fresh
policy's termination its learned value for every step left, or with ``--set
absorbing_reward=random`` what uniformly random actions earn per step under it.

Beside the learned reward, the **true-reward baseline** (:mod:`emgail_jax.reward.baseline`):
the same TRPO, settings and budget on the env's true rewards, read from ``--cache`` once
computed. The budget is the run's iterations, gamma and GAE lambda unless its env declares
another (:attr:`envs.Env.rl_budget`) or ``--iterations`` or ``--set`` say otherwise. Also the
learned reward per step that the fresh policies and the demonstrations earn. Writes
``RUN_DIR/reoptimize.json`` (a name that says what was checked otherwise, :func:`default_name`).

``--env-set`` trains and scores the fresh policies in a variant of the env (changed masses,
gravity, friction or viscosity: docs/environments.md), ERD normalised by the variant's own
references; the run's own jointly trained policies are deployed there beside them.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import os
import sys

from emgail_jax.host import jax_setup
from emgail_jax.host.command_line import ArgumentParser, add_run_and_seed
from emgail_jax.host.schedule import FINAL_WINDOW  # the iterations averaged, as training's
from emgail_jax.reward import baseline, check, draws, progress, recipe


def budget_of(args: argparse.Namespace, run) -> check.Budget:
    """The env's budget for ``run`` as ``args`` change it (:func:`given_budget`)."""
    return given_budget(args, check.default_budget(run))


def given_budget(args: argparse.Namespace, budget: check.Budget) -> check.Budget:
    """``budget`` with ``--iterations`` and the ``gamma``, ``gae_lambda`` and
    ``value_target_scaling`` settings in place where given."""
    given = {
        "iterations": args.iterations,
        "gamma": args.gamma,
        "gae_lambda": args.gae_lambda,
        "value_target_scaling": args.value_target_scaling,
    }
    given = {name: value for name, value in given.items() if value is not None}
    return dataclasses.replace(budget, **given)


def print_result(run, result: dict) -> None:
    from rich.console import Console

    console = Console(width=140)
    console.print(_result_table(run, result))
    for line in [*_reward_lines(result), *_headline_lines(result)]:
        console.print(line)
    reference = (result.get("variant") or {}).get("reference_meets_bar")
    if reference and None not in reference and not all(reference):
        # ERD is |reference - return|: past a weak reference it grows, so say it is weak.
        console.print(
            f"the variant's best true-reward agents, ERD's 0 here, meet {sum(reference)} of "
            f"{len(reference)} of the experts' bars: agents that beat them score ERD > 0 too; "
            "read the bars"
        )
    for line in _draws_lines(result):
        console.print(line)


def _reward_lines(result: dict) -> list[str]:
    """Which reward was checked: the saved one with its recipe, a refit made here, or the
    paper's (none said by a check recorded before it was told)."""
    reward = result.get("reward") or {}
    source = reward.get("source")
    given = lambda settings: recipe.spelled({key: on for key, on in settings.items() if on})
    if source == "saved":
        form, price = reward["form"], reward["termination_price"]
        if form != reward["saved_form"]:
            form += f" (saved as {reward['saved_form']})"
        fall = "" if price is None else f", a fall paid per step left at its {price} price"
        return [
            f"reward checked: the saved reward {reward['directory']} (python -m "
            f"emgail_jax.refit: {given(reward['recipe'])}), read as {form}{fall}"
        ]
    if source == "refit":
        return [
            f"reward checked: the refit '{result['saved_reward']}' made here "
            f"({given(reward['recipe'])}), read as {result['reward_form']}"
        ]
    if source == "paper":
        return [f"reward checked: the paper's, the run's own ({result['reward_form']})"]
    return []


def _headline_lines(result: dict) -> list[str]:
    """The check's headline, the mean over every seed x draw; beside it what a choice among the
    draws kept, the true-reward baseline's every draw and the do-nothing reference."""
    three = lambda x: "-" if x is None else f"{x:.3f}"
    share = lambda x: "-" if x is None else f"{x:.0%}"
    distance = result.get("final_distance")
    lines = [
        f"re-optimised ERD, mean of every seed x draw: {three(result['erd_draws_mean'])} ± "
        f"{three(result['erd_draws_std'])} (sample sd, n = {result['erd_draws_n']}); episodes "
        f"meeting the experts' bars {share(result['success_rate'])}"
        + ("" if distance is None else f", final distance to the ball {distance:.3f}")
    ]
    if "draws" in result:
        lines.append(
            f"best of {len(result['draws'])} draws kept by the learned reward: "
            f"{three(result['erd_mean'])} ± {three(result['erd_std'])} over "
            f"{len(result['seeds'])} seeds; episodes meeting the bars "
            f"{share(result['kept_success_rate'])}"
        )
    baseline = result.get("baseline")
    if baseline:
        lines.append(
            f"true reward: kept {three(baseline['erd'])}; each draw "
            + " ".join(three(e) for e in baseline["draws_erd"])
            + f", lowest {three(baseline['erd_lowest'])}; episodes meeting the bars "
            f"{share(baseline['success_rate'])} (kept {share(baseline['kept_success_rate'])})"
        )
    for row in result.get("do_nothing") or []:
        lines.append(f"doing nothing ({row['actions']} actions): ERD {three(row['erd'])}")
    return lines


def _result_table(run, result: dict):
    """The table of every seed's fresh agents, the baseline and a variant's own policies."""
    from rich.table import Table

    names = run.problem.env.intention_names
    budget = result["budget"]
    table = Table(
        title=f"fresh TRPO on the learned rewards of iteration {result['iteration']}, "
        f"{budget['iterations']} iterations, gamma {budget['gamma']}, lambda "
        f"{budget.get('gae_lambda', '-')}"
        f"{', value targets scaled' if budget.get('value_target_scaling') else ''}"
        f" (mean of the last {FINAL_WINDOW})"
    )
    columns = ("reward", "norm. ERD", "per intention", "true returns (expert)", "bars met")
    for column in (*columns, "episodes meeting bars"):
        table.add_column(column)
    expert = result["expert_returns"]
    number = lambda x: "-" if x is None else f"{x:.3f}"

    def row(label, scores):
        returns = ", ".join(
            f"{names[i]} {r:.1f}" + ("" if expert is None else f" ({expert[i]:.1f})")
            for i, r in enumerate(scores["returns"])
        )
        per = scores["erd_per_intention"]
        bars = scores["meets_bar"]
        met = "-" if None in bars else f"{sum(bars)}/{len(bars)}"
        per_text = "-" if per is None else " ".join(f"{e:.2f}" for e in per)
        table.add_row(label, number(scores["erd"]), per_text, returns, met, _shares(scores))

    for seed_result in result["per_seed"]:
        seed_result = {**seed_result, "meets_bar": [q["meets_bar"] for q in seed_result["success"]]}
        row(f"seed {seed_result['run_seed']}", seed_result)
    if result.get("baseline"):
        row("true reward", result["baseline"])
    joint = (result.get("variant") or {}).get("joint_policies")
    for seed_result in joint["per_seed"] if joint else []:
        row(
            f"seed {seed_result['run_seed']}: its own policy",
            {**seed_result, "meets_bar": [None], "erd_per_intention": None},
        )
    return table


def _shares(scores: dict) -> str:
    """Per true intention, the share of its agent's episodes that meet the experts' bar, and
    its final distance to the ball where measured."""
    texts = []
    for q in scores.get("success") or []:
        share = check.episode_share(q)
        text = "-" if share is None else f"{share:.0%}"
        if q.get("final_distance") is not None:
            text += f" ({q['final_distance']:.3f})"
        texts.append(text)
    return " ".join(texts) or "-"


def _draws_lines(result: dict) -> list[str]:
    """Per seed, the draws kept, a fall's price and the learned reward earned."""
    two = lambda x: "-" if x is None else f"{x:.2f}"
    lines = []
    for seed_result in result["per_seed"] if "draws" in result else []:
        draws_erd = " ".join(two(e) for e in seed_result["draws_erd"])
        lines.append(
            f"seed {seed_result['run_seed']}: of {len(result['draws'])} draws, kept by the "
            f"learned reward ({result.get('draw_rule', 'most')}; each draw's ERD {draws_erd}), "
            "true intentions acted by draws "
            + " ".join(str(result["rl_seeds"][d]) for d in seed_result["draw"])
        )
    for seed_number, price in zip(
        result["seeds"], result.get("absorbing_price") or [], strict=False
    ):
        paid = zip(price["random_actions"], price["learned"], strict=True)
        lines.append(
            f"seed {seed_number}: a fall paid per step left "
            + ", ".join(f"{two(r)} (learned {two(a)})" for r, a in paid)
            + ", what random actions earn"
        )
    for seed_result in result["per_seed"]:
        earned = seed_result["learned_reward_per_step"]
        pairs = zip(earned["fresh_policies"], earned["demonstrations"], strict=True)
        lines.append(
            f"seed {seed_result['run_seed']}: learned reward per step, fresh policies / "
            "demonstrations: " + ", ".join(f"{two(a)} / {two(b)}" for a, b in pairs)
        )
    return lines


def argument_parser() -> argparse.ArgumentParser:
    parser = ArgumentParser(
        prog="python -m emgail_jax.reoptimize", description=__doc__.split("\n")[0]
    )
    add_run_and_seed(parser)
    parser.add_argument(
        "--rl-seed",
        type=int,
        default=0,
        metavar="R",
        help="another draw of the fresh policies' initialisation and samples on the same "
        "rewards (default 0)",
    )
    parser.add_argument(
        "--draws",
        type=int,
        default=1,
        metavar="N",
        help="train N draws (RL seeds R .. R + N - 1) and keep per intention the agent that "
        "earns the most learned reward (--keep-draw); the true-reward baseline's the one that "
        "earns the most true reward (default 1); a check stopped part-way goes on where it "
        "stopped",
    )
    parser.add_argument(
        "--keep-draw",
        choices=draws.DRAW_RULES,
        default="most",
        help="with --draws: per intention keep the agent that earns the most learned reward "
        "per step (default), or the one nearest what the demonstrations earn",
    )
    parser.add_argument(
        "--snapshot", type=int, default=None, metavar="ITER", help="the rewards of this snapshot"
    )
    parser.add_argument("--iterations", type=int, default=None, help="default: the env's budget")
    parser.add_argument(
        "--refit",
        action="store_true",
        help="check the refit that re-optimises best where it was measured (python -m "
        "emgail_jax.refit, reused if saved): "
        + recipe.spelled(recipe.REFIT)
        + ", read as log D unless the env's episodes end early (without "
        "consolidate_absorbing); "
        + "; ".join(f"on {env} also {recipe.refit_extras(env)}" for env in recipe.REFIT_BY_ENV)
        + "; a --set or --iterations given with it replaces that one",
    )
    recipe.add_settings_option(parser, recipe.CHECK_SETTINGS, "a setting of the check or its refit")
    parser.add_argument(
        "--no-baseline", dest="baseline", action="store_false", help="skip the true reward"
    )
    parser.add_argument(
        "--cache", default=None, help=f"true-reward baselines (default {baseline.default_cache()})"
    )
    parser.add_argument(
        "--env-set",
        nargs="+",
        default=[],
        metavar="KEY=FACTOR",
        help="train and score in a variant of the env: mass.BODY, gravity, friction, viscosity "
        "(factors on the model's values; ERD against the variant's own true-reward baseline)",
    )
    parser.add_argument(
        "--merge",
        nargs="+",
        default=[],
        metavar="CHECK",
        help="train no agent on the learned reward: join these checks, each of one seed "
        "(--seed S) with the options given here, into the check of their seeds",
    )
    parser.add_argument("--out", default=None, help="default: RUN_DIR/reoptimize[-...].json")
    parser.add_argument("--quiet", action="store_true")
    return parser


def parse_args(argv=None, env: str | None = None) -> argparse.Namespace:
    """The command line, its ``--set`` settings typed and checked, with ``--refit``'s recipe
    for ``env`` filled in (:func:`~emgail_jax.reward.recipe.with_refit_recipe`); exits 2 with
    one line on a setting it does not take."""
    args = recipe.parsed_command_line(argument_parser(), argv, recipe.CHECK_SETTINGS)
    return recipe.with_refit_recipe(args, env)


def _check_options(args: argparse.Namespace) -> None:
    from emgail_jax.host.run_spec import RunError

    if args.rl_seed < 0:
        raise RunError("--rl-seed must be 0 or more")
    if args.draws < 1:
        raise RunError("--draws must be at least 1")
    if args.keep_draw != "most" and args.draws == 1:
        raise RunError("--keep-draw chooses among draws: give --draws N with N > 1 too")
    if args.iterations is not None and args.iterations < 1:
        raise RunError("--iterations must be at least 1")
    recipe.check_refit_settings(args)
    if args.across_seeds and args.consolidate:
        raise RunError("across_seeds averages the run's own rewards: not with a refit")
    if args.absorbing_reward == "random" and args.across_seeds:
        raise RunError("absorbing_reward=random prices one seed's reward: not with across_seeds")
    if args.env_set and not args.baseline:
        raise RunError(
            "--env-set scores against the variant's true-reward baseline: drop --no-baseline"
        )
    if args.merge and args.seed is not None:
        raise RunError("--merge joins checks of one seed each: drop --seed")


# Options deleted since checks were first recorded, at the one value they still have: a
# check's record (what --merge and a check stopped part-way match) reads as before.
RETIRED_OPTIONS = {"ensemble": 0, "consolidate_agents": 0, "consolidate_state_only": False}
RETIRED_DETAILS = {"ensemble": None}


@dataclasses.dataclass
class Chosen:
    """The reward the command line asks for: ``parameters`` (one per seed; None: the run's),
    read by ``function`` and ``absorbing`` (None: the run's reward and absorbing reward), and
    what was done to get them (``result`` keys)."""

    parameters: list | None = None
    function: object = None
    absorbing: object = None
    details: dict = dataclasses.field(default_factory=dict)


def _run_opened(args: argparse.Namespace):
    """``(args, run)`` of the command line (:func:`_reward_opened`), in the variant if asked."""
    args, run = _reward_opened(args)
    if args.env_set:
        run.problem = check.variant_problem(run, args.env_set)
    return args, run


def _reward_opened(args: argparse.Namespace):
    """``(args, run)`` of the command line: ``args`` with the reward checked resolved
    (:func:`reward_source`) and its form for the run's env
    (:func:`~emgail_jax.reward.recipe.refit_reward_form`), the saved run with that form; a
    saved reward's run opened as ``load_reward`` opens it."""
    import envs
    from emgail_jax.host.run_spec import RunError
    from emgail_jax.host.saved_run import SavedRun
    from emgail_jax.reward import product

    _check_options(args)
    args = argparse.Namespace(**{**vars(args), "reward": reward_source(args)})
    if args.reward == "saved":
        run, _ = product.opened(args.run_dir, args.reward_form)
    else:
        run = SavedRun.open(args.run_dir, snapshot=args.snapshot)
    if run.config.method.m_step.form.airl and (args.reward_form or args.consolidate):
        # Its reward is g_i(s), no reading of a GAIL discriminator's logit, nor refitted as one.
        raise RunError(
            "an AIRL run's reward is g_i(s): reward_form, consolidate and --refit do not apply"
        )
    form = recipe.refit_reward_form(args, envs.env_class(run.spec.env).terminates)
    args = argparse.Namespace(**{**vars(args), "reward_form": form})
    if args.reward_form is not None:
        run = run.with_reward_form(args.reward_form)
    return args, run


def reward_source(args: argparse.Namespace) -> str:
    """The reward a check reads: ``refit``, made (or reused) here (``--refit``,
    ``consolidate``); ``saved``, the run's ``RUN/reward/``; or ``paper``, the run's own
    discriminators. Unless ``--set reward`` names one, the saved reward where the run has
    one refitted from the networks checked (``--snapshot``) and no other is asked
    (``across_seeds``), as ``load_reward`` chooses.

    Raises:
      RunError: a reward named beside a refit, or a saved one that the run lacks or that does
        not go with the options given.
    """
    from emgail_jax.host.run_spec import RunError
    from emgail_jax.reward import product

    if args.consolidate:
        if args.reward is not None:
            raise RunError(
                f"--set reward={args.reward} checks a reward made before: not with --refit or "
                "consolidate"
            )
        return "refit"
    if args.reward == "paper":
        return "paper"
    if args.reward is None and (args.across_seeds or not product.exists(args.run_dir)):
        return "paper"
    snapshot = product.read(args.run_dir)["networks"]["snapshot"]
    if args.reward is None and snapshot != args.snapshot:
        return "paper"  # the snapshot's own reward: the saved one is of other networks
    if args.across_seeds or args.absorbing_reward:
        given = "across_seeds" if args.across_seeds else "absorbing_reward"
        raise RunError(
            f"{given} goes with the run's own reward, not the saved one (which pays a "
            "termination as its reward.json says): give --set reward=paper"
        )
    if snapshot != args.snapshot:
        networks = "the final networks" if snapshot is None else f"snapshot {snapshot}"
        raise RunError(f"the saved reward was refitted from {networks}: drop --snapshot")
    return "saved"


def _opened(args: argparse.Namespace):
    """``(args, run, seeds, Chosen)`` of the command line (:func:`_reward_opened`): the saved
    reward read as ``load_reward`` reads it, or the refit or across-seeds reward if asked."""
    from emgail_jax.host.run_spec import RunError
    from emgail_jax.host.saved_run import across_seeds_reward
    from emgail_jax.reward import saved

    args, run = _reward_opened(args)
    seeds = list(range(run.spec.seeds)) if args.seed is None else [run.seed_index(args.seed)]
    chosen = Chosen(
        details={
            "reward": {"source": args.reward},
            "consolidation": None,
            **RETIRED_DETAILS,
            "across_seeds": None,
            "absorbing_price": None,
            "termination": None,
        }
    )
    if args.reward == "saved":  # as load_reward reads it, in the env it was saved in
        saved_reward_chosen(run, seeds, chosen)
    if args.env_set:
        run.problem = check.variant_problem(run, args.env_set)
    if args.consolidate:
        name, refit = "-".join(recipe.refit_parts(args)), recipe.refit_of(args)
        run = saved.run_to_refit(run, refit)
        chosen.parameters, chosen.details["consolidation"] = saved.saved_or_refitted(
            run, seeds, refit, name, progress=not args.quiet
        )
        chosen.details["saved_reward"] = name
        recipe_given = {key: getattr(args, key) for key in recipe.SAVED_SETTINGS}
        chosen.details["reward"]["recipe"] = recipe_given
    if args.across_seeds:
        if run.spec.seeds < 2:
            raise RunError("across_seeds needs a run of 2 or more seeds")
        chosen.parameters = [run.across_seeds_parameters(seed) for seed in seeds]
        chosen.function = across_seeds_reward(run.reward_function())
        if run.absorbing_reward_function() is not None:
            chosen.absorbing = across_seeds_reward(run.absorbing_reward_function())
        # [seed][t][i]: seed t's intention averaged into intention i of each checked seed
        chosen.details["across_seeds"] = [p["intentions"] for p in chosen.parameters]
    if args.absorbing_reward == "random":
        priced_at_random_actions(run, seeds, chosen)
    return args, run, seeds, chosen


def saved_reward_chosen(run, seeds: list[int], chosen: Chosen) -> None:
    """``chosen`` as the run's saved reward (``RUN/reward/``) of ``seeds``, each exactly the
    :class:`~emgail_jax.reward.load.LearnedReward` ``load_reward`` returns: its parameters,
    its function and its termination (paid per step left; 0 where it has none), and
    ``reward.json``'s recipe in its details."""
    import jax.numpy as jnp

    from emgail_jax.reward import load, product
    from emgail_jax.reward.refit import priced_absorbing_reward

    description = product.read(run.run_dir)
    rewards = [load.saved_reward(run, description, seed, run.run_dir) for seed in seeds]
    chosen.function = run.reward_function()
    chosen.parameters = [reward.parameters for reward in rewards]
    paid = [reward.termination_values for reward in rewards]
    if paid[0] is not None or run.absorbing_reward_function() is not None:
        # The reward's own termination, never the run's absorbing state's in its place.
        intentions = jnp.arange(run.num_intentions)
        values = [reward.termination(intentions) for reward in rewards]
        chosen.parameters = [
            {**reward.parameters, product.PRICE: price}
            for reward, price in zip(rewards, values, strict=True)
        ]
        chosen.absorbing = priced_absorbing_reward
        chosen.details["termination"] = values
    chosen.details["reward"] = {
        "source": "saved",
        "directory": product.directory(run.run_dir),
        "saved_reward": description["saved_reward"],
        "form": rewards[0].form,
        "saved_form": description["form"],
        "termination_price": (description["termination"] or {}).get("price"),
        "recipe": description["recipe"],
        "refit": description["refit"],
        "networks": description["networks"],
    }


# Details of the reward checked with one entry per seed; the others are alike for every seed.
PER_SEED_DETAILS = ("consolidation", "across_seeds", "absorbing_price", "termination")


def _merge_opened(args: argparse.Namespace):
    """``(args, run, seeds, Chosen, draws)`` of ``--merge``: its checks' draws joined over
    their seeds (:func:`~emgail_jax.reward.check.joined_seeds`), each check verified to
    be one seed's of this run with these options (its recorded ``check``,
    :func:`check_identity`)."""
    from emgail_jax.host import records
    from emgail_jax.host.run_spec import RunError

    args, run = _run_opened(args)
    expected = records.to_json_value(check_identity(args, run))
    rl_seeds = list(range(args.rl_seed, args.rl_seed + args.draws))
    parts = {}
    for path in args.merge:
        part = _read_check(path)
        recorded = part.get("check")
        options = recorded.get("options") if isinstance(recorded, dict) else None
        if not isinstance(options, dict) or options.get("seed") is None:
            raise RunError(f"'{path}' is no check of one seed: write each with --seed S")
        seed = recorded["options"]["seed"]
        other = {**recorded, "options": {**recorded["options"], "seed": None}}
        if other != expected:
            differ = sorted(_differing(other["options"], expected["options"]))
            if other["iteration"] != expected["iteration"]:
                differ.append("the networks' iteration")
            raise RunError(
                f"'{path}' was checked otherwise ({', '.join(differ)}): give the options "
                "its --seed checks were run with"
            )
        if part.get("rl_seeds", [part.get("rl_seed")]) != rl_seeds:
            raise RunError(f"'{path}' trained other draws: give the --draws and --rl-seed it had")
        if seed in parts:
            raise RunError(f"seed {seed} is checked twice: give each seed's check once")
        parts[seed] = part
    ordered = [parts[seed] for seed in sorted(parts)]
    try:
        joined = [
            check.joined_seeds([part.get("draws", [part])[d] for part in ordered])
            for d in range(args.draws)
        ]
    except ValueError as error:
        raise RunError(f"--merge: {error}") from None
    details = {name: ordered[0].get(name) for name in ("reward", *RETIRED_DETAILS, "saved_reward")}
    for name in PER_SEED_DETAILS:
        entries = [part.get(name) for part in ordered]
        details[name] = None if None in entries else [e for entry in entries for e in entry]
    if details["saved_reward"] is None:
        del details["saved_reward"]
    seeds = [run.seed_index(seed) for seed in sorted(parts)]
    return args, run, seeds, Chosen(details=details), joined


def _read_check(path: str) -> dict:
    import json

    from emgail_jax.host.run_spec import RunError

    try:
        with open(path) as f:
            found = json.load(f)
    except (OSError, ValueError) as error:
        raise RunError(f"--merge: cannot read '{path}' ({error})") from None
    if not isinstance(found, dict):
        raise RunError(f"--merge: '{path}' is not a reoptimize check")
    return found


def _differing(given: dict, expected: dict) -> list[str]:
    """The options, spelled as on the command line, in which two checks' recorded options
    differ."""
    names = sorted(set(given) | set(expected))
    spelled = lambda n: f"--set {n}" if n in recipe.CHECK_SETTINGS else "--" + n.replace("_", "-")
    return [spelled(n) for n in names if given.get(n) != expected.get(n)]


def priced_at_random_actions(run, seeds: list[int], chosen: Chosen) -> None:
    """``chosen`` with its absorbing state paid, seed by seed, what uniformly random actions
    earn per step under its reward (``--set absorbing_reward=random``)."""
    import jax.numpy as jnp
    import numpy as np

    from emgail_jax.host.run_spec import RunError
    from emgail_jax.reward.refit import priced_absorbing_reward, random_actions_reward

    learned_absorbing = chosen.absorbing or run.absorbing_reward_function()
    if learned_absorbing is None:
        raise RunError(
            "absorbing_reward prices an absorbing state, and this reward has none: refit it "
            "with consolidate_absorbing=true, or check a run trained with absorbing_state"
        )
    function = chosen.function or run.reward_function()
    parameters = chosen.parameters or [run.reward_parameters(seed) for seed in seeds]
    intentions = jnp.arange(run.num_intentions)
    chosen.parameters, chosen.details["absorbing_price"] = [], []
    for seed_parameters in parameters:
        price = random_actions_reward(run, seed_parameters, function)
        chosen.parameters.append({**seed_parameters, "absorbing_price": price})
        learned = np.asarray(learned_absorbing(seed_parameters, intentions))
        chosen.details["absorbing_price"].append({"learned": learned, "random_actions": price})
    chosen.absorbing = priced_absorbing_reward


def main(argv=None) -> int:
    from emgail_jax.host.run_spec import read_summary

    given = parse_args(argv)  # refuses a setting it does not take before reading the run
    jax_setup.setup(host_devices=1)

    import envs
    from emgail_jax.host import run_lock
    from emgail_jax.host.checkpoints import CheckpointError
    from emgail_jax.host.demonstration_files import DemonstrationError
    from emgail_jax.host.run_spec import RunError

    with contextlib.ExitStack() as held:
        try:
            held.enter_context(run_lock.reading(given.run_dir))  # no live run writes it
            args = parse_args(argv, read_summary(given.run_dir).get("env"))
            opened = _merge_opened(args) if args.merge else (*_opened(args), None)
        except (RunError, CheckpointError, envs.EnvError, DemonstrationError) as error:
            print(f"error: {error}", file=sys.stderr)
            return 2
        return _reoptimized(*opened)


def _variant_references(args: argparse.Namespace, run, budget, cache: str) -> dict | None:
    """With ``--env-set``: the variant's own references (its best true-reward agents, ERD's 0),
    set as ``run``'s expert returns; None otherwise."""
    if not args.env_set:
        return None
    draws_count = args.reference_draws
    reference = baseline.variant_reference(run, budget, cache, draws_count, not args.quiet)
    run.problem = check.with_expert_returns(run.problem, reference["returns"])
    return {
        "dynamics": args.env_set,
        "reference_draws": draws_count,
        "reference_draw": reference["draw"],
        "reference_returns": reference["draws_returns"],
        "original_experts_erd": reference["original_experts_erd"],
        "reference_meets_bar": reference["meets_bar"],
    }


def _trained_draws(args: argparse.Namespace, run, seeds, chosen: Chosen, path: str) -> list:
    """Every draw of fresh agents on the chosen reward, those finished before read back."""
    finished = progress.FinishedDraws(path, check_identity(args, run))
    trained = []
    for rl_seed in range(args.rl_seed, args.rl_seed + args.draws):
        draw = finished.read(rl_seed, not args.quiet)
        if draw is None:
            draw = check.reoptimize(
                run,
                seeds,
                budget_of(args, run),
                progress=not args.quiet,
                parameters=chosen.parameters,
                reward_function=chosen.function,
                absorbing_function=chosen.absorbing,
                rl_seed=rl_seed,
                partial=finished.partial(rl_seed),
            )
            finished.write(rl_seed, draw)
        trained.append(draw)
    return trained


def _reoptimized(
    args: argparse.Namespace, run, seeds: list[int], chosen: Chosen, merged: list | None
) -> int:
    """The rest of :func:`main`: the fresh agents trained (or ``merged``'s draws taken),
    scored and written."""
    from emgail_jax.host import records

    budget = budget_of(args, run)
    cache = args.cache or baseline.default_cache()
    variant = _variant_references(args, run, budget, cache)
    path = args.out or os.path.join(args.run_dir, default_name(args))
    every = merged or _trained_draws(args, run, seeds, chosen, path)
    result = every[0] if args.draws == 1 else draws.chosen_by_learned_reward(every, args.keep_draw)
    result.update(draws.single_draws(every))
    kept = [q for row in result["per_seed"] for q in row["success"]]
    result["kept_success_rate"] = check.success_summary(kept)["success_rate"]
    result["do_nothing"] = check.do_nothing(run.problem)
    # What the fresh agents were paid: an AIRL run's policies trained on f - log pi, its
    # fresh agents on g_i(s).
    airl = run.config.method.m_step.form.airl
    result["reward_form"] = "airl-g" if airl else run.algorithm.reward_form
    result.update(chosen.details)
    if variant is not None:
        variant["joint_policies"] = check.joint_policies(run, seeds, result["iteration"])
    result["variant"] = variant
    result["check"] = check_identity(args, run)  # what --merge matches its parts by
    result["baseline"] = _baseline(args, run, budget, cache) if args.baseline else None
    records.write_json(path, result)
    progress.FinishedDraws(path, {}).remove()
    print_result(run, records.to_json_value(result))
    print(f"wrote {path}")
    return 0


def _baseline(args: argparse.Namespace, run, budget, cache: str) -> dict:
    """The true-reward baseline's draws (how far the search varies on the true reward): the
    one kept by true return, every draw's ERD and its lowest beside it."""
    baselines = [
        baseline.true_reward_baseline(run, budget, cache, not args.quiet, rl_seed=rl_seed)
        for rl_seed in range(args.rl_seed, args.rl_seed + args.draws)
    ]
    kept = baselines[0] if args.draws == 1 else draws.best_baseline(baselines)
    return {**kept, **draws.baseline_draws(baselines, kept)}


# The options a check's draws depend on, beside its settings (not how many draws, nor where
# and how it reports).
IDENTITY_FLAGS = ("run_dir", "seed", "rl_seed", "snapshot", "iterations", "refit", "env_set")


def check_identity(args: argparse.Namespace, run) -> dict:
    """What a check's draws depend on: its options and settings and the iteration of the
    networks checked."""
    names = (*IDENTITY_FLAGS, *recipe.CHECK_SETTINGS)
    options = {name: getattr(args, name) for name in names} | RETIRED_OPTIONS
    # Left out when not given, as before the setting existed, so that those checks resume.
    if options["value_target_scaling"] is None:
        del options["value_target_scaling"]
    identity = {"iteration": run.snapshot or run.iteration}
    # A check of the run's own reward or of a refit made here reads as before the saved one
    # could be checked; a saved one is told by the refit it was written from and its reading.
    if options.pop("reward") == "saved":
        from emgail_jax.reward import product

        description = product.read(args.run_dir)
        options["reward"] = "saved"
        price = (description["termination"] or {}).get("price")
        identity["saved_reward"] = [description["saved_reward"], description["form"], price]
    return {"options": dict(sorted(options.items())), **identity}


def default_name(args) -> str:
    """``reoptimize[-seed-S][-rl-R][-draws-N][-it-N][-gamma-G][-lambda-L][-[no-]scaled-values]
    [-snapshot-ITER][-consolidated-STEPS[-penalty-W][-fresh][-noise-S][-batch-M]...]
    [-across-seeds][-FORM][-env-...].json``: a check of one seed, or at another budget, does
    not overwrite the check of every seed at the env's budget."""
    parts = ["reoptimize"]
    if args.seed is not None:
        parts.append(f"seed-{args.seed}")
    if args.rl_seed:
        parts.append(f"rl-{args.rl_seed}")
    if args.draws > 1:
        parts.append(f"draws-{args.draws}")
        if args.keep_draw != "most":
            parts.append(f"keep-{args.keep_draw}")
    if args.iterations is not None:
        parts.append(f"it-{args.iterations}")
    if args.gamma is not None:
        parts.append(f"gamma-{args.gamma:g}")
    if args.gae_lambda is not None:
        parts.append(f"lambda-{args.gae_lambda:g}")
    if args.value_target_scaling is not None:
        parts.append("scaled-values" if args.value_target_scaling else "no-scaled-values")
    parts += reward_parts(args)
    if args.env_set:
        parts.append("env-" + "-".join(args.env_set))
    return "-".join(parts) + ".json"


def reward_parts(args) -> list[str]:
    """The parts of :func:`default_name` that say which reward was checked: the snapshot, the
    refit or the saved reward, the reward form."""
    parts = recipe.refit_parts(args)
    if args.reward == "saved":
        parts.append("saved")
    if args.across_seeds:
        parts.append("across-seeds")
    if args.reward_form:
        parts.append(args.reward_form)
    if args.absorbing_reward == "random":
        parts.append("absorbing-random")
    return parts


if __name__ == "__main__":
    sys.exit(main())
