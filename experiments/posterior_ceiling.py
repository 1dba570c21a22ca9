"""How well can a per-pair posterior tell the intentions apart, step by step within an episode?

    python experiments/posterior_ceiling.py --env reacher --intentions 2 [--episodes 500] \
        [--demos FILE] [--run RUN_DIR] [--with-step]
    python experiments/posterior_ceiling.py --env driver --intentions 2 [--radius 4] \
        [--demo-seed 0] [--run RUN_DIR] [--with-step]

Trains a classifier (scikit-learn's MLP, tanh, the posterior's 64-64) on the hidden labels of
`--episodes` fresh episodes per intention of the experts, and scores it on the demonstrations
(the env's shipped ones, or `--demos`), overall and per step of the episode: what a posterior
could reach on these observations if it learned from the experts themselves. The classifier
sees what the posterior sees, one (observation, executed action) pair. The experts are the
shipped ones, deterministic, for an MJX env; for the driver they are the analytic expert with
its steering noise at `--radius`, as its demonstrations (generated for `--demo-seed`) are made.

With `--with-step` a second classifier sees the pair and its step within the episode, which
the posterior does not: a ceiling for a posterior that knew the time.

With `--run` (an EM-GAIL run directory with a checkpoint on the same demonstrations), the same
per-step and per-tenth accuracy of that run's own posterior (eq. 29's pair labels, matched by
the trajectory labels), and for an MJX env the two quantities its training samples depend on:
how far apart the experts' actions for different intentions are at the demonstrations' states,
and how far each learned policy's mean action is from its own expert's. For the driver, whose
expert needs the unobserved heading, each intention's mean demonstrated action by tenth, and
how far apart the learned policies' mean actions are at the demonstrations' states, with the
policies' action noise.
"""

from __future__ import annotations

import argparse
import itertools
import sys

import numpy as np

from emgail_jax.host.command_line import ArgumentParser

STEPS_SHOWN = (0, 1, 2, 3, 5, 8, 12, 20, 30, 45, 60, 80, 99)


def by_step(values: np.ndarray, step: np.ndarray) -> str:
    """The mean of ``values`` at each of STEPS_SHOWN that the episodes reach."""
    shown = [s for s in STEPS_SHOWN if (step == s).any()]
    return "  ".join(f"{s}: {values[step == s].mean():.3f}" for s in shown)


def by_tenth(values: np.ndarray, step: np.ndarray) -> str:
    """The mean of ``values`` over each tenth of the steps the episodes reach (first-last)."""
    bounds = np.linspace(0, step.max() + 1, 11).round().astype(int)
    spans = [(a, b) for a, b in itertools.pairwise(bounds) if b > a]
    return "  ".join(
        f"{a}-{b - 1}: {values[(step >= a) & (step < b)].mean():.3f}" for a, b in spans
    )


def parse_args(argv=None) -> argparse.Namespace:
    parser = ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--env", required=True)
    parser.add_argument("--intentions", type=int, required=True)
    parser.add_argument("--episodes", type=int, default=500, help="fresh episodes per intention")
    parser.add_argument("--demos", default=None, help="demonstrations file (default: shipped)")
    parser.add_argument("--run", default=None, metavar="DIR", help="an EM-GAIL run to compare")
    parser.add_argument("--radius", type=float, default=None, help="driver: radius of path 2")
    parser.add_argument("--demo-seed", type=int, default=None, help="driver: demonstration seed")
    parser.add_argument(
        "--with-step",
        action="store_true",
        help="also a classifier that sees the step within the episode (the posterior does not)",
    )
    return parser.parse_args(argv)


def _inputs(demos, with_step: bool) -> np.ndarray:
    """The classifier's input of every pair: observation and action, and the step if asked."""
    step = [demos.step_in_episode[:, None]] if with_step else []
    return np.concatenate([demos.observations, demos.actions, *step], 1)


def supervised_ceiling(
    name: str, env, demos, expert, episodes: int, with_step: bool = False
) -> dict[str, np.ndarray]:
    """Whether the supervised posterior, trained on ``episodes`` fresh episodes per intention
    of ``expert`` (``generate``'s signature), labels each demonstration pair right (printed
    overall and by step): ``{"pair": [N] bool}``, and ``"pair and step"`` with ``with_step``."""
    import jax
    from sklearn.neural_network import MLPClassifier
    from sklearn.preprocessing import StandardScaler

    from emgail_jax.method import demonstrations

    # A key the demonstrations were not drawn with (the driver's: PRNGKey(--demo-seed)).
    fresh = demonstrations.generate(env, expert, episodes, jax.random.PRNGKey(12345))
    labels, step = np.asarray(demos.intentions), demos.step_in_episode
    right = {}
    for seen in ("pair", "pair and step") if with_step else ("pair",):
        timed = seen == "pair and step"
        scaler = StandardScaler().fit(_inputs(fresh, timed))
        classifier = MLPClassifier((64, 64), activation="tanh", early_stopping=True, random_state=0)
        classifier.fit(scaler.transform(_inputs(fresh, timed)), fresh.intentions)
        predicted = classifier.predict(scaler.transform(_inputs(demos, timed)))
        right[seen] = predicted == labels
    print(
        f"{name}: {len(fresh)} fresh expert pairs; on the "
        f"{len(labels)} demonstration pairs the supervised posterior scores "
        f"{right['pair'].mean():.4f}"
    )
    print(f"  accuracy by step:                  {by_step(right['pair'], step)}")
    print(f"  by tenth of the episode:           {by_tenth(right['pair'], step)}")
    if with_step:
        given = right["pair and step"]
        print(f"  given the step too, it scores {given.mean():.4f}")
        print(f"  accuracy by step, given the step:  {by_step(given, step)}")
        print(f"  by tenth, given the step:          {by_tenth(given, step)}")
    return right


def mean_pairwise_distance(actions: list[np.ndarray]) -> np.ndarray:
    """``[N]`` the mean over pairs of intentions of ``|a_i - a_j|``, given each intention's
    actions ``[N, A]`` at the same N states."""
    k = len(actions)
    pairs = [(i, j) for i in range(k) for j in range(i + 1, k)]
    return np.mean([np.linalg.norm(actions[i] - actions[j], axis=-1) for i, j in pairs], 0)


def compare_run(run_dir: str, demos, expert=None) -> None:
    """The per-step accuracy of a run's own posterior and, given an ``expert(obs, i)`` (the
    shipped experts), how far apart the experts' actions are and how far each learned
    policy's mean action is from its own expert's. Without one (the driver's acts on whole
    states), each intention's mean demonstrated action and how far apart the learned
    policies' mean actions are at the demonstrations' states."""
    import jax.numpy as jnp

    from emgail_jax.host.saved_run import SavedRun
    from emgail_jax.method.metrics import hungarian_accuracy

    step, labels = demos.step_in_episode, np.asarray(demos.intentions)
    run = SavedRun.open(run_dir)
    k = run.num_intentions
    obs = jnp.asarray(run.demonstration_pairs.observations)
    if expert is not None:
        experts_actions = [np.asarray(expert(obs, jnp.full(obs.shape[:1], i))) for i in range(k)]
        apart = mean_pairwise_distance(experts_actions)
        print(f"  experts' actions apart (mean |a_i - a_j|): {by_step(apart, step)}")
    else:  # the driver's expert acts on whole states: its demonstrated actions, noise averaged
        for t in range(k):
            shown = by_tenth(np.asarray(demos.actions)[labels == t, 0], step[labels == t])
            print(f"  demonstrated action {t} (mean):    {shown}")
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
        print(f"    its posterior by tenth:          {by_tenth(pair_labels == own, step)}")
        policy = run.policy(seed)
        if expert is None:
            _policies_at_the_demonstrations(run, seed, policy, obs, matched, demos)
            continue
        error = np.zeros(len(labels))
        for t in range(k):
            mine = labels == t
            imitated = np.asarray(policy(obs[mine], matched[t]))
            error[mine] = np.linalg.norm(imitated - experts_actions[t][mine], axis=-1)
        print(f"    |policy - its expert| by step:   {by_step(error, step)}")


def _policies_at_the_demonstrations(run, seed, policy, obs, matched, demos) -> None:
    """How far apart ``seed``'s learned policies' mean actions are at the demonstrations'
    states (matched to the true intentions, whose demonstrated actions are printed beside),
    and the noise they act with."""
    import jax

    step, k = demos.step_in_episode, len(matched)
    apart = mean_pairwise_distance([np.asarray(policy(obs, matched[t])) for t in range(k)])
    leaves = jax.tree_util.tree_flatten_with_path(run.seed_state(seed).policy)[0]
    log_std = [np.ravel(x) for path, x in leaves if "log_std" in jax.tree_util.keystr(path)]
    noise = " ".join(f"{s:.3f}" for s in np.exp(np.concatenate(log_std)))
    print(f"    policies' mean actions apart:    {by_tenth(apart, step)}")
    print(f"    policies' action noise (std):    {noise}")


def main(argv=None) -> int:
    args = parse_args(argv)
    driver = args.env == "driver"
    for given, option in ((args.radius, "--radius"), (args.demo_seed, "--demo-seed")):
        if given is not None and not driver:
            print(f"error: {option} applies to the driver env only", file=sys.stderr)
            return 2
    if args.episodes < 1:
        print(f"error: --episodes must be at least 1; got {args.episodes}", file=sys.stderr)
        return 2
    from emgail_jax.host import jax_setup

    jax_setup.setup(host_devices=1)
    import envs
    from emgail_jax import experts
    from emgail_jax.host.demonstration_files import DemonstrationError
    from emgail_jax.host.problem import make_problem

    options = {} if args.radius is None else {"radius": args.radius}
    try:
        problem = make_problem(args.env, args.intentions, args.demos, options, args.demo_seed or 0)
    except (envs.EnvError, DemonstrationError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    env, name = problem.env, f"{args.env}-{args.intentions}"
    shipped = None  # the driver's expert acts on whole states: no action comparison
    if driver:
        # The analytic expert with its steering noise, as the demonstrations are made.
        expert, name = env.expert_policy, f"{name} radius {env.radius:g}"
    else:
        shipped = experts.load_expert_policy(env)
        if shipped is None:
            print(f"error: no shipped experts for '{args.env}'", file=sys.stderr)
            return 2
        expert = lambda state, i, _: shipped(state.obs, i)  # deterministic
    supervised_ceiling(name, env, problem.demos, expert, args.episodes, args.with_step)
    if args.run is not None:
        compare_run(args.run, problem.demos, shipped)
    return 0


if __name__ == "__main__":
    sys.exit(main())
