"""The reward check's fresh TRPO as ``reoptimize`` runs it against scoring every iteration (as
it did before), measured in one run: seconds per row-iteration (a row: one run seed's K
policies) and their ratio.

    python experiments/bench_reward_check.py [--env halfcheetah] [--intentions 2] [--rows 2] \
        [--iterations 100]

The fresh agents are scored on evaluation episodes every 10th iteration and each of the last 10
(:data:`emgail_jax.reward.check.CURVE_EVERY`), which changes neither their training nor
their final numbers; the evaluation episodes are as long as the training rollout, so scoring
every iteration costs most of a rollout more. Both ways train TRPO on the env's true rewards
(a learned reward adds one small MLP per step) from the same keys, on one device as
``reoptimize`` does; the compile is timed apart and excluded.
"""

from __future__ import annotations

import sys

from emgail_jax.host.command_line import ArgumentParser


def main(argv=None) -> int:
    parser = ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--env", default="halfcheetah")
    parser.add_argument("--intentions", type=int, default=2)
    parser.add_argument("--rows", type=int, default=2)
    parser.add_argument("--iterations", type=int, default=100)
    args = parser.parse_args(argv)
    if args.iterations <= 0 or args.rows <= 0:
        parser.error("--iterations and --rows: give positive numbers")

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
    k = env.num_intentions
    row_keys = jax.random.split(jax.random.PRNGKey(0), args.rows)
    keys = np.stack([jax.random.split(key, k) for key in row_keys])  # [rows, K]
    row_iterations = args.rows * args.iterations

    def timed(curve_every: int):
        fresh = reward_check.train_fresh(
            trainer, keys, None, args.iterations, label="", progress=False, curve_every=curve_every
        )
        return fresh.train_s, fresh.compile_s, np.isfinite(fresh.returns[0, :, 0, 0]).sum()

    shipped = timed(reward_check.CURVE_EVERY)
    before = timed(1)
    print(f"{args.env}-{k}, {args.rows} rows x {args.iterations} iterations, one device")
    for name, (seconds, compiled, scored) in (("as shipped", shipped), ("every iteration", before)):
        print(
            f"  {name:16s} {scored:4d} iterations scored, {seconds / row_iterations:.3f} s per "
            f"row-iteration (compile {compiled:.0f} s)"
        )
    print(f"  ratio every iteration / as shipped: {before[0] / shipped[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
