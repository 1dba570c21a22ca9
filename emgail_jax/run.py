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
import itertools
import os
import shutil
import signal
import sys
import traceback

import numpy as np

from emgail_jax.host import jax_setup, run_lock, stopping
from emgail_jax.host.run_spec import (
    DEFAULT_RANDOM_EPISODES,
    RunError,
    RunSpec,
    read_summary,
    stored_sources,
)

OUTPUTS = ("summary.json", "metrics.csv", "tensorboard", "checkpoints", "snapshots")
DEFAULT_CHECKPOINT_EVERY = 50
DEFAULT_SNAPSHOT_EVERY = 50
DEFAULT_SEEDS = 4


def parse_args(argv=None) -> argparse.Namespace:
    from emgail_jax.method.algorithms import NAMES
    from emgail_jax.method.config import INTENTION_INPUTS, PRIORS, RESPONSIBILITIES

    parser = argparse.ArgumentParser(
        prog="python -m emgail_jax.run", description=__doc__.split("\n")[0]
    )
    parser.add_argument("--env", default=None, help="env name (default: driver)")
    parser.add_argument(
        "--intentions",
        type=_intention_count,
        default=None,
        help="K: learn the env's first K intentions (default: all), or auto: choose K from the "
        "demonstrations (starting from --max-intentions, with the mixture prior)",
    )
    parser.add_argument(
        "--max-intentions",
        type=int,
        default=None,
        help="with --intentions auto: the most intentions it may choose (default: the env's all)",
    )
    parser.add_argument("--algo", default=None, choices=NAMES, help="default: emgail")
    parser.add_argument(
        "--seeds", type=int, default=None, help=f"seeds in parallel (default {DEFAULT_SEEDS})"
    )
    parser.add_argument("--iterations", type=int, default=None, help="total (default 400)")
    parser.add_argument(
        "--out", default=None, help="output directory (default: a new runs/ENV-ALGO[-N])"
    )
    parser.add_argument("--resume", default=None, metavar="DIR", help="continue the run in DIR")
    parser.add_argument(
        "--demos",
        nargs="+",
        default=None,
        metavar="SOURCE",
        help="demonstrations: an .npz file, a Minari dataset (minari:ID or its directory), or "
        "several of them, one intention each (README, Demonstrations format)",
    )
    parser.add_argument("--radius", type=float, default=None, help="driver: radius of path 2")
    parser.add_argument("--seed", type=int, default=None, help="first training seed")
    parser.add_argument("--demo-seed", type=int, default=None, help="driver: demonstration seed")
    parser.add_argument("--info-weight", type=float, default=None, help="infogail: lambda")
    parser.add_argument(
        "--random-episodes",
        type=int,
        default=None,
        help="episodes of random actions that set ERD's random reference "
        f"(default {DEFAULT_RANDOM_EPISODES})",
    )
    parser.add_argument(
        "--intention-input",
        default=None,
        choices=INTENTION_INPUTS,
        help="one network head per intention (default) or the intention as a one-hot input",
    )
    parser.add_argument(
        "--responsibilities",
        default=None,
        choices=RESPONSIBILITIES,
        help="E-step: the posterior of each pair's whole demonstration (default; centred over "
        "the demonstrations with trajectory-centered), or of each pair alone (the paper's "
        "eq. 18), or the hidden labels (an oracle, for diagnosis)",
    )
    parser.add_argument(
        "--prior",
        default=None,
        choices=PRIORS,
        help="E-step prior over the intentions: uniform (default, the paper's) or mixture "
        "weights estimated from the demonstrations (for intentions in unequal shares)",
    )
    parser.add_argument(
        "--reseed",
        default=None,
        choices=("on", "off"),
        help="re-seed an intention that holds no demonstration (default on; "
        "docs/no-empty-intention.md)",
    )
    parser.add_argument("--num-envs", type=int, default=None, help="envs per intention")
    parser.add_argument("--rollout-length", type=int, default=None, help="steps per rollout")
    parser.add_argument(
        "--eval-every",
        type=int,
        default=None,
        help="evaluation episodes every N iterations and in the last 10 (default 10)",
    )
    parser.add_argument("--chunk-size", type=int, default=None, help="iterations per call")
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        dest="set",
        help="any other hyper-parameter of emgail_jax.method.config (its flat key), e.g. --set "
        "discriminator_steps=5 --set trpo.cg_damping=0 (repeatable)",
    )
    parser.add_argument(
        "--seed-batch",
        type=int,
        default=None,
        help="seeds vmapped together on a device (default: 1 on CPU, all on GPU/TPU)",
    )
    parser.add_argument(
        "--checkpoint-every",
        type=int,
        default=None,
        help=f"iterations between checkpoints (default {DEFAULT_CHECKPOINT_EVERY})",
    )
    parser.add_argument(
        "--snapshot-every",
        type=int,
        default=None,
        help="iterations between snapshots of the learned networks, all kept (default "
        f"{DEFAULT_SNAPSHOT_EVERY}; 0: none)",
    )
    parser.add_argument("--overwrite", action="store_true", help="replace an earlier run")
    parser.add_argument(
        "--coordinator",
        default=None,
        metavar="HOST:PORT",
        help="a run over several processes or hosts: process 0's address (jax.distributed)",
    )
    parser.add_argument("--num-processes", type=int, default=None, help="with --coordinator")
    parser.add_argument("--process-id", type=int, default=None, help="with --coordinator")
    parser.add_argument(
        "--wandb",
        default=None,
        metavar="PROJECT",
        help="also log the metrics, config and final summary to this Weights & Biases project "
        "(needs the extra: pip install 'emgail-jax[wandb]'; WANDB_MODE=offline keeps it local)",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bar or table")
    return parser.parse_args(argv)


def _intention_count(text: str) -> int | str:
    if text == "auto":
        return text
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"a number or auto, not '{text}'") from None


# Options that define a run; a resumed run takes them from its summary.json.
_RUN_OPTIONS = (
    "env",
    "intentions",
    "max_intentions",
    "algo",
    "seeds",
    "demos",
    "radius",
    "seed",
    "demo_seed",
    "info_weight",
    "random_episodes",
    "intention_input",
    "responsibilities",
    "prior",
    "reseed",
    "set",
    "num_envs",
    "rollout_length",
    "eval_every",
    "chunk_size",
    "seed_batch",
)


def spec_from_args(args: argparse.Namespace) -> RunSpec:
    from emgail_jax.host.demonstration_sources import canonical
    from emgail_jax.method.config import RunConfig

    # What may change on resume: the host's schedule of outputs and the total.
    continued = {
        "iterations": args.iterations,
        "checkpoint_every": args.checkpoint_every,
        "snapshot_every": args.snapshot_every,
    }
    if args.resume is not None:
        given = [f"--{name.replace('_', '-')}" for name in _RUN_OPTIONS if getattr(args, name)]
        if given or args.out or args.overwrite:
            dropped = ", ".join(given) or "--out/--overwrite"
            raise RunError(
                f"--resume continues a run with its own settings; drop {dropped} "
                "(only --iterations, the new total, may be given)"
            )
        spec = RunSpec.from_summary(read_summary(args.resume))
        config = _with_options(spec.config, continued)
        return dataclasses.replace(spec, config=config)

    env = args.env or "driver"
    # The run's own counts; the config checks its hyper-parameters itself.
    for name in ("seeds", "random_episodes"):
        value = getattr(args, name)
        if value is not None and value < 1:
            raise RunError(f"--{name.replace('_', '-')} must be at least 1; got {value}")
    intentions, choosing = _learned_intentions(args, env)
    env_options = {}
    if args.radius is not None:
        if env != "driver":
            raise RunError("--radius applies to the driver env only")
        env_options["radius"] = args.radius
    overrides = {
        **continued,
        "algo": args.algo,
        "info_weight": args.info_weight,
        "intention_input": args.intention_input,
        "responsibilities": args.responsibilities,
        "prior": "mixture" if choosing else args.prior,
        "choose_intentions": choosing or None,
        "reseed": None if args.reseed is None else args.reseed == "on",
        "num_envs": args.num_envs,
        "rollout_length": args.rollout_length,
        "eval_every": args.eval_every,
        "chunk_size": args.chunk_size,
        "seed_batch": args.seed_batch,
    }
    config = _with_options(RunConfig(), overrides)
    try:
        config = config.with_settings(args.set)
    except ValueError as error:
        raise RunError(f"--set: {error}") from None
    return RunSpec(
        env=env,
        intentions=intentions,
        env_options=env_options,
        algo=config.method.algo.value,
        seeds=args.seeds or DEFAULT_SEEDS,
        first_seed=args.seed or 0,
        demo_sources=tuple(map(canonical, args.demos or ())),
        demo_seed=args.demo_seed or 0,
        config=config,
        random_episodes=args.random_episodes or DEFAULT_RANDOM_EPISODES,
    )


def _with_options(config, options: dict):
    """``config`` with the settings of the command line's options (None: not given); a value
    out of its domain is named as the option."""
    from emgail_jax.method.config import SettingError

    given = {key: value for key, value in options.items() if value is not None}
    try:
        return config.with_values(**given)
    except SettingError as error:
        raise RunError(error.naming(f"--{error.key.replace('_', '-')}")) from None


def _learned_intentions(args: argparse.Namespace, env: str) -> tuple[int | None, bool]:
    """``(K learned or None for the env's default, whether K is chosen from the data)``; auto
    starts from ``--max-intentions``, by default all the env has."""
    import envs
    from emgail_jax.method.algorithms import AlgorithmName

    choosing = args.intentions == "auto"
    if args.max_intentions is not None and not choosing:
        raise RunError("--max-intentions goes with --intentions auto")
    count = args.intentions
    if choosing:
        count = args.max_intentions
        if count is None:
            count = len(envs.env_class(env).intention_names)
    if count is not None and count < 1:
        raise RunError("--intentions and --max-intentions must be at least 1")
    if choosing and args.prior == "uniform":
        raise RunError("--intentions auto weighs the intentions: drop --prior uniform")
    if choosing and args.algo is not None and not AlgorithmName(args.algo).learns_posterior:
        raise RunError("--intentions auto needs a posterior: use --algo emgail or infogail")
    return count, choosing


def default_output(env: str, algo: str, root: str = "runs") -> str:
    """``runs/ENV-ALGO``, or the first ``runs/ENV-ALGO-N`` not taken: a run without ``--out``
    never touches an earlier one."""
    base = os.path.join(root, f"{env}-{algo}")
    candidates = itertools.chain([base], (f"{base}-{n}" for n in itertools.count(2)))
    return next(path for path in candidates if not os.path.exists(path))


def create_output(out: str) -> None:
    """Creates the directory ``out`` (nothing in it yet)."""
    if os.path.exists(out) and not os.path.isdir(out):
        raise RunError(f"--out '{out}' is a file, not a directory: choose another --out")
    os.makedirs(out, exist_ok=True)
    if not os.access(out, os.W_OK):
        raise RunError(f"cannot write to '{out}': choose a writable --out")


@contextlib.contextmanager
def _writing(out: str, new: bool):
    """Holds ``out``'s run lock, creating the directory first for a ``new`` run; a run that
    ends before writing anything (refused) leaves no directory behind."""
    created = new and not os.path.exists(out)
    if new:
        create_output(out)
    elif not os.path.isdir(out):
        read_summary(out)  # says it is no run directory
    try:
        with run_lock.hold(out):
            yield
    finally:
        if created and os.listdir(out) == [run_lock.LOCK_NAME]:
            shutil.rmtree(out)


def prepare_output(out: str, overwrite: bool) -> None:
    """Creates ``out``; refuses to mix with an earlier run unless ``overwrite``."""
    create_output(out)
    existing = [name for name in OUTPUTS if os.path.exists(os.path.join(out, name))]
    if existing and not overwrite:
        raise RunError(
            f"'{out}' already holds a run ({', '.join(existing)}): "
            "pass --resume to continue it, --overwrite to replace it, or choose another --out"
        )
    for name in existing:
        path = os.path.join(out, name)
        shutil.rmtree(path) if os.path.isdir(path) else os.remove(path)


def train(
    spec: RunSpec,
    problem,
    out: str,
    *,
    resume: bool = False,
    progress: bool = True,
    signals: stopping.Signals | None = None,
    wandb_run=None,
) -> dict:
    """Trains (or, with ``resume``, continues) the run ``spec`` and writes its outputs to ``out``
    (and the metrics to ``wandb_run``, a W&B run of :func:`~emgail_jax.host.records.start_wandb`).

    Returns the summary as written to ``summary.json``; its ``status`` is ``"completed"`` or
    ``"interrupted"`` (a first signal within the chunk loop of ``signals``, the command's).
    In a run of several processes (``jax.distributed``), every process trains its share of the
    seeds and process 0 alone writes the outputs.
    """
    import jax

    from emgail_jax.host import records
    from emgail_jax.host.seed_runner import chunks, evaluation_plan, gather

    config = spec.config.resolved(problem.env)
    runner, parameters = _runner(spec, problem, config)
    summary_path = os.path.join(out, "summary.json")
    writes = jax.process_index() == 0
    write_json = records.write_json if writes else lambda path, data: None
    summary = _summary_header(spec, problem, config)
    summary["devices"] = [str(d) for d in runner.sharding.mesh.devices.flat]
    summary["processes"] = jax.process_count()
    summary["machine"] = records.machine_facts()
    summary["parameters"] = parameters
    timings = {"compile_time_s": 0.0, "train_time_s": 0.0, "iterations": 0}
    if resume:
        timings = read_summary(out).get("timings", timings)
    running = {**summary, "status": "running", "timings": timings}
    if not resume:  # before the first compile: from then on a killed run can be resumed
        write_json(summary_path, running)
    state, history, done = _first_state(runner, out, resume, jax.random.PRNGKey(spec.first_seed))
    if resume:  # once the checkpoint is read: a failed restore leaves the summary as it was
        write_json(summary_path, running)

    # Chunks only group iterations into compiled calls; they do not change the results.
    schedule = config.schedule
    plan = chunks(done, schedule.iterations, schedule.chunk_size)
    signals = signals or stopping.Signals()
    recorder = _ChunkRecorder(
        out,
        config,
        history,
        done,
        resume,
        schedule.checkpoint_every,
        writes,
        signals,
        wandb_run,
        schedule.snapshot_every,
    )
    if plan:
        evaluating = lambda first, length: evaluation_plan(
            first, length, schedule.iterations, schedule.eval_every
        )
        with signals.stoppable(), recorder.open(progress and writes):
            runner.run(state, plan, evaluating, recorder.after_chunk)
        timings = {
            "compile_time_s": timings["compile_time_s"] + runner.timings.compile_s,
            "train_time_s": timings["train_time_s"] + runner.timings.train_s,
            "iterations": timings["iterations"] + runner.timings.iterations,
        }
    iteration, history = recorder.iteration, recorder.history

    summary.update(timings=timings, iterations_done=iteration)
    if iteration < schedule.iterations:
        summary.update(status="interrupted", stopped_by=signal.Signals(recorder.stopped_by).name)
    else:
        summary["status"] = "completed"
    summary["final"] = _final_summary(problem, config, history, timings, spec)
    if config.method.algo.learns_posterior:
        final_state = recorder.host_state if recorder.host_state is not None else gather(state)
        summary["final"].update(_held_final(problem, config, runner.data.demos, final_state))
    if config.method.choose_intentions:
        chosen = _chosen_final(problem, config, runner.data.demos, final_state, history)
        summary["final"].update(chosen)
    write_json(summary_path, summary)
    return records.to_json_value(summary)


@dataclasses.dataclass
class _ChunkRecorder:
    """After each chunk: the metrics to ``metrics.csv``/TensorBoard, the progress bar, a
    checkpoint every ``checkpoint_every`` iterations and at the end (or on a stop request), and
    a snapshot of the learned networks after each chunk that reaches a multiple of
    ``snapshot_every`` and at the end (0: none)."""

    out: str
    config: object  # the resolved RunConfig
    history: dict | None
    iteration: int  # iterations done
    resume: bool
    checkpoint_every: int
    writes: bool  # process 0 of the run
    signals: stopping.Signals
    wandb_run: object = None
    snapshot_every: int = DEFAULT_SNAPSHOT_EVERY

    def __post_init__(self):
        self.last_saved = self.iteration
        self.host_state = None  # every seed's state as last saved, on the host
        self.stopped_by = None  # the signal that stopped the run, in every process

    @contextlib.contextmanager
    def open(self, progress: bool):
        from emgail_jax.host import records
        from emgail_jax.host.progress import ProgressBar

        keep_until = self.iteration if self.resume else None
        self.log = records.MetricsLog(
            self.out, keep_until=keep_until, enabled=self.writes, wandb_run=self.wandb_run
        )
        fields = {"ERD": "-", "acc": "-"}
        self.bar = ProgressBar(
            "training", self.config.schedule.iterations, fields, self.iteration, enabled=progress
        )
        try:
            yield self
        finally:
            self.bar.close()
            self.log.close()

    def after_chunk(self, first: int, length: int, state, metrics: dict) -> bool:
        from emgail_jax.host import checkpoints
        from emgail_jax.host.seed_runner import concat_history, gather

        self.log.write(first, metrics)
        self.history = concat_history(self.history, metrics)
        self.iteration = first + length
        self.bar.update(length, **_progress_fields(self.history))
        self.stopped_by = _agreed_signal(self.signals.requested)
        finished = self.iteration >= self.config.schedule.iterations or self.stopped_by is not None
        if finished or self.iteration - self.last_saved >= self.checkpoint_every:
            host_state = gather(state)  # every process takes part
            if self.writes:
                checkpoints.save(self.out, self.iteration, host_state, self.history)
            self.last_saved, self.host_state = self.iteration, host_state
        every = self.snapshot_every
        if every and (finished or self.iteration // every > first // every):
            snapshot = gather(checkpoints.snapshot_of(state))  # every process takes part
            if self.writes:
                checkpoints.save_snapshot(self.out, self.iteration, snapshot)
        self.signals.progressed()
        return self.stopped_by is None


def _agreed_signal(requested: int | None) -> int | None:
    """The signal that asks the run to stop, as every process sees it: in a run of several
    processes, one asked is all asked (else they would part at the next collective)."""
    import jax

    if jax.process_count() == 1:
        return requested
    from jax.experimental import multihost_utils

    asked = multihost_utils.process_allgather(np.int32(requested or 0))
    return int(asked.max()) or None


def _runner(spec: RunSpec, problem, config):
    """The multi-seed runner of the run's update, and the update's parameter counts."""
    from emgail_jax.host.seed_runner import Runner
    from emgail_jax.method.batches import DemonstrationPairs
    from emgail_jax.method.training import RunData, make_train

    env = problem.env
    pairs = DemonstrationPairs.create(
        problem.demos, problem.random_returns, problem.true_intentions
    )
    data = RunData.create(pairs, env, config.info_weight)
    init, update = make_train(config.method, env)
    # Runs of one process that differ only in data (the sweep's driver radii) share programs.
    program_key = (config.program_key(), env.program_key())
    runner = Runner(init, update, spec.seeds, data, config.schedule.seed_batch, program_key)
    return runner, parameter_counts(init, data)


def _first_state(runner, out: str, resume: bool, key):
    """``(state, history, iterations done)``: restored from the last checkpoint, or new."""
    from emgail_jax.host import checkpoints

    if resume and checkpoints.latest_iteration(out) is not None:
        host_state, history, done = checkpoints.restore(out, runner.abstract_state(key))
        return runner.place_state(host_state), history, done
    return runner.init(key), None, 0


def _summary_header(spec: RunSpec, problem, config) -> dict:
    env = problem.env
    return {
        "env": env.name,
        "env_options": env.options(),
        "algo": config.method.algo.value,
        "intentions": env.num_intentions,
        "seeds": spec.seeds,
        "first_seed": spec.first_seed,
        "iterations": config.schedule.iterations,
        "random_episodes": spec.random_episodes,
        "demonstrations": {
            "source": problem.demos_source,
            "path": stored_sources(spec.demo_sources),
            "seed": spec.demo_seed,
            "pairs": len(problem.demos),
            "intentions": problem.true_intentions,
            "labels": problem.demos.intentions is not None,
            "expert_returns": problem.demos.expert_returns is not None,
        },
        "config": config.to_dict(),
    }


def _final_summary(problem, config, history, timings, spec) -> dict:
    from emgail_jax.host.seed_runner import final_metrics
    from emgail_jax.method.training import evaluation_phases

    env = problem.env
    rollout = config.method.rollout
    k, b, t = env.num_intentions, rollout.num_envs, rollout.rollout_length
    final = final_metrics(history)
    iterations = history["eval/returns"].shape[1]
    evaluated = int(np.sum(~np.isnan(history["eval/returns"][0, :, 0])))
    eval_steps = b * t * evaluation_phases(config.method, env)  # per intention and evaluation
    env_steps = k * (b * t * iterations + eval_steps * evaluated)
    no_accuracy = not config.method.algo.learns_posterior or problem.demos.intentions is None
    no_erd = problem.demos.expert_returns is None
    summary = {
        "erd": None if no_erd else final["eval/erd"],
        "erd_per_intention": None if no_erd else final["eval/erd_per_intention"],
        "cluster_accuracy": None if no_accuracy else final["eval/cluster_accuracy"],
        "returns": final["eval/returns"],
        "expert_returns": problem.demos.expert_returns,
        "random_returns": problem.random_returns,
        "compile_time_s": timings["compile_time_s"],
        "train_time_s": timings["train_time_s"],
        "iteration_time_s": timings["train_time_s"] / max(timings["iterations"], 1),
        "env_steps": env_steps * spec.seeds,
    }
    if "posterior/intention_weights" in final:  # the mixture prior: [seeds][K]
        summary["intention_weights"] = final["posterior/intention_weights"]
    if "posterior/intentions_in_use" in final:  # --intentions auto: [seeds]
        summary["intentions_held"] = np.rint(final["posterior/intentions_in_use"]).astype(int)
    if "reseed/reseedings" in history:  # the re-seedings of emptied intentions, to the end
        summary["reseedings"] = history["reseed/reseedings"][:, -1].astype(int)
    name = "trajectory_cluster_accuracy"
    if f"eval/{name}" in final:  # EM-GAIL and Info/IntentionGAIL in trajectory mode
        summary[name] = None if no_accuracy else final[f"eval/{name}"]
    return summary


def _held_final(problem, config, demos, states) -> dict:
    """``demonstrations_held[seed][K]``: how many demonstrations each learned intention holds
    under the final state's E-step (none: a collapsed intention)."""
    from emgail_jax.method.choosing import demonstrations_held
    from emgail_jax.method.training import make_networks, responsibilities_of, seed_state

    method = config.method
    networks = make_networks(method, problem.env)
    held = [
        demonstrations_held(
            np.asarray(responsibilities_of(networks, method, seed_state(states, s), demos).gamma),
            demos.episode,
            demos.episodes,
        )
        for s in range(states.intention_weights.shape[0])
    ]
    return {"demonstrations_held": np.stack(held)}


def _chosen_final(problem, config, demos, states, history) -> dict:
    """The final metrics of a run that chooses K: the seeds together decide, on the final
    state, the intentions each keeps (:func:`~emgail_jax.method.choosing.chosen_intentions`);
    the ERD is then that of the last evaluations matched to those, the accuracies the final
    state's (a retired intention's demonstrations go to the kept one the posterior ranks
    next)."""
    from emgail_jax.host.seed_runner import FINAL_WINDOW
    from emgail_jax.method.choosing import chosen_intentions
    from emgail_jax.method.metrics import normalized_erd
    from emgail_jax.method.training import (
        clustering_metrics,
        make_networks,
        responsibilities_of,
        seed_state,
    )

    method = config.method
    networks = make_networks(method, problem.env)
    seeds = states.intention_weights.shape[0]
    responsibilities = [
        responsibilities_of(networks, method, seed_state(states, seed), demos)
        for seed in range(seeds)
    ]
    gamma = np.stack([np.asarray(r.gamma) for r in responsibilities])
    weights = np.asarray(states.intention_weights)
    kept = chosen_intentions(gamma, weights, demos.episode, demos.episodes)  # [S, M]
    m = kept.shape[1]
    k = problem.true_intentions
    returns = history["eval/learned_returns"]
    returns = returns.reshape(*returns.shape[:2], m, k)  # [S, L, M learned, K true]
    final = {"intentions_kept": kept, "intentions_chosen": kept.sum(1)}
    per_seed = []
    for seed in range(seeds):
        values = {}
        if problem.demos.expert_returns is not None:
            evaluated = np.flatnonzero(~np.isnan(returns[seed, :, 0, 0]))[-FINAL_WINDOW:]
            erds = [
                normalized_erd(
                    returns[seed, i], demos.expert_returns, demos.random_returns, kept[seed]
                )
                for i in evaluated
            ]
            values["erd"] = np.mean([float(e.mean) for e in erds])
            values["erd_per_intention"] = np.mean([e.per_intention for e in erds], 0)
            matched = [
                returns[seed, i][np.asarray(e.matching), np.arange(k)]
                for i, e in zip(evaluated, erds, strict=True)
            ]
            values["returns"] = np.mean(matched, 0)
        if demos.has_labels:
            clustering = clustering_metrics(
                responsibilities[seed], demos, m, method.e_step.responsibilities, kept[seed]
            )
            values.update({name[5:]: float(v) for name, v in clustering.items()})
        per_seed.append(values)
    for name in per_seed[0]:
        final[name] = np.stack([values[name] for values in per_seed])
    return final


def _progress_fields(history: dict[str, np.ndarray]) -> dict[str, str]:
    """The progress bar's latest ERD and accuracy: means over seeds of the last measured
    values, or "-" when undefined (no labels, nothing evaluated yet)."""
    fields = {}
    for label, name in (("ERD", "eval/erd"), ("acc", "eval/cluster_accuracy")):
        values = history[name]
        measured = np.flatnonzero(~np.all(np.isnan(values), 0))
        fields[label] = "-" if not len(measured) else f"{np.nanmean(values[:, measured[-1]]):.3f}"
    return fields


def parameter_counts(init, data) -> dict[str, int]:
    """Learnable parameters of each network of one seed, and their total (the paper's Table 2
    "#LP" counts policy, value, discriminator and posterior)."""
    import jax

    state = jax.eval_shape(init, jax.random.PRNGKey(0), data)
    counts = {
        name: sum(int(np.prod(leaf.shape)) for leaf in jax.tree.leaves(params))
        for name, params in state.network_parameters().items()
    }
    return {**counts, "total": sum(counts.values())}


def print_summary(summary: dict) -> None:
    from rich.console import Console
    from rich.table import Table

    from emgail_jax.host.seed_runner import FINAL_WINDOW

    final = summary["final"]
    seeds = summary["seeds"]
    done = summary["iterations_done"]
    window = f"the last {FINAL_WINDOW} of {done}" if done > FINAL_WINDOW else f"all {done}"
    table = Table(
        title=f"{summary['algo']} on {summary['env']} (K={summary['intentions']}), "
        f"mean of {window} iterations ({summary['status']})"
    )
    table.add_column("seed", justify="right")
    table.add_column("norm. ERD", justify="right")
    table.add_column("per intention", justify="right")
    table.add_column("cluster acc.", justify="right")
    table.add_column("true returns (learned / expert)")
    held = final.get("demonstrations_held")
    if held is not None:
        table.add_column("demos held", justify="right")
    chosen = final.get("intentions_chosen")
    if chosen is not None:
        table.add_column("K chosen", justify="right")
    erds = final["erd"] or [None] * seeds
    per_intention = final.get("erd_per_intention") or [None] * seeds
    accuracy = final["cluster_accuracy"] or [None] * seeds
    expert = final["expert_returns"] or [None] * summary["intentions"]
    number = lambda x: "-" if x is None else f"{x:.3f}"
    rows = zip(erds, per_intention, accuracy, final["returns"], strict=True)
    for seed, (erd, erd_i, acc, returns) in enumerate(rows):
        pairs = ", ".join(
            f"{r:.1f}" if e is None else f"{r:.1f}/{e:.1f}"
            for r, e in zip(returns, expert, strict=True)
        )
        table.add_row(
            str(summary["first_seed"] + seed),
            number(erd),
            "-" if erd_i is None else " ".join(f"{e:.2f}" for e in erd_i),
            number(acc),
            pairs,
            *([] if held is None else [" ".join(str(n) for n in held[seed])]),
            *([] if chosen is None else [str(chosen[seed])]),
        )
    console = Console()
    console.print(table)
    console.print(
        f"compile {final['compile_time_s']:.1f} s, train {final['train_time_s']:.1f} s "
        f"({final['iteration_time_s'] * 1000:.0f} ms per iteration for all seeds)"
    )


def _command(
    args: argparse.Namespace,
    signals: stopping.Signals,
    held: contextlib.ExitStack,
    locked: bool,
) -> tuple[str, dict]:
    """The run the command line asks for, trained: ``(run directory, summary)``; ``held``
    holds the run directory's lock (taken here unless ``locked`` already)."""
    import jax

    from emgail_jax.host import records
    from emgail_jax.host.checkpoints import CheckpointError, latest_iteration
    from emgail_jax.host.problem import problem_of
    from emgail_jax.host.seed_runner import seed_sharding

    primary = jax.process_index() == 0
    out = args.resume or args.out
    with held:
        # Before anything reads or writes the directory: a live run keeps it.
        if primary and out is not None and not locked:
            _hold_output(args, held)
        spec = spec_from_args(args)
        seed_sharding(spec.seeds)  # the seeds fit the processes, before anything compiles
        if out is None:
            out = default_output(spec.env, spec.algo)
            if primary:
                held.enter_context(_writing(out, new=True))
        # A run killed before its first checkpoint restarts: its summary holds its spec.
        unfinished = args.resume is not None and read_summary(out).get("status") == "running"
        if args.resume is not None and latest_iteration(out) is None and not unfinished:
            raise CheckpointError(f"'{out}' holds no checkpoint to resume from")
        problem = problem_of(spec)
        if spec.config.method.e_step.responsibilities.oracle and problem.demos.intentions is None:
            raise RunError("--responsibilities labels needs demonstrations with hidden labels")
        logs_to_wandb = args.wandb is not None and primary
        if logs_to_wandb:
            records.require_wandb()
        if args.resume is None:
            if primary:
                prepare_output(out, args.overwrite)
        else:
            done = latest_iteration(out)
            start = "the start (it stopped before its first checkpoint)" if done is None else done
            print(f"resuming '{out}' from iteration {start}")
        wandb_run = None
        if logs_to_wandb:
            header = _summary_header(spec, problem, spec.config.resolved(problem.env))
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
        error = jax_setup.seed_share_error(_seeds_of(args), distributed.num_processes)
        if error:
            print(f"error: {error}", file=sys.stderr)
            return 2
    held = contextlib.ExitStack()
    locked = distributed is None and bool(args.resume or args.out)
    if locked:
        # The lock at once, before JAX starts (a run of several processes takes it later, so
        # that the others hear of a refusal).
        try:
            _hold_output(args, held)
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


def _seeds_of(args: argparse.Namespace) -> int:
    """The seeds of the run asked for, as :func:`spec_from_args` will find them."""
    if args.resume is not None:
        with contextlib.suppress(RunError, AttributeError, TypeError, ValueError):
            return int(read_summary(args.resume).get("seeds", 1))
        return 1  # no readable summary: the command fails later, with its own message
    return args.seeds or DEFAULT_SEEDS


def _hold_output(args: argparse.Namespace, held: contextlib.ExitStack) -> None:
    held.enter_context(_writing(args.resume or args.out, new=args.resume is None))


def _main(
    args: argparse.Namespace,
    signals: stopping.Signals,
    several: bool,
    held: contextlib.ExitStack,
    locked: bool,
) -> int:
    """The command, its errors as one line and exit code 2; in a run of several processes,
    a failure is posted for the others (:func:`jax_setup.report_failure`), which end too."""
    import jax

    import envs
    from emgail_jax.host.checkpoints import CheckpointError
    from emgail_jax.host.demonstration_files import DemonstrationError
    from emgail_jax.host.records import WandbError

    try:
        out, summary = _command(args, signals, held, locked)
    except (envs.EnvError, DemonstrationError, RunError, CheckpointError, WandbError) as error:
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
    print(line, file=sys.stderr)
    jax_setup.report_failure(line.removeprefix("error: "))
    return code


if __name__ == "__main__":
    sys.exit(main())
