"""How far TRPO gets on an env's TRUE rewards at the IRL budget: the floor of every IRL result.

    python experiments/rl_floor.py --env halfcheetah [--intentions 1] [--iterations 400] \
        [--set KEY=VALUE ...]

Trains one policy per intention with the project's B-step (TRPO, GAE, value baseline) on the
true reward, with the rollout sizes and hyper-parameters of an IRL run (`emgail_jax.method.config`),
and prints every 10 iterations the deterministic return of each intention, its normalised ERD
against the shipped experts and the policy's entropy. No imitation method trained at the
same budget with the same B-step can be expected to beat this curve.
"""

from __future__ import annotations

import sys
import time

from emgail_jax.host.command_line import ArgumentParser


def main(argv=None) -> int:
    parser = ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--env", required=True)
    parser.add_argument("--intentions", type=int, default=1)
    parser.add_argument("--iterations", type=int, default=400)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    args = parser.parse_args(argv)

    from emgail_jax.host import jax_setup

    jax_setup.setup(host_devices=1)
    import jax
    import jax.numpy as jnp
    import numpy as np

    from emgail_jax.host.problem import make_problem
    from emgail_jax.host.seed_runner import chunk_length, chunks, run_chunks
    from emgail_jax.method.config import RunConfig
    from emgail_jax.method.rl import intention_chunk, make_rl_train

    problem = make_problem(args.env, args.intentions)
    env = problem.env
    expert_returns = np.asarray(problem.demos.expert_returns)
    random_returns = np.asarray(problem.random_returns)
    trainer = make_rl_train(RunConfig().with_settings(args.set).method, env)
    step = intention_chunk(trainer, jnp.arange(env.num_intentions))
    plan = chunks(0, args.iterations, chunk_length(args.iterations, 10))
    start = time.perf_counter()

    def report(first, length, states, metrics) -> bool:
        returns = np.diag(np.asarray(metrics["eval/returns"])[-1])  # each on its own reward
        erd = np.abs(expert_returns - returns) / np.abs(expert_returns - random_returns)
        entropy = np.asarray(metrics["policy/entropy"])[-1]
        listed = lambda values, digits: ", ".join(f"{v:.{digits}f}" for v in values)
        print(
            f"iteration {first + length}: returns {listed(returns, 1)} (experts "
            f"{listed(expert_returns, 1)}), ERD {erd.mean():.3f}, entropy "
            f"{listed(entropy, 2)}, {time.perf_counter() - start:.0f} s",
            flush=True,
        )
        return True

    keys = jax.random.split(jax.random.PRNGKey(args.seed), env.num_intentions)
    states = jax.jit(jax.vmap(trainer.init))(keys)
    run_chunks(step, states, plan, lambda first, n: np.ones(n, bool), report)  # evaluate each
    return 0


if __name__ == "__main__":
    sys.exit(main())
