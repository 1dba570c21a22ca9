"""Command line: train EM-GAIL, Info/IntentionGAIL or GAIL on one env for several seeds.

    python -m emgail_jax.run --env driver --algo emgail --seeds 4 --iterations 400 --out DIR
    python -m emgail_jax.run --resume DIR [--iterations TOTAL]

writes ``DIR/summary.json``, ``DIR/metrics.csv`` (one row per iteration and seed), TensorBoard
events under ``DIR/tensorboard`` and orbax checkpoints under ``DIR/checkpoints`` (README,
"Running").
``--iterations`` is the run's total: a resumed run continues from its last checkpoint up to it.
SIGINT or SIGTERM stops a run after the iteration chunk in progress, checkpoints it and marks
``summary.json`` ``"status": "interrupted"``; ``--resume`` continues it exactly.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import os
import sys
import traceback

from emgail_jax.host import jax_setup, records, stopping
from emgail_jax.host.command_line import ArgumentParser
from emgail_jax.host.run_directory import default_output, prepare_output, writing
from emgail_jax.host.run_spec import (
    DEFAULT_RANDOM_EPISODES,
    RunError,
    RunSpec,
    read_summary,
    stored_seeds,
)
from emgail_jax.host.summary_table import print_summary

DEFAULT_SEEDS = 4


def parse_args(argv=None) -> argparse.Namespace:
    return _parser()[0].parse_args(argv)


def run_options() -> tuple[str, ...]:
    """The options that define a run (their ``dest``): a resumed run takes them from its
    summary.json, and refuses them on its command line."""
    return _parser()[1]


def _parser() -> tuple[argparse.ArgumentParser, tuple[str, ...]]:
    """The command's parser, and the ``dest`` of its run-defining options."""
    from emgail_jax.method.config import (
        INTENTION_INPUTS,
        NAMES,
        PRIORS,
        RESPONSIBILITIES,
        REWARD_RECIPES,
        RunSchedule,
    )

    parser = ArgumentParser(prog="python -m emgail_jax.run", description=__doc__.split("\n")[0])
    defining = parser.add_argument_group(
        "the run's definition (a resumed run takes these from its summary.json)"
    )
    defines_run = []

    def run_option(*flags, **kwargs) -> None:
        defines_run.append(defining.add_argument(*flags, **kwargs).dest)

    run_option("--env", help="env name (default: driver)")
    run_option(
        "--intentions",
        type=_intention_count,
        help="K: learn the env's first K intentions (default: all), or auto: choose K from the "
        "demonstrations (starting from --max-intentions, with the mixture prior)",
    )
    run_option(
        "--max-intentions",
        type=int,
        help="with --intentions auto: the most intentions it may choose (default: the env's all)",
    )
    run_option("--algo", choices=NAMES, help="default: emgail")
    run_option("--seeds", type=int, help=f"seeds in parallel (default {DEFAULT_SEEDS})")
    parser.add_argument("--iterations", type=int, help="total (default 400)")
    parser.add_argument("--out", help="output directory (default: a new runs/ENV-ALGO[-N])")
    parser.add_argument("--resume", metavar="DIR", help="continue the run in DIR")
    run_option(
        "--demos",
        nargs="+",
        metavar="SOURCE",
        help="demonstrations: an .npz file, a Minari dataset (minari:ID or its directory), or "
        "several of them, one intention each (docs/usage.md, Demonstrations format)",
    )
    run_option("--radius", type=float, help="driver: radius of path 2")
    run_option("--seed", type=int, help="first training seed")
    run_option("--demo-seed", type=int, help="driver: demonstration seed")
    run_option("--info-weight", type=float, help="infogail: lambda")
    run_option(
        "--random-episodes",
        type=int,
        help="episodes of random actions that set ERD's random reference "
        f"(default {DEFAULT_RANDOM_EPISODES})",
    )
    run_option(
        "--intention-input",
        choices=INTENTION_INPUTS,
        help="one network head per intention (default) or the intention as a one-hot input",
    )
    run_option(
        "--responsibilities",
        choices=RESPONSIBILITIES,
        help="E-step: the posterior of each pair's whole demonstration (default; centred over "
        "the demonstrations with trajectory-centered), or of each pair alone (the paper's "
        "eq. 18), or the hidden labels (an oracle, for diagnosis)",
    )
    run_option(
        "--prior",
        choices=PRIORS,
        help="E-step prior over the intentions: uniform (default, the paper's) or mixture "
        "weights estimated from the demonstrations (for intentions in unequal shares)",
    )
    run_option(
        "--reseed",
        choices=("on", "off"),
        help="re-seed an intention that holds no demonstration (default on; docs/defaults.md, "
        "reseed)",
    )
    run_option(
        "--rewards",
        choices=REWARD_RECIPES,
        help="how the rewards are trained: the paper's (default), or for-reuse, rewards meant for "
        "a fresh agent to re-optimise (log D, a replay of past samples with noise around them, a "
        "gradient penalty, absorbing states where episodes end early; each one --set away; "
        "docs/defaults.md, run --rewards)",
    )
    run_option(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="any other hyper-parameter by its key (emgail_jax.method.settings), e.g. --set "
        "discriminator_steps=5 --set trpo.cg_damping=0 (repeatable)",
    )
    run_option("--num-envs", type=int, help="envs per intention")
    run_option("--rollout-length", type=int, help="steps per rollout")
    run_option(
        "--eval-every",
        type=int,
        help="evaluation episodes every N iterations and in the last 10 (default 10)",
    )
    run_option("--chunk-size", type=int, help="iterations per call")
    run_option(
        "--seed-batch",
        type=int,
        help="seeds vmapped together on a device (default: 1 on CPU, all on GPU/TPU)",
    )
    parser.add_argument(
        "--checkpoint-every",
        type=int,
        help=f"iterations between checkpoints (default {RunSchedule.checkpoint_every})",
    )
    parser.add_argument(
        "--snapshot-every",
        type=int,
        help="iterations between snapshots of the learned networks, all kept (default "
        f"{RunSchedule.snapshot_every}; 0: none)",
    )
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="replace an earlier run, and the checks and refitted rewards made from it",
    )
    parser.add_argument(
        "--coordinator",
        metavar="HOST:PORT",
        help="a run over several processes or hosts: process 0's address (jax.distributed)",
    )
    parser.add_argument("--num-processes", type=int, help="with --coordinator")
    parser.add_argument("--process-id", type=int, help="with --coordinator")
    parser.add_argument(
        "--wandb",
        metavar="PROJECT",
        help="also log the metrics, config and final summary to this Weights & Biases project "
        "(needs the extra: pip install 'emgail-jax[wandb]'; WANDB_MODE=offline keeps it local)",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bar or table")
    return parser, tuple(defines_run)


def _intention_count(text: str) -> int | str:
    if text == "auto":
        return text
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"a number or auto, not '{text}'") from None


# The options that are settings of the config under their own name (their ``dest`` is the
# flat key); the cadence ones may change on resume.
_CADENCE = ("iterations", "checkpoint_every", "snapshot_every")
_SETTING_OPTIONS = (
    *_CADENCE,
    *("algo", "info_weight", "intention_input", "responsibilities", "num_envs"),
    *("rollout_length", "eval_every", "chunk_size", "seed_batch"),
)


def spec_from_args(args: argparse.Namespace) -> RunSpec:
    """The run the command line asks for: a resumed run's from its summary.json, with the
    cadence given; a new run's from its options, its reward recipe and its ``--set`` settings,
    its config built from all of them at once. A setting refused is named as the option or
    the ``--set`` that gave it."""
    from emgail_jax.method.config import SettingError

    options = _config_options(args)
    try:
        if args.resume is not None:
            return _resumed_spec(args, options)
        return _new_spec(args, options)
    except ValueError as error:
        # The settings refuse with a ValueError or a SettingError; a RunError, an EnvError or a
        # DemonstrationError (its subclasses) already says what to change.
        if type(error) not in (ValueError, SettingError):
            raise
        option = isinstance(error, SettingError) and error.key in options
        if option and options[error.key] == error.value:
            raise RunError(error.naming(f"--{error.key.replace('_', '-')}")) from None
        if not args.set:
            raise RunError(str(error)) from None
        recipe = f" (with --rewards {args.rewards})" if args.rewards not in (None, "paper") else ""
        raise RunError(f"--set{recipe}: {error}") from None


def _config_options(args: argparse.Namespace) -> dict:
    """The config's settings the options give, by flat key (an option not given: absent),
    once the options that cannot go together are refused."""
    if args.resume is not None:
        _refuse_run_options(args)
        return {key: getattr(args, key) for key in _CADENCE if getattr(args, key) is not None}
    choosing = args.intentions == "auto"
    _refuse_counts(args, choosing)
    options = {key: getattr(args, key) for key in _SETTING_OPTIONS}
    options["prior"] = "mixture" if choosing else args.prior
    options["choose_intentions"] = choosing or None
    options["reseed"] = None if args.reseed is None else args.reseed == "on"
    return {key: value for key, value in options.items() if value is not None}


def _refuse_run_options(args: argparse.Namespace) -> None:
    """A resumed run takes its own settings: only the cadence may be given."""
    given = [f"--{name.replace('_', '-')}" for name in run_options() if getattr(args, name)]
    if given or args.out or args.overwrite:
        dropped = ", ".join(given) or "--out/--overwrite"
        raise RunError(
            f"--resume continues a run with its own settings; drop {dropped} "
            "(only --iterations, the new total, and the --checkpoint-every and --snapshot-every "
            "cadence may be given)"
        )


def _refuse_counts(args: argparse.Namespace, choosing: bool) -> None:
    """Refuses the run's own counts out of range and options that do not go together (the
    config checks its hyper-parameters itself)."""
    from emgail_jax.method.config import AlgorithmName

    for name in ("seeds", "random_episodes", "intentions", "max_intentions"):
        value = getattr(args, name)
        if value is not None and value != "auto" and value < 1:
            raise RunError(f"--{name.replace('_', '-')} must be at least 1; got {value}")
    if args.radius is not None and (args.env or "driver") != "driver":
        raise RunError("--radius applies to the driver env only")
    if args.max_intentions is not None and not choosing:
        raise RunError("--max-intentions goes with --intentions auto")
    if choosing and args.prior == "uniform":
        raise RunError("--intentions auto weighs the intentions: drop --prior uniform")
    if choosing and args.algo == AlgorithmName.GAIL:
        raise RunError("--intentions auto needs a posterior: use --algo emgail or infogail")


def _resumed_spec(args: argparse.Namespace, cadence: dict) -> RunSpec:
    """The spec of the run ``--resume`` continues, with the ``cadence`` settings given."""
    summary = read_summary(args.resume)
    spec = RunSpec.from_summary(summary)
    return dataclasses.replace(spec, config=spec.config.with_values(**cadence))


def _new_spec(args: argparse.Namespace, options: dict) -> RunSpec:
    """The spec of a new run: the ``options``' settings, then the reward recipe's for the env,
    then ``--set``'s, the config built from them at once."""
    import envs
    from emgail_jax.host.demonstration_sources import canonical
    from emgail_jax.method import settings
    from emgail_jax.method.config import RewardRecipe, RunConfig

    env = args.env or "driver"
    demo_sources = tuple(map(canonical, args.demos or ()))
    # K learned: the env's unless given; auto starts from --max-intentions or all the env has.
    kind = envs.env_class(env)
    intentions = args.intentions
    if intentions == "auto":
        intentions = args.max_intentions or len(kind.intention_names)
    recipe = RewardRecipe(args.rewards or RewardRecipe.PAPER)
    chosen = settings.parsed(args.set, like=RunConfig())
    config = RunConfig().with_values(
        **{**options, **recipe.settings(terminates=kind.terminates), **chosen}
    )
    return RunSpec(
        env=env,
        intentions=intentions,
        env_options={} if args.radius is None else {"radius": args.radius},
        algo=config.method.algo.value,
        seeds=args.seeds or DEFAULT_SEEDS,
        first_seed=args.seed or 0,
        demo_sources=demo_sources,
        demo_seed=args.demo_seed or 0,
        config=config,
        random_episodes=args.random_episodes or DEFAULT_RANDOM_EPISODES,
    )


def _command(
    args: argparse.Namespace,
    signals: stopping.Signals,
    held: contextlib.ExitStack,
    locked: bool,
) -> tuple[str, dict]:
    """The run the command line asks for, trained: ``(run directory, summary)``; ``held``
    holds the run directory's lock (taken here unless ``locked`` already)."""
    # JAX and what imports it come in only here, once the lock is held (issue 30: a refused
    # command ends before JAX starts).
    import jax

    from emgail_jax.host.training_run import summary_header, train

    primary = jax.process_index() == 0
    with held:
        out, spec, problem = _open_run(args, held, locked, primary)
        wandb_run = None
        if args.wandb is not None and primary:
            header = summary_header(spec, problem, spec.config.resolved(problem.env))
            name = os.path.basename(os.path.abspath(out))
            wandb_run = records.start_wandb(args.wandb, name, header)
        if problem.demos.expert_returns is None:
            print("notice: the demonstrations carry no expert_returns, so ERD is reported as null")
        if problem.demos.intentions is None:
            print("notice: the demonstrations carry no intention labels, so accuracy is null")
        summary = train(
            spec,
            problem,
            out,
            resume=args.resume is not None,
            progress=not args.quiet,
            signals=signals,
            wandb_run=wandb_run,
        )
    if wandb_run is not None:
        records.finish_wandb(wandb_run, summary)
    return out, summary


def _open_run(args: argparse.Namespace, held: contextlib.ExitStack, locked: bool, primary: bool):
    """``(run directory, spec, problem)`` of the run asked for, its directory locked and ready
    to write (a new run's emptied, a resumed one's checked for a checkpoint); W&B checked."""
    from emgail_jax.host.checkpoints import CheckpointError, latest_iteration
    from emgail_jax.host.problem import problem_of
    from emgail_jax.host.seed_runner import seed_sharding

    out = args.resume or args.out
    # Before anything reads or writes the directory: a live run keeps it.
    if primary and out is not None and not locked:
        held.enter_context(writing(out, new=args.resume is None))
    spec = spec_from_args(args)
    seed_sharding(spec.seeds)  # the seeds fit the processes, before anything compiles
    if out is None:
        out = default_output(spec.env, spec.algo)
        if primary:
            held.enter_context(writing(out, new=True))
    # A run killed before its first checkpoint restarts: its summary holds its spec.
    unfinished = args.resume is not None and read_summary(out).get("status") == "running"
    if args.resume is not None and latest_iteration(out) is None and not unfinished:
        raise CheckpointError(f"'{out}' holds no checkpoint to resume from")
    problem = problem_of(spec)
    if spec.config.method.e_step.responsibilities.oracle and problem.demos.intentions is None:
        raise RunError("--responsibilities labels needs demonstrations with hidden labels")
    if args.wandb is not None and primary:
        records.require_wandb()
    if args.resume is None:
        if primary:
            prepare_output(out, args.overwrite)
    else:
        done = latest_iteration(out)
        start = "the start (it stopped before its first checkpoint)" if done is None else done
        print(f"resuming '{out}' from iteration {start}")
    return out, spec, problem


def main(argv=None) -> int:
    args = parse_args(argv)
    try:
        distributed = jax_setup.Distributed.from_options(
            args.coordinator, args.num_processes, args.process_id
        )
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    if distributed is not None:
        # Every process refuses alike, before it waits for the others.
        seeds = args.seeds or DEFAULT_SEEDS if args.resume is None else stored_seeds(args.resume)
        error = jax_setup.seed_share_error(seeds, distributed.num_processes)
        if error:
            print(f"error: {error}", file=sys.stderr)
            return 2
    held = contextlib.ExitStack()
    locked = distributed is None and bool(args.resume or args.out)
    if locked:
        # The lock at once, before JAX starts (a run of several processes takes it later, so
        # that the others hear of a refusal).
        try:
            held.enter_context(writing(args.resume or args.out, new=args.resume is None))
        except RunError as error:
            print(f"error: {error}", file=sys.stderr)
            return 2
        except OSError as error:
            print(_write_error(error), file=sys.stderr)
            return 2
    with held, stopping.Signals() as signals:  # from here on a signal ends a run in seconds
        jax_setup.setup(distributed=distributed)
        signals.install()  # jax.distributed takes SIGTERM for its preemption notices
        code = _main(args, signals, distributed is not None, held, locked)
    if distributed is not None:
        jax_setup.leave(code)
    return code


def _main(
    args: argparse.Namespace,
    signals: stopping.Signals,
    several: bool,
    held: contextlib.ExitStack,
    locked: bool,
) -> int:
    """The command, its errors as one line and exit code 2; in a run of several processes,
    a failure is posted for the others (:func:`jax_setup.report_failure`), which end too."""
    import jax  # here, not above: the command has the lock by now (issue 30)

    import envs
    from emgail_jax.host.checkpoints import CheckpointError
    from emgail_jax.host.demonstration_files import DemonstrationError

    refusals = (envs.EnvError, DemonstrationError, RunError, CheckpointError, records.WandbError)
    try:
        out, summary = _command(args, signals, held, locked)
    except refusals as error:
        return _failed(f"error: {error}", 2)
    except OSError as error:  # the output cannot be created or written (permissions, full disk)
        return _failed(_write_error(error), 2)
    except Exception as error:
        if not several:
            raise
        first = str(error).strip().splitlines()[0] if str(error).strip() else ""
        gone = jax_setup.peers_gone()
        if gone:  # a collective broke off: say why, not where
            return _failed(f"error: process {gone[0]} of the run is gone ({first[:200]})", 1)
        traceback.print_exc()
        return _failed(f"error: {type(error).__name__}: {first[:300]}", 1)
    if jax.process_index() == 0:
        if not args.quiet:
            print_summary(summary)
        print(f"wrote {os.path.join(out, 'summary.json')} ({summary['status']})")
    return stopping.INTERRUPTED if summary["status"] == "interrupted" else 0


def _write_error(error: OSError) -> str:
    where = f" ('{error.filename}')" if error.filename else ""
    return (
        f"error: {error.strerror or error}{where}: the run's outputs could not be written; "
        "check that --out is a writable directory with room on its disk (--resume then "
        "continues from the last checkpoint)"
    )


def _failed(line: str, code: int) -> int:
    sys.stderr.write(f"{line}\n")  # one write: other processes' logs may write at once
    jax_setup.report_failure(line.removeprefix("error: "))
    return code


if __name__ == "__main__":
    sys.exit(main())
