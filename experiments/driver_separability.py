"""Separability of the driver's demonstrations against the radius of path 2 (paper Fig. 4b).

    python experiments/driver_separability.py [--radii 3.6 4 5 ...] [--out DIR]

For every radius: the demonstrations `emgail_jax.run` would use (500 pairs per intention), their
separability (Gaussian mixture, mean and std over 5 mixture seeds), and, for reference, the
accuracy a supervised classifier reaches with the hidden labels (3-fold cross-validated MLP): an
upper bound on what any clustering of these pairs can reach.
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

from emgail_jax.host.command_line import ArgumentParser

DEFAULT_RADII = (3.6, 4.0, 4.5, 5.0, 6.0, 7.0, 8.0, 10.0, 12.0, 15.0, 20.0, 30.0, 50.0)


def parse_args(argv=None) -> argparse.Namespace:
    parser = ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--radii", type=float, nargs="+", default=DEFAULT_RADII)
    parser.add_argument("--demo-seed", type=int, default=0)
    parser.add_argument("--out", default=None, help="also write separability.csv/.md here")
    parser.add_argument(
        "--env-option",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="driver option other than radius (repeatable), e.g. expert_noise=0.1",
    )
    return parser.parse_args(argv)


def measure(radius: float, demo_seed: int, options: dict[str, float]) -> tuple[float, ...]:
    """(radius, destination gap, separability mean, its std, supervised accuracy) of the
    demonstrations at ``radius``."""
    from sklearn.model_selection import cross_val_score
    from sklearn.neural_network import MLPClassifier
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    import envs
    from emgail_jax.host.problem import default_demos
    from emgail_jax.method.metrics import separability

    env = envs.make("driver", intentions=2, radius=radius, **options)
    demos, _ = default_demos(env, demo_seed)
    mean, std = separability(demos.observations, demos.actions, demos.intentions)
    pairs = np.concatenate([demos.observations, demos.actions], 1)
    classifier = make_pipeline(
        StandardScaler(), MLPClassifier((64, 64), max_iter=2000, random_state=0)
    )
    supervised = cross_val_score(classifier, pairs, demos.intentions, cv=3).mean()
    destination_gap = float(np.linalg.norm(np.subtract(*env.destinations())))
    return radius, destination_gap, mean, std, supervised


def print_table(rows: list[tuple[float, ...]]) -> None:
    from rich.console import Console
    from rich.table import Table

    table = Table(title="driver: separability against the radius of path 2 (path 1: 3.5)")
    for name in ("radius", "destination gap", "separability", "supervised acc."):
        table.add_column(name, justify="right")
    for radius, gap, mean, std, supervised in rows:
        table.add_row(f"{radius:g}", f"{gap:.2f}", f"{mean:.3f} ± {std:.3f}", f"{supervised:.3f}")
    Console().print(table)


def write_tables(out: str, rows: list[tuple[float, ...]]) -> None:
    """``separability.csv`` and ``separability.md`` in ``out``."""
    os.makedirs(out, exist_ok=True)
    with open(os.path.join(out, "separability.csv"), "w") as f:
        f.write("radius,destination_gap,separability,separability_std,supervised_accuracy\n")
        for row in rows:
            f.write(",".join(f"{v:.4f}" for v in row) + "\n")
    with open(os.path.join(out, "separability.md"), "w") as f:
        f.write("| radius of path 2 | destination gap | separability | supervised acc. |\n")
        f.write("|---:|---:|---:|---:|\n")
        for radius, gap, mean, std, supervised in rows:
            f.write(f"| {radius:g} | {gap:.2f} | {mean:.3f} ± {std:.3f} | {supervised:.3f} |\n")


def main(argv=None) -> int:
    args = parse_args(argv)
    from emgail_jax.host import jax_setup

    jax_setup.setup(host_devices=1)
    from rich.progress import track

    options = {}
    for item in args.env_option:
        name, _, value = item.partition("=")
        options[name] = float(value)
    rows = [
        measure(radius, args.demo_seed, options)
        for radius in track(args.radii, description="radii")
    ]
    print_table(rows)
    if args.out:
        write_tables(args.out, rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
