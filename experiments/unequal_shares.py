"""Demonstrations in unequal shares, made from a balanced set: the first N_i episodes of every
intention i of the shipped (or generated, for the driver) demonstrations, written as a
demonstrations file for ``python -m emgail_jax.run --demos FILE``.

    python experiments/unequal_shares.py --env hopper --episodes 5 3 1 --out /tmp/hopper-531.npz
    python -m emgail_jax.run --env hopper --demos /tmp/hopper-531.npz --prior mixture

The true shares are printed; the mixture prior's weights (``final.intention_weights`` in the
run's ``summary.json``) should come out near them.
"""

from __future__ import annotations

import dataclasses
import sys

from emgail_jax.host.command_line import ArgumentParser


def main(argv=None) -> int:
    parser = ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--env", required=True)
    parser.add_argument("--episodes", type=int, nargs="+", required=True, help="per intention")
    parser.add_argument("--radius", type=float, default=None, help="the driver's path 2")
    parser.add_argument("--out", required=True, help="the demonstrations file to write")
    parser.add_argument(
        "--drop-labels",
        action="store_true",
        help="write the pairs without their labels and expert returns, as unlabelled sets come "
        "(the labels go to OUT.labels.npy, for diagnosis only)",
    )
    args = parser.parse_args(argv)

    from emgail_jax.host import jax_setup

    jax_setup.setup(host_devices=1)
    import numpy as np

    import envs
    from emgail_jax.host import demonstration_files
    from emgail_jax.host.problem import make_problem
    from emgail_jax.method.demonstrations import first_episodes

    options = {} if args.radius is None else {"radius": args.radius}
    try:
        problem = make_problem(args.env, len(args.episodes), env_options=options)
        demos = first_episodes(problem.demos, args.episodes)
    except (envs.EnvError, demonstration_files.DemonstrationError, ValueError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    pairs = np.bincount(demos.intentions, minlength=len(args.episodes))
    if args.drop_labels:
        np.save(f"{args.out}.labels.npy", demos.intentions)
        demos = dataclasses.replace(demos, intentions=None, expert_returns=None)
    demonstration_files.save(demos, args.out)
    shares = ", ".join(f"{p / pairs.sum():.3f}" for p in pairs)
    print(f"wrote {len(demos)} pairs ({', '.join(map(str, pairs))}; shares {shares}) to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
