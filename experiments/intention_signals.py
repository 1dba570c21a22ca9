"""What the learner's own signals say about each learned intention's demonstrations.

    python experiments/intention_signals.py RUN_DIR [--snapshot ITER] [--seed S]

For every learned intention of one seed, and within it for every true intention (the hidden
labels) of the demonstrations it holds (the one with the most responsibility over their
pairs), three per-demonstration signals averaged over its pairs:

- ``logit``: the holder's discriminator logit f(s, a, i). High where the holder's policy does
  not produce the demonstration (its samples are D's negatives).
- ``log pi``: the log-likelihood of the demonstrated actions under the holder's policy.
- ``agree``: the share of the pairs whose per-pair posterior argmax is the holder.

An intention that holds two experts' demonstrations while its policy follows one of them
would show it as two groups apart in one of these (docs/notebook/no-empty-intention.md, reacher-3).
"""

from __future__ import annotations

import argparse
import sys

import jax.numpy as jnp
import numpy as np

from emgail_jax.host.command_line import ArgumentParser


def signals(run, seed: int) -> dict[str, np.ndarray]:
    """Per demonstration of ``seed``: ``holder [E]``, ``true [E]`` (-1 unknown), and ``logit``,
    ``log_pi`` ``[E, K]`` under every learned intention and ``agree [E]`` with the holder."""
    from emgail_jax.method import normalizer as obs_norm
    from emgail_jax.method.discriminator import expert_logits
    from emgail_jax.method.networks import action_distribution
    from emgail_jax.method.reseeding import demonstration_responsibilities

    def per_demonstration(values) -> np.ndarray:  # [N, C] -> [E, C], the mean over its pairs
        return np.asarray(
            demonstration_responsibilities(jnp.asarray(values), pairs.episode, episodes)
        )

    pairs, k = run.demonstration_pairs, run.num_intentions
    episode, episodes = np.asarray(pairs.episode), pairs.episodes
    state = run.seed_state(seed)
    responsibilities = run.responsibilities(seed)
    holder = np.asarray(responsibilities.trajectory_labels)
    obs = obs_norm.normalize(
        state.normalizer, pairs.observations, run.config.method.networks.obs_clip
    )
    logits = expert_logits(
        run.networks.discriminator.apply,
        state.discriminator.params,
        obs,
        pairs.actions,
        run.algorithm.discriminator_conditions(k),
    )  # [N, C]
    log_pi = []
    for intention in range(k):
        condition = run.algorithm.policy_condition(jnp.full(obs.shape[0], intention), k)
        mean, log_std = run.networks.policy.apply(state.policy, obs, condition)
        log_pi.append(action_distribution(mean, log_std).log_prob(pairs.actions))
    first = np.array([np.flatnonzero(episode == e)[0] for e in range(episodes)])
    agree = np.asarray(responsibilities.pair_labels) == holder
    return {
        "holder": holder[first],
        "true": np.asarray(pairs.labels)[first],
        "logit": per_demonstration(logits),
        "log_pi": per_demonstration(jnp.stack(log_pi, 1)),
        "agree": per_demonstration(agree[:, None].astype(np.float32))[:, 0],
    }


def table(found: dict[str, np.ndarray], k: int) -> list[str]:
    """One line per (learned intention, true intention) of the demonstrations it holds."""
    holder, true = found["holder"], found["true"]
    lines = ["learned  true  demos  logit (own)    log pi (own)   agree"]
    for learned in range(k):
        if not (holder == learned).any():
            lines.append(f"{learned:7d}     -      0  (empty)")
            continue
        for label in np.unique(true[holder == learned]):
            mine = (holder == learned) & (true == label)
            logit, log_pi = found["logit"][mine, learned], found["log_pi"][mine, learned]
            lines.append(
                f"{learned:7d}  {label:4d}  {mine.sum():5d}  "
                f"{logit.mean():+6.2f} ± {logit.std():4.2f}  "
                f"{log_pi.mean():+6.2f} ± {log_pi.std():4.2f}  {found['agree'][mine].mean():5.2f}"
            )
    return lines


def parse_args(argv=None) -> argparse.Namespace:
    parser = ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("run_dir", metavar="RUN_DIR")
    parser.add_argument("--snapshot", type=int, default=None, metavar="ITER")
    parser.add_argument(
        "--seed", type=int, default=None, help="as run --seed numbers it (default: every seed)"
    )
    return parser.parse_args(argv)


def main(argv=None) -> int:
    args = parse_args(argv)
    from emgail_jax.host.checkpoints import CheckpointError
    from emgail_jax.host.run_spec import RunError
    from emgail_jax.host.saved_run import SavedRun

    try:
        run = SavedRun.open(args.run_dir, snapshot=args.snapshot)
        if not run.algorithm.learns_posterior:
            raise RunError(f"{run.config.method.algo} learns no posterior: nothing to cluster")
        seeds = range(run.spec.seeds) if args.seed is None else [run.seed_index(args.seed)]
        for seed in seeds:
            found = signals(run, seed)
            print(f"seed {run.seed_number(seed)}, iteration {args.snapshot or run.iteration}:")
            print("\n".join(table(found, run.num_intentions)))
    except (RunError, CheckpointError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
