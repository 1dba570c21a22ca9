"""How well can a per-pair posterior tell the intentions apart, step by step within an episode?

    python experiments/posterior_ceiling.py --env reacher --intentions 2 [--episodes 500] \
        [--demos FILE] [--run RUN_DIR]

Trains a classifier (scikit-learn's MLP, tanh, the posterior's 64-64) on the hidden labels of
`--episodes` fresh deterministic episodes per intention of the shipped experts, and scores it on
the demonstrations (the env's shipped ones, or `--demos`), overall and per step of the episode:
what a posterior could reach on these observations if it learned from the experts themselves.

With `--run` (an EM-GAIL run directory with a checkpoint on the same demonstrations), the same
per-step accuracy of that run's own posterior (eq. 29's pair labels, best matching), and the two
quantities its training samples depend on: how far apart the experts' actions for different
intentions are at the demonstrations' states, and how far each learned policy's mean action is
from its own expert's (the intention matched by the trajectory labels).
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

STEPS_SHOWN = (0, 1, 2, 3, 5, 8, 12, 20, 30, 45)


def by_step(values: np.ndarray, step: np.ndarray) -> str:
    """The mean of ``values`` at each of STEPS_SHOWN that the episodes reach."""
    shown = [s for s in STEPS_SHOWN if (step == s).any()]
    return "  ".join(f"{s}: {values[step == s].mean():.3f}" for s in shown)


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--env", required=True)
    parser.add_argument("--intentions", type=int, required=True)
    parser.add_argument("--episodes", type=int, default=500, help="fresh episodes per intention")
    parser.add_argument("--demos", default=None, help="demonstrations file (default: shipped)")
    parser.add_argument("--run", default=None, metavar="DIR", help="an EM-GAIL run to compare")
    return parser.parse_args(argv)


def _pairs(demos) -> np.ndarray:
    return np.concatenate([demos.observations, demos.actions], 1)


def supervised_ceiling(name: str, env, demos, expert, episodes: int) -> np.ndarray:
    """Whether the supervised posterior, trained on ``episodes`` fresh expert episodes per
    intention, labels each demonstration pair right (printed overall and by step)."""
    import jax
    from sklearn.neural_network import MLPClassifier
    from sklearn.preprocessing import StandardScaler

    from emgail_jax.method import demonstrations

    # A key the shipped demonstrations were not drawn with.
    fresh = demonstrations.generate(
        env, lambda state, i, _: expert(state.obs, i), episodes, jax.random.PRNGKey(12345)
    )
    scaler = StandardScaler().fit(_pairs(fresh))
    classifier = MLPClassifier((64, 64), activation="tanh", early_stopping=True, random_state=0)
    classifier.fit(scaler.transform(_pairs(fresh)), fresh.intentions)
    right = classifier.predict(scaler.transform(_pairs(demos))) == np.asarray(demos.intentions)
    print(
        f"{name}: {len(fresh)} fresh expert pairs; on the "
        f"{len(right)} demonstration pairs the supervised posterior scores {right.mean():.4f}"
    )
    print(f"  accuracy by step:                  {by_step(right, demos.step_in_episode)}")
    return right


def compare_run(run_dir: str, demos, expert) -> None:
    """The per-step accuracy of a run's own posterior, how far apart the experts' actions are,
    and how far each learned policy's mean action is from its own expert's."""
    import jax.numpy as jnp

    from emgail_jax.host.saved_run import SavedRun
    from emgail_jax.method.metrics import hungarian_accuracy

    step, labels = demos.step_in_episode, np.asarray(demos.intentions)
    run = SavedRun.open(run_dir)
    k = run.num_intentions
    obs = jnp.asarray(run.demonstration_pairs.observations)
    experts_actions = [np.asarray(expert(obs, jnp.full(obs.shape[:1], i))) for i in range(k)]
    apart = np.mean(
        [
            np.linalg.norm(experts_actions[i] - experts_actions[j], axis=-1)
            for i in range(k)
            for j in range(i + 1, k)
        ],
        0,
    )
    print(f"  experts' actions apart (mean |a_i - a_j|): {by_step(apart, step)}")
    for seed in range(run.spec.seeds):
        responsibilities = run.responsibilities(seed)
        pair_labels = np.asarray(responsibilities.pair_labels)
        trajectory_labels = np.asarray(responsibilities.trajectory_labels)
        # The learned intention holding most of each true intention's demonstrations.
        matched = [
            np.bincount(trajectory_labels[labels == t], minlength=k).argmax() for t in range(k)
        ]
        own = np.asarray(matched)[labels]
        print(
            f"  run seed {seed}: accuracy (eq. 29) {hungarian_accuracy(pair_labels, labels, k):.4f}"
        )
        print(f"    its posterior by step:           {by_step(pair_labels == own, step)}")
        policy = run.policy(seed)
        error = np.zeros(len(labels))
        for t in range(k):
            mine = labels == t
            imitated = np.asarray(policy(obs[mine], matched[t]))
            error[mine] = np.linalg.norm(imitated - experts_actions[t][mine], axis=-1)
        print(f"    |policy - its expert| by step:   {by_step(error, step)}")


def main(argv=None) -> int:
    args = parse_args(argv)
    from emgail_jax.host import jax_setup

    jax_setup.setup(host_devices=1)
    from emgail_jax import experts
    from emgail_jax.host.problem import make_problem

    problem = make_problem(args.env, args.intentions, args.demos)
    expert = experts.load_expert_policy(problem.env)
    if expert is None:
        print(f"error: no shipped experts for '{args.env}'", file=sys.stderr)
        return 2
    name = f"{args.env}-{args.intentions}"
    supervised_ceiling(name, problem.env, problem.demos, expert, args.episodes)
    if args.run is not None:
        compare_run(args.run, problem.demos, expert)
    return 0


if __name__ == "__main__":
    sys.exit(main())
