"""Is the learned reward a reward? Train fresh policies on it and measure their ERD (paper §5.2).

    python -m emgail_jax.reoptimize RUN_DIR [--seed 0] [--iterations N]

For every learned intention i, a new policy is trained from scratch with TRPO on the frozen
pseudo-reward R_i(s, a) of the run's ``--seed`` (intentions vmapped), never seeing the true
reward. Its deterministic episodes are scored under the true rewards; the normalised ERD takes
the best matching of learned to true intentions. Beside it, the learned reward per step that
the fresh policies earn and that the demonstrations the run assigned to each intention earn:
fresh policies that out-earn the demonstrations yet score far from the experts have optimised a
reward that pays off the demonstrations' support. Writes ``RUN_DIR/reoptimize.json``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

from emgail_jax.host import jax_setup


def reoptimize(run, seed: int, iterations: int, chunk: int = 10, progress: bool = True) -> dict:
    """Trains one policy per learned intention on ``run``'s frozen reward of ``seed``."""
    import jax
    import jax.numpy as jnp

    from emgail_jax.host.progress import ProgressBar
    from emgail_jax.host.seed_runner import chunk_length, chunks, run_chunks
    from emgail_jax.method.metrics import normalized_erd
    from emgail_jax.method.rl import intention_chunk, make_rl_train

    env = run.problem.env
    k = run.num_intentions
    learned_reward = run.reward(seed)

    def reward_fn(obs, action, true_reward, intention):
        return learned_reward(obs, action, intention)

    trainer = make_rl_train(run.config, env, reward_fn)
    plan = chunks(0, iterations, chunk_length(iterations, chunk))
    no_inputs = lambda first, length: np.zeros(length, bool)
    # The policies' keys come from the run's seed, one per learned intention.
    keys = jax.random.split(jax.random.PRNGKey(run.spec.first_seed + seed + 1000), k)
    states = jax.jit(jax.vmap(trainer.init))(keys)
    start = time.perf_counter()
    step = intention_chunk(trainer, jnp.arange(k)).lower(states, no_inputs(*plan[0])).compile()
    compile_s = time.perf_counter() - start
    demos = run.problem.demos
    expert_returns = demos.expert_returns
    random_returns = run.problem.random_returns
    in_use = run.intentions_in_use(seed)  # --intentions auto: the learned ones kept
    score = lambda r: normalized_erd(r, expert_returns, random_returns, in_use)
    erds, all_returns, earned = [], [], []
    bar = ProgressBar("re-optimising", iterations, {"ERD": "-"}, enabled=progress)

    def after_chunk(first, length, states, metrics) -> bool:
        returns = np.asarray(metrics["eval/returns"])  # [chunk, K learned, K env]
        all_returns.extend(returns)
        earned.extend(np.asarray(metrics["train/reward"]))  # [chunk, K] learned reward per step
        if expert_returns is not None:
            for r in returns:
                erds.append(float(score(r).mean))
        bar.update(length, ERD=f"{erds[-1]:.3f}" if erds else "-")
        return True

    start = time.perf_counter()
    run_chunks(step, states, plan, no_inputs, after_chunk)
    bar.close()
    train_s = time.perf_counter() - start
    last = np.mean(all_returns[-10:], axis=0)
    result = {
        "run_seed": seed,
        "iterations": iterations,
        "returns": last,  # [K learned, K env], mean of the last 10 iterations
        "expert_returns": expert_returns,
        "random_returns": random_returns,
        "erd": float(np.mean(erds[-10:])) if erds else None,
        "erd_curve": erds,
        "learned_reward_per_step": {
            "fresh_policies": np.mean(earned[-10:], axis=0),  # [K], last 10 iterations
            "demonstrations": demonstrations_reward(run, seed),  # [K]
        },
        "compile_time_s": compile_s,
        "train_time_s": train_s,
    }
    if expert_returns is not None:
        erd = score(last)
        result["matching"] = np.asarray(erd.matching)
        result["erd_per_intention"] = np.asarray(erd.per_intention)
    return result


def demonstrations_reward(run, seed: int) -> np.ndarray:
    """``[K]``: learned intention i's reward per step on the demonstration pairs, weighted by
    the run's responsibilities gamma_i (every pair alike without a posterior); NaN for an
    intention the run assigned no demonstration to."""
    pairs = run.demonstration_pairs
    k = run.num_intentions
    if run.algorithm.learns_posterior:
        gamma = np.asarray(run.responsibilities(seed).gamma)  # [N, K]
    else:
        gamma = np.ones((pairs.observations.shape[0], k))
    reward = run.reward(seed)
    per_pair = np.stack(
        [np.asarray(reward(pairs.observations, pairs.actions, i)) for i in range(k)], -1
    )  # [N, K]
    weight = gamma.sum(0)
    total = (gamma * per_pair).sum(0)
    return np.divide(total, weight, out=np.full(k, np.nan), where=weight > 0)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m emgail_jax.reoptimize", description=__doc__.split("\n")[0]
    )
    parser.add_argument("run_dir")
    parser.add_argument("--seed", type=int, default=0, help="whose learned reward (0..seeds-1)")
    parser.add_argument("--iterations", type=int, default=None, help="default: the run's")
    parser.add_argument("--quiet", action="store_true")
    args = parser.parse_args(argv)
    jax_setup.setup(host_devices=1)

    import envs
    from emgail_jax.host import records
    from emgail_jax.host.checkpoints import CheckpointError
    from emgail_jax.host.demonstration_files import DemonstrationError
    from emgail_jax.host.run_spec import RunError
    from emgail_jax.host.saved_run import SavedRun

    try:
        run = SavedRun.open(args.run_dir)
        run.seed_state(args.seed)
        if args.iterations is not None and args.iterations < 1:
            raise RunError("--iterations must be at least 1")
    except (RunError, CheckpointError, envs.EnvError, DemonstrationError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    iterations = args.iterations or run.config.iterations
    result = reoptimize(run, args.seed, iterations, progress=not args.quiet)
    path = os.path.join(args.run_dir, "reoptimize.json")
    records.write_json(path, result)
    names = run.problem.env.intention_names
    learned = np.asarray(result["returns"])
    if result["erd"] is None:
        print("no expert returns in the demonstrations: ERD cannot be computed")
    else:
        matched = ", ".join(
            f"{names[i]}: {learned[j, i]:.1f} (expert {result['expert_returns'][i]:.1f})"
            for i, j in enumerate(result["matching"])
        )
        print(
            f"re-optimised on the learned reward of seed {args.seed} for {iterations} iterations: "
            f"normalised ERD {result['erd']:.3f} (mean of the last 10) [{matched}]"
        )
    earned = result["learned_reward_per_step"]
    print(
        "learned reward per step, fresh policies / demonstrations: "
        + ", ".join(
            f"{a:.2f} / {b:.2f}"
            for a, b in zip(earned["fresh_policies"], earned["demonstrations"], strict=True)
        )
    )
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
