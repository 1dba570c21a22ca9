"""A reward check's seeds in one process against a process per seed at once, each pinned to
its own core (as the sweep runs a check, ``--check-processes``), measured in one run: row
iterations per second of each way and their ratio (a row: one run seed's K fresh policies).

    python experiments/bench_check_processes.py [--env halfcheetah] [--intentions 2] \
        [--rows 2] [--iterations 50]

Both ways train the check's fresh TRPO on the env's true rewards from the same keys, on one
XLA device per process as ``reoptimize`` does. Every process compiles and warms up first, then
waits for the others, so that only the training they do at once is timed (with the timed
run's program read back from the compilation cache, which the output gives).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

from emgail_jax.host.command_line import ArgumentParser

WARM_UP = 10  # iterations trained before the timed ones: the compile and the first chunk


def main(argv=None) -> int:
    parser = ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--env", default="halfcheetah")
    parser.add_argument("--intentions", type=int, default=2)
    parser.add_argument("--rows", type=int, default=2)
    parser.add_argument("--iterations", type=int, default=50)
    parser.add_argument(
        "--worker", nargs=3, metavar=("FIRST_ROW", "ROWS", "DIR"), help=argparse.SUPPRESS
    )
    args = parser.parse_args(argv)
    if args.iterations <= 0 or args.rows <= 0:
        parser.error("--iterations and --rows: give positive numbers")
    if args.worker:
        return worker(args, *args.worker)
    cores = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
    if len(cores) < 2 or args.rows < 2:
        parser.error("a process per row needs 2 or more rows and 2 or more cores here")
    one = timed_processes(args, [(0, args.rows)], pin=None)
    apart = timed_processes(args, [(row, 1) for row in range(args.rows)], pin=cores)
    row_iterations = args.rows * args.iterations
    print(f"{args.env}-{args.intentions}, {args.rows} rows x {args.iterations} iterations")
    for name, (seconds, compiles) in (("one process", one), (f"{args.rows} processes", apart)):
        print(
            f"  {name:14s} {row_iterations / seconds:.2f} row-iterations per s ({seconds:.1f} s, "
            f"of which reading the program back {max(compiles):.1f} s)"
        )
    print(f"  ratio {args.rows} processes / one process: {one[0] / apart[0]:.2f}")
    return 0


def timed_processes(
    args, shares: list[tuple[int, int]], pin: list[int] | None
) -> tuple[float, list[float]]:
    """Seconds from the moment every process has warmed up to the last one's end, and each
    process's compile seconds within them."""
    with tempfile.TemporaryDirectory() as directory:
        children = []
        for slot, (first, rows) in enumerate(shares):
            command = [sys.executable, __file__, "--env", args.env]
            command += ["--intentions", str(args.intentions), "--iterations", str(args.iterations)]
            command += ["--worker", str(first), str(rows), directory]
            children.append(subprocess.Popen(command))
            if pin:
                os.sched_setaffinity(children[-1].pid, {pin[slot % len(pin)]})
        while len(os.listdir(directory)) < len(children):  # each writes a file once warmed up
            if any(child.poll() for child in children):
                raise SystemExit("a worker failed")
            time.sleep(0.05)
        with open(os.path.join(directory, "go"), "w"):
            pass
        started = time.monotonic()
        if any(child.wait() for child in children):
            raise SystemExit("a worker failed")
        seconds = time.monotonic() - started
        compiles = []
        for first, _ in shares:
            with open(os.path.join(directory, f"warm-{first}")) as f:
                compiles.append(json.load(f)["compile_s"])
        return seconds, compiles


def worker(args, first: str, rows: str, directory: str) -> int:
    from emgail_jax.host import jax_setup

    jax_setup.setup(host_devices=1)
    import jax
    import numpy as np

    from emgail_jax.host.problem import make_problem
    from emgail_jax.method.config import RunConfig
    from emgail_jax.method.rl import make_rl_train
    from emgail_jax.reward import check as reward_check

    env = make_problem(args.env, args.intentions).env
    trainer = make_rl_train(RunConfig().method, env)
    row_keys = jax.random.split(jax.random.PRNGKey(0), int(first) + int(rows))[int(first) :]
    keys = np.stack([jax.random.split(key, env.num_intentions) for key in row_keys])
    reward_check.train_fresh(trainer, keys, None, WARM_UP, label="", progress=False)
    warm = os.path.join(directory, f"warm-{first}")
    open(warm, "w").close()
    while not os.path.exists(os.path.join(directory, "go")):
        time.sleep(0.05)
    fresh = reward_check.train_fresh(trainer, keys, None, args.iterations, label="", progress=False)
    with open(warm, "w") as f:
        json.dump({"compile_s": fresh.compile_s}, f)
    return 0


if __name__ == "__main__":
    sys.exit(main())
