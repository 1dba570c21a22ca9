"""Command line: train EM-GAIL, Info/IntentionGAIL or GAIL on one env for several seeds.

    python -m emgail_jax.run --env driver --algo emgail --seeds 4 --iterations 400 --out DIR

writes ``DIR/summary.json``, ``DIR/metrics.csv`` (one row per iteration and seed) and TensorBoard
events under ``DIR/tensorboard`` (DESIGN §6).
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import time

import numpy as np

from emgail_jax import runtime

OUTPUTS = ("summary.json", "metrics.csv", "tensorboard")


class RunError(ValueError):
    """A run that cannot start; the message says what to change."""


def parse_args(argv=None) -> argparse.Namespace:
    from emgail_jax.algorithms import NAMES

    parser = argparse.ArgumentParser(
        prog="python -m emgail_jax.run", description=__doc__.split("\n")[0]
    )
    parser.add_argument("--env", default="driver", help="env name (default: driver)")
    parser.add_argument(
        "--intentions", type=int, default=None, help="K: use the first K intentions"
    )
    parser.add_argument("--algo", default="emgail", choices=NAMES)
    parser.add_argument("--seeds", type=int, default=4, help="seeds trained in parallel")
    parser.add_argument("--iterations", type=int, default=400)
    parser.add_argument("--out", required=True, help="output directory")
    parser.add_argument("--demos", default=None, help="demonstrations .npz (DESIGN §5)")
    parser.add_argument("--radius", type=float, default=None, help="driver: radius of path 2")
    parser.add_argument("--seed", type=int, default=0, help="first training seed")
    parser.add_argument("--demo-seed", type=int, default=0, help="driver: demonstration seed")
    parser.add_argument("--info-weight", type=float, default=None, help="infogail: lambda")
    parser.add_argument("--num-envs", type=int, default=None, help="envs per intention")
    parser.add_argument("--rollout-length", type=int, default=None, help="steps per rollout")
    parser.add_argument("--eval-episodes", type=int, default=None)
    parser.add_argument("--chunk-size", type=int, default=None, help="iterations per call")
    parser.add_argument("--overwrite", action="store_true", help="replace an earlier run")
    parser.add_argument("--quiet", action="store_true", help="no progress bar or table")
    return parser.parse_args(argv)


def build_config(args: argparse.Namespace):
    from emgail_jax.config import Config

    overrides = {
        "algo": args.algo,
        "iterations": args.iterations,
        "info_weight": args.info_weight,
        "num_envs": args.num_envs,
        "rollout_length": args.rollout_length,
        "eval_episodes": args.eval_episodes,
        "chunk_size": args.chunk_size,
    }
    return Config().replace(**{k: v for k, v in overrides.items() if v is not None})


def prepare_output(out: str, overwrite: bool) -> None:
    """Creates ``out``; refuses to mix with an earlier run unless ``overwrite``."""
    existing = [name for name in OUTPUTS if os.path.exists(os.path.join(out, name))]
    if existing and not overwrite:
        raise RunError(
            f"'{out}' already holds a run ({', '.join(existing)}): "
            "pass --overwrite to replace it or choose another --out"
        )
    os.makedirs(out, exist_ok=True)
    for name in existing:
        path = os.path.join(out, name)
        shutil.rmtree(path) if os.path.isdir(path) else os.remove(path)


def train(problem, config, seeds: int, out: str, seed: int = 0, progress: bool = True) -> dict:
    """Trains ``seeds`` seeds on ``problem`` and writes the run's outputs to ``out``.

    Returns the summary (as written to ``summary.json``).
    """
    import jax

    from emgail_jax import records
    from emgail_jax.runner import Runner, chunk_length, concat_history, final_metrics
    from emgail_jax.training import ExpertData, make_train

    env = problem.env
    config = config.resolved(env)
    expert = ExpertData.create(problem.demos, problem.random_returns, env.num_intentions)
    init, update = make_train(config, env, expert)
    chunk = chunk_length(config.iterations, config.chunk_size)
    runner = Runner(init, update, seeds, chunk)
    log = records.MetricsLog(out)
    summary = {
        "env": env.name,
        "env_options": env.options(),
        "algo": config.algo,
        "intentions": env.num_intentions,
        "seeds": seeds,
        "first_seed": seed,
        "iterations": config.iterations,
        "demonstrations": {"source": problem.demos_source, "pairs": len(problem.demos)},
        "devices": [str(d) for d in runner.sharding.mesh.devices.flat],
        "config": config.to_dict(),
        "status": "running",
    }
    summary_path = os.path.join(out, "summary.json")
    records.write_json(summary_path, summary)

    state = runner.init(jax.random.PRNGKey(seed))
    runner.compile(state)
    history = None
    bar = _Progress(config.iterations, enabled=progress)
    try:
        for first in range(0, config.iterations, chunk):
            state, metrics = runner.step(state)
            log.write(first, metrics)
            history = concat_history(history, metrics)
            bar.update(chunk, metrics)
    finally:
        bar.close()
        log.close()

    final = final_metrics(history)
    timings = runner.timings
    k, b, t = env.num_intentions, config.num_envs, config.rollout_length
    steps_per_iteration = k * (b * t + config.eval_episodes * env.episode_length)
    summary["status"] = "completed"
    summary["final"] = {
        "erd": final["eval/erd"],
        "cluster_accuracy": None if config.algo == "gail" else final["eval/cluster_accuracy"],
        "returns": final["eval/returns"],
        "expert_returns": problem.demos.expert_returns,
        "random_returns": problem.random_returns,
        "compile_time_s": timings.compile_s,
        "train_time_s": timings.train_s,
        "iteration_time_s": timings.train_s / timings.iterations,
        "env_steps": steps_per_iteration * timings.iterations * seeds,
    }
    records.write_json(summary_path, summary)
    return records.to_json_value(summary)


class _Progress:
    """A rich progress bar showing iteration, ERD, clustering accuracy, it/s and ETA."""

    def __init__(self, total: int, enabled: bool):
        self.enabled = enabled
        if not enabled:
            return
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        self.progress = Progress(
            TextColumn("[bold]training"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("ERD {task.fields[erd]}  acc {task.fields[acc]}  {task.fields[speed]}"),
            TimeElapsedColumn(),
            TextColumn("ETA"),
            TimeRemainingColumn(),
        )
        self.progress.start()
        self.task = self.progress.add_task("train", total=total, erd="-", acc="-", speed="")
        self.start = time.perf_counter()
        self.done = 0

    def update(self, advance: int, metrics: dict) -> None:
        if not self.enabled:
            return
        self.done += advance
        erd = np.nanmean(metrics["eval/erd"][:, -1])
        acc = metrics["eval/cluster_accuracy"][:, -1]
        acc_text = "-" if np.all(np.isnan(acc)) else f"{np.nanmean(acc):.3f}"
        speed = self.done / (time.perf_counter() - self.start)
        self.progress.update(
            self.task, advance=advance, erd=f"{erd:.3f}", acc=acc_text, speed=f"{speed:.1f} it/s"
        )

    def close(self) -> None:
        if self.enabled:
            self.progress.stop()


def print_summary(summary: dict) -> None:
    from rich.console import Console
    from rich.table import Table

    final = summary["final"]
    table = Table(
        title=f"{summary['algo']} on {summary['env']} (K={summary['intentions']}), "
        f"mean of the last 10 of {summary['iterations']} iterations"
    )
    table.add_column("seed", justify="right")
    table.add_column("norm. ERD", justify="right")
    table.add_column("cluster acc.", justify="right")
    table.add_column("true returns (learned / expert)")
    accuracy = final["cluster_accuracy"] or [None] * len(final["erd"])
    for seed, (erd, acc, returns) in enumerate(
        zip(final["erd"], accuracy, final["returns"], strict=True)
    ):
        pairs = ", ".join(
            f"{r:.1f}/{e:.1f}" if e is not None else f"{r:.1f}"
            for r, e in zip(returns, final["expert_returns"] or [None] * len(returns), strict=True)
        )
        table.add_row(
            str(summary["first_seed"] + seed),
            "-" if erd is None else f"{erd:.3f}",
            "-" if acc is None else f"{acc:.3f}",
            pairs,
        )
    console = Console()
    console.print(table)
    console.print(
        f"compile {final['compile_time_s']:.1f} s, train {final['train_time_s']:.1f} s "
        f"({final['iteration_time_s'] * 1000:.0f} ms per iteration for all seeds)"
    )


def main(argv=None) -> int:
    args = parse_args(argv)
    runtime.setup()

    import envs
    from emgail_jax.demos import DemonstrationError
    from emgail_jax.problem import make_problem

    try:
        if args.seeds < 1 or args.iterations < 1:
            raise RunError("--seeds and --iterations must be at least 1")
        env_options = {}
        if args.radius is not None:
            if args.env != "driver":
                raise RunError("--radius applies to the driver env only")
            env_options["radius"] = args.radius
        config = build_config(args)
        problem = make_problem(
            args.env, args.intentions, args.demos, env_options, demo_seed=args.demo_seed
        )
        prepare_output(args.out, args.overwrite)
    except (envs.EnvError, DemonstrationError, RunError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    if problem.demos.expert_returns is None:
        print("notice: the demonstrations carry no expert_returns, so ERD is reported as null")
    if problem.demos.intentions is None:
        print("notice: the demonstrations carry no intention labels, so accuracy is null")
    summary = train(problem, config, args.seeds, args.out, args.seed, progress=not args.quiet)
    if not args.quiet:
        print_summary(summary)
    print(f"wrote {os.path.join(args.out, 'summary.json')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
