"""Refit a run's rewards against every snapshot's policy, and save them for reoptimize and load.

Each seed's discriminator is fitted again against the samples of every policy the run kept a
snapshot of (:mod:`emgail_jax.reward.refit`).

    python -m emgail_jax.refit RUN_DIR [--seed S] [--snapshot ITER] [--set KEY=VALUE ...]
        [--overwrite] [--quiet]

The recipe is ``reoptimize --refit``'s for the run's env (:mod:`emgail_jax.reward.recipe`), any
``--set`` given replacing its part. Every seed's refit is saved under ``RUN_DIR/rewards/NAME``,
where ``reoptimize RUN_DIR --refit`` (with the same ``--set``) finds it; a refit saved before is
reused, not made again. The reward to take away is written beside it, ``RUN_DIR/reward/``
(:mod:`emgail_jax.reward.product`): the parameters and ``reward.json``, how to read them, which
``load_reward(RUN_DIR)`` returns.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import shutil
import sys
import time

from emgail_jax.host import jax_setup
from emgail_jax.host.command_line import ArgumentParser, add_run_and_seed
from emgail_jax.reward import recipe

# The refit's settings, and how the reward it writes is read (``RUN_DIR/reward/``).
SETTINGS = recipe.SAVED_SETTINGS


def argument_parser() -> argparse.ArgumentParser:
    parser = ArgumentParser(prog="python -m emgail_jax.refit", description=__doc__.split("\n")[0])
    add_run_and_seed(parser)
    parser.add_argument(
        "--snapshot",
        type=int,
        default=None,
        metavar="ITER",
        help="refit from this snapshot's networks (default: the run's final ones)",
    )
    recipe.add_settings_option(parser, SETTINGS, "a setting of the refit in place of the recipe's")
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="delete the refit of that name saved before, every seed's, and refit anew "
        "(default: reuse it)",
    )
    parser.add_argument(
        "--quiet", action="store_true", help="no progress, only what was written and its time"
    )
    return parser


def parse_args(argv=None, env: str | None = None) -> argparse.Namespace:
    """The command line, its ``--set`` settings typed and checked, on ``--refit``'s recipe for
    ``env``; exits 2 with one line on a setting it does not take."""
    args = recipe.parsed_command_line(argument_parser(), argv, SETTINGS)
    return recipe.with_refit_recipe(argparse.Namespace(**vars(args), refit=True), env)


def main(argv=None) -> int:
    parse_args(argv)  # refuses a setting it does not take before reading the run
    jax_setup.setup(host_devices=1)

    import envs
    from emgail_jax.host import run_lock
    from emgail_jax.host.checkpoints import CheckpointError
    from emgail_jax.host.demonstration_files import DemonstrationError
    from emgail_jax.host.run_spec import RunError, read_summary

    given = argument_parser().parse_args(argv)
    started = time.monotonic()
    with contextlib.ExitStack() as held:
        try:
            held.enter_context(run_lock.reading(given.run_dir))  # no live run writes it
            args = parse_args(argv, read_summary(given.run_dir).get("env"))
            name, written = refitted(args)
        except (RunError, CheckpointError, envs.EnvError, DemonstrationError) as error:
            print(f"error: {error}", file=sys.stderr)
            return 2
    for directory in written:
        for file in sorted(os.listdir(directory)):
            print(os.path.join(directory, file))
    print(
        f"wrote {written[-1]} in {time.monotonic() - started:.0f} s: load_reward("
        f"{args.run_dir!r}, seed=S) returns it (the refit kept as refit={name!r})"
    )
    return 0


def refitted(args: argparse.Namespace) -> tuple[str, list[str]]:
    """Every seed asked refitted (or its refit saved before reused) and saved, and the reward
    to take away written from every seed refitted so: the refit's name and the two
    directories (``RUN/rewards/NAME``, ``RUN/reward``)."""
    from emgail_jax.host.run_spec import RunError
    from emgail_jax.host.saved_run import SavedRun
    from emgail_jax.reward import product, saved

    if not args.consolidate:
        raise RunError("--set consolidate=0 refits nothing: give it a number of steps")
    recipe.check_refit_settings(args)
    run = SavedRun.open(args.run_dir, snapshot=args.snapshot)
    if run.config.method.m_step.form.airl:
        raise RunError("an AIRL run's reward is g_i(s), not refitted as a discriminator")
    seeds = list(range(run.spec.seeds)) if args.seed is None else [run.seed_index(args.seed)]
    name, refit = "-".join(recipe.refit_parts(args)), recipe.refit_of(args)
    directory = os.path.join(saved.rewards_directory(args.run_dir), name)
    if args.overwrite:
        shutil.rmtree(directory, ignore_errors=True)
    run = saved.run_to_refit(run, refit)
    reading = reading_of(args, run)
    saved.saved_or_refitted(run, seeds, refit, name, progress=not args.quiet)
    settings = {key: getattr(args, key) for key in SETTINGS}
    return name, [directory, product.write(run, name, reading, settings)]


def reading_of(args: argparse.Namespace, run):
    """How the refit is read (:class:`~emgail_jax.reward.product.Reading`): the recipe's
    reward form (:func:`~emgail_jax.reward.recipe.refit_reward_form`; the run's own if none),
    and with absorbing states the price of a termination (the recipe's, else learned).

    Raises:
      RunError: a termination price asked of a refit without absorbing states.
    """
    import envs
    from emgail_jax.host.run_spec import RunError
    from emgail_jax.reward import product

    terminates = envs.env_class(run.spec.env).terminates
    form = recipe.refit_reward_form(args, terminates) or run.algorithm.reward_form
    if args.absorbing_reward and not args.consolidate_absorbing:
        raise RunError(
            "absorbing_reward prices an absorbing state: give consolidate_absorbing=true"
        )
    price = (args.absorbing_reward or "learned") if args.consolidate_absorbing else None
    return product.Reading(str(form), price)


if __name__ == "__main__":
    sys.exit(main())
