"""Evaluate a run: roll out every learned intention, score it, and draw what it does.

    python -m emgail_jax.evaluate RUN_DIR [--episodes 10] [--seed 0]

Prints, per seed, the normalised ERD (and each true intention's share of it) with the matching
of true to learned intentions, the clustering accuracy of the posterior as training measures
it (eq. 29; in trajectory mode also the trajectory labels' accuracy), with the Hungarian mapping,
and how many demonstrations each learned intention holds (none: a collapsed intention).
Writes the same numbers to ``RUN_DIR/evaluation.json`` and figures to ``RUN_DIR/figures``:

- ``learning_curves.png``: ERD and clustering accuracy over iterations (from ``metrics.csv``);
- driver: ``paths_seed{S}.png``, the XY paths of every learned intention over the experts' paths
  and the demonstrations;
- other envs: ``traces_seed{S}.png``, the env's trace over time (x-position; the reacher's
  distance to each ball) per learned intention, against the experts' when they can be replayed.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import os
import sys

import jax
import jax.numpy as jnp
import matplotlib
import matplotlib.pyplot as plt
import numpy as np
from scipy.optimize import linear_sum_assignment

import envs
from emgail_jax.host import jax_setup, records, run_lock
from emgail_jax.host.checkpoints import CheckpointError
from emgail_jax.host.command_line import ArgumentParser
from emgail_jax.host.demonstration_files import DemonstrationError
from emgail_jax.host.run_spec import RunError
from emgail_jax.host.saved_run import SavedRun
from emgail_jax.host.schedule import FINAL_WINDOW
from emgail_jax.method.choosing import kept_share
from emgail_jax.method.metrics import normalized_erd
from emgail_jax.method.rollout import episodes as run_episodes

COLORS = ("tab:blue", "tab:orange", "tab:green", "tab:red")
EVALUATION_SEED = 12345  # the episodes' key: every evaluation of a run sees the same starts


def expert_rollouts(run, episodes: int, key):
    """The experts' episodes, when an expert can act in the env; else None."""
    raw = run.problem.env
    env = envs.EpisodeWrapper(raw)
    k = raw.num_intentions
    rows = jnp.broadcast_to(jnp.arange(k)[:, None], (k, episodes))
    if hasattr(raw, "expert_action"):
        act = lambda state, _: jax.vmap(jax.vmap(raw.expert_action))(state, rows)
    else:
        try:
            from emgail_jax.experts import load_expert_policy
        except ImportError:
            return None
        expert = load_expert_policy(raw)
        if expert is None:
            return None
        act = lambda state, _: expert(state.obs, rows)
    return jax.device_get(jax.jit(lambda key: run_episodes(env, act, key, k, episodes, True))(key))


def score(run, seed: int, returns: np.ndarray) -> dict:
    """ERD with the best matching, and the clustering accuracies as training measures them
    (with the Hungarian mapping of true intentions to clusters)."""
    demos = run.problem.demos
    mean_returns = returns.mean(1)  # [K learned, K env]
    in_use = run.intentions_in_use(seed)
    result = {
        "returns": mean_returns,
        "episodes": int(returns.shape[1]),
        "erd": None,
        "erd_per_intention": None,
        "matching": None,
    }
    if demos.expert_returns is not None:
        random_returns = run.problem.random_returns
        erd = normalized_erd(mean_returns, demos.expert_returns, random_returns, in_use)
        result["erd"] = float(erd.mean)
        result["erd_per_intention"] = np.asarray(erd.per_intention)
        result["matching"] = np.asarray(erd.matching)
    result.update(run.clustering(seed))
    if "cluster_accuracy" in result:
        responsibilities = run.responsibilities(seed)
        if in_use is not None:
            responsibilities = responsibilities.kept_only(in_use)
        counts = np.zeros((run.problem.true_intentions, run.num_intentions))
        np.add.at(counts, (demos.intentions, responsibilities.pair_labels), 1)
        result["cluster_of_intention"] = linear_sum_assignment(-counts)[1]
    if run.algorithm.learns_posterior:
        result["demonstrations_held"] = run.demonstrations_held(seed)
    if in_use is not None:
        result["intentions_chosen"] = int(in_use.sum())
    return result


def plot_learning_curves(run_dir: str, path: str) -> None:
    with open(os.path.join(run_dir, "metrics.csv")) as f:
        rows = list(csv.DictReader(f))
    seeds = sorted({int(r["seed"]) for r in rows})
    panels = [("eval/erd", "normalised ERD"), ("eval/cluster_accuracy", "clustering accuracy")]
    panels = [p for p in panels if any(r[p[0]] != "" for r in rows)]
    fig, axes = plt.subplots(1, len(panels), figsize=(5 * len(panels), 3.5), squeeze=False)
    for ax, (column, label) in zip(axes[0], panels, strict=True):
        for seed in seeds:
            mine = [r for r in rows if int(r["seed"]) == seed and r[column] != ""]
            ax.plot([int(r["iteration"]) for r in mine], [float(r[column]) for r in mine],
                    label=f"seed {seed}", lw=1)  # fmt: skip
        ax.set_xlabel("iteration")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0][0].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_intention_weights(run, path: str) -> None:
    """Each seed's mixture weights against the iteration, with the share an intention needs to
    be kept when K is chosen from the data: how ``--intentions auto`` decided. An intention
    retired at the end (too light, or a duplicate the seeds' consensus merged) is dashed."""
    weights = np.asarray(run.history["posterior/intention_weights"])  # [S, L, K]
    seeds, iterations, k = weights.shape
    fig, axes = plt.subplots(1, seeds, figsize=(3.2 * seeds, 3), sharey=True, squeeze=False)
    for seed, ax in enumerate(axes[0]):
        kept = run.intentions_in_use(seed)  # None when K was given
        for i in range(k):
            style = "-" if kept is None or kept[i] else "--"
            ax.plot(np.arange(1, iterations + 1), weights[seed, :, i], color=COLORS[i],
                    ls=style, label=f"learned {i}", lw=1.2)  # fmt: skip
        if run.config.method.choose_intentions:
            ax.axhline(kept_share(run.demonstration_pairs.episodes), color="k", ls=":", lw=1,
                       label="kept above")  # fmt: skip
            ax.axvspan(max(iterations - FINAL_WINDOW, 0), iterations, color="0.9")
        title = f"seed {run.spec.first_seed + seed}"
        if kept is not None:
            title += f": K = {kept.sum()}"
        ax.set_title(title, fontsize=9)
        ax.set_yscale("log")
        ax.set_xlabel("iteration")
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("mixture weight")
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_driver_paths(run, trace, alive, matching, path: str) -> None:
    env = run.problem.env
    demos = run.problem.demos
    fig, ax = plt.subplots(figsize=(6, 5))
    for i in range(run.problem.true_intentions):
        points = env.path_points(i)
        ax.plot(points[:, 0], points[:, 1], "--", color=COLORS[i], lw=2.5, alpha=0.5,
                label=f"expert path {i + 1}")  # fmt: skip
        if demos.intentions is not None:
            mine = demos.observations[demos.intentions == i]
            ax.scatter(mine[:, -2], mine[:, -1], s=2, color=COLORS[i], alpha=0.15)
    colors = learned_colors(matching, env.num_intentions)
    for j, color in enumerate(colors):
        for e in range(trace["x"].shape[2]):
            steps = alive[:, j, e] > 0
            ax.plot(trace["x"][steps, j, e], trace["y"][steps, j, e], color=color, lw=1,
                    label=f"learned intention {j}" if e == 0 else None)  # fmt: skip
    ax.set_aspect("equal")
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.legend(fontsize=8)
    ax.set_title(f"driver, radius {env.radius:g}: learned intentions over the experts' paths")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_traces(run, trace, alive, expert, matching, path: str) -> None:
    names = list(trace)
    k = run.num_intentions
    fig, axes = plt.subplots(1, len(names), figsize=(5 * len(names), 3.5), squeeze=False)
    colors = learned_colors(matching, k)
    for ax, name in zip(axes[0], names, strict=True):
        for j, color in enumerate(colors):
            _band(ax, trace[name][:, j], alive[:, j], color, f"learned {j}", "-")
        if expert is not None:
            _, expert_alive, expert_trace = expert
            for i in range(run.problem.true_intentions):
                _band(ax, expert_trace[name][:, i], expert_alive[:, i], COLORS[i % 4],
                      f"expert {run.problem.env.intention_names[i]}", "--")  # fmt: skip
        ax.set_xlabel("step")
        ax.set_ylabel(name)
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=8)
    fig.suptitle(f"{run.problem.env.name}: learned intentions against the experts")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def learned_colors(matching: np.ndarray | None, k: int) -> list[str]:
    """The colour of each of ``k`` learned intentions: its matched true intention's, grey for
    one left unmatched (more learned than true); in learned order without a matching."""
    if matching is None:
        return [COLORS[j % len(COLORS)] for j in range(k)]
    colors = ["0.6"] * k
    for i, j in enumerate(matching):
        colors[j] = COLORS[i % len(COLORS)]
    return colors


def _band(ax, values, alive, color, label, style):
    """Mean over episodes (while alive) with a min-max band; ``values [T, E]``."""
    masked = np.where(alive > 0, values, np.nan)
    steps = np.arange(len(values))
    with np.errstate(all="ignore"):
        ax.plot(steps, np.nanmean(masked, 1), style, color=color, label=label, lw=1.2)
        ax.fill_between(steps, np.nanmin(masked, 1), np.nanmax(masked, 1), color=color, alpha=0.15)


def seed_line(run, seed: int, result: dict) -> str:
    """One seed's scores in a line: ERD with each true intention's matched learned one, and the
    clustering accuracy with each true intention's cluster."""
    names = run.problem.env.intention_names[: run.num_intentions]
    parts = [f"seed {run.spec.first_seed + seed}:"]
    if result["erd"] is not None:
        matched = ", ".join(
            f"{names[i]} -> learned {j} ({result['returns'][j, i]:.1f} vs expert "
            f"{run.problem.demos.expert_returns[i]:.1f})"
            for i, j in enumerate(result["matching"])
        )
        parts.append(f"ERD {result['erd']:.3f} [{matched}]")
    if "cluster_accuracy" in result:
        clusters = ", ".join(
            f"{names[i]} -> cluster {c}" for i, c in enumerate(result["cluster_of_intention"])
        )
        parts.append(f"accuracy {result['cluster_accuracy']:.3f} [{clusters}]")
    if "trajectory_cluster_accuracy" in result:
        parts.append(f"trajectory accuracy {result['trajectory_cluster_accuracy']:.3f}")
    if "demonstrations_held" in result:
        held = " ".join(str(n) for n in result["demonstrations_held"])
        parts.append(f"demonstrations held per learned intention {held}")
    if "intentions_chosen" in result:
        parts.append(f"K chosen {result['intentions_chosen']}")
    return " ".join(parts)


def write_figures(
    run, run_dir: str, out: str, seed_results: tuple, seed: int, episodes: int
) -> list[str]:
    """The learning curves, and the paths (driver) or traces (MJX, beside ``episodes`` of the
    experts' own) of the run's seed numbered ``seed``, whose rollouts and scores are
    ``seed_results``."""
    os.makedirs(out, exist_ok=True)
    written = [os.path.join(out, "learning_curves.png")]
    plot_learning_curves(run_dir, written[-1])
    if "posterior/intention_weights" in run.history:  # the mixture prior
        written.append(os.path.join(out, "intention_weights.png"))
        plot_intention_weights(run, written[-1])
    _, alive, trace, result = seed_results
    if run.problem.env.name == "driver":
        written.append(os.path.join(out, f"paths_seed{seed}.png"))
        plot_driver_paths(run, trace, alive, result["matching"], written[-1])
    elif trace:
        expert = expert_rollouts(run, episodes, jax.random.PRNGKey(EVALUATION_SEED))
        if expert is None:
            print("notice: no expert to replay for this env; the traces show the learner only")
        written.append(os.path.join(out, f"traces_seed{seed}.png"))
        plot_traces(run, trace, alive, expert, result["matching"], written[-1])
    return written


def main(argv=None) -> int:
    parser = ArgumentParser(
        prog="python -m emgail_jax.evaluate", description=__doc__.split("\n")[0]
    )
    parser.add_argument("run_dir")
    parser.add_argument("--episodes", type=int, default=10, help="per learned intention")
    parser.add_argument(
        "--seed",
        type=int,
        default=None,
        help="the run seed whose figures are drawn, as run --seed numbers it (default: the first)",
    )
    parser.add_argument("--out", default=None, help="figure directory (default RUN_DIR/figures)")
    args = parser.parse_args(argv)
    jax_setup.setup(host_devices=1)
    matplotlib.use("Agg")

    with contextlib.ExitStack() as held:
        try:
            held.enter_context(run_lock.reading(args.run_dir))  # no live run writes it
            run = SavedRun.open(args.run_dir)
            drawn = run.seed_index(args.seed)
        except (RunError, CheckpointError, envs.EnvError, DemonstrationError) as error:
            print(f"error: {error}", file=sys.stderr)
            return 2
        evaluate_run(run, args, drawn)
    return 0


def evaluate_run(run: SavedRun, args: argparse.Namespace, drawn: int = 0) -> None:
    """The command's work on the opened run: every seed's deterministic episodes scored,
    ``evaluation.json`` and the figures of its ``drawn``-th seed written."""
    env = run.problem.env
    print(f"{run.spec.algo} on {env.name} (K={run.num_intentions}), iteration {run.iteration}, "
          f"{args.episodes} deterministic episodes per learned intention")  # fmt: skip
    key = jax.random.PRNGKey(EVALUATION_SEED)
    results = []
    for seed in range(run.spec.seeds):
        returns, alive, trace = run.episodes(seed, args.episodes, key, traces=True)
        result = score(run, seed, returns)
        results.append((returns, alive, trace, result))
        print(seed_line(run, seed, result))

    evaluation_path = os.path.join(args.run_dir, "evaluation.json")
    records.write_json(
        evaluation_path,
        {
            "iteration": run.iteration,
            "episodes_per_intention": args.episodes,
            "seeds": {str(run.spec.first_seed + s): r[-1] for s, r in enumerate(results)},
        },
    )

    out = args.out or os.path.join(args.run_dir, "figures")
    figures = write_figures(
        run, args.run_dir, out, results[drawn], run.seed_number(drawn), args.episodes
    )
    written = [evaluation_path, *figures]
    for path in written:
        print(f"wrote {path}")


if __name__ == "__main__":
    sys.exit(main())
