"""Experts for the MJX envs: one TRPO policy per intention, trained on its true reward, and the
demonstrations they write (format: docs/usage.md, "Demonstrations format").

    python -m emgail_jax.experts --env ENV               # train, checkpoint, score, write demos
    python -m emgail_jax.experts --env ENV --evaluate    # score the shipped experts only
    python -m emgail_jax.experts --env ENV --demos-only  # rewrite the demos from the checkpoint
    python -m emgail_jax.experts --env ENV --add-rewards  # rewards, final obs by replaying pairs
    python -m emgail_jax.experts --env ENV --export-minari [--out DIR]  # the demos as Minari

Training vmaps the intentions and runs ``--seeds`` independent seeds of each (sharded over the
host devices, so both cores work); the best seed of every intention, by its own deterministic
return over the last iterations, becomes that intention's expert. Its policy and observation
normaliser are saved with orbax under ``emgail_jax/data/experts/ENV`` (a few tens of kB), with
``meta.json`` (training settings, returns, quality). The demonstrations are the experts'
deterministic (mean-action) episodes: 5 x 500 = 2500 pairs per intention (reacher 30 x 50),
with the hidden labels, each expert's mean true return, every pair's reward and every episode's
final observation, in ``emgail_jax/data/ENV.npz``. ``--add-rewards`` adds the last two to an
``ENV.npz`` without them, every other array unchanged, by replaying each pair one step from its
observation (hopper's and halfcheetah's shipped demonstrations, which the experts no longer
reproduce on this CPU; accuracy: docs/environments.md). ``--export-minari`` writes them as Minari
datasets, one per intention (``emgail_jax.host.minari_datasets``), under ``--out`` (default: the
local Minari datasets directory, ``MINARI_DATASETS_PATH`` or ``~/.minari/datasets``).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from functools import partial
from importlib import resources

import numpy as np

from emgail_jax.host import jax_setup
from emgail_jax.host.command_line import ArgumentParser
from emgail_jax.host.expert_bars import evaluation_keys, quality


@dataclasses.dataclass(frozen=True)
class ExpertSpec:
    """How the experts of one env are trained and how many demonstrations they write."""

    iterations: int
    num_envs: int  # auto-resetting envs per intention and seed
    rollout_length: int  # steps of each per iteration
    gamma: float = 0.995
    max_kl: float = 0.01
    init_log_std: float = -0.5
    value_epochs: int = 5  # what trained the shipped experts (the IRL default is now 20)
    demo_episodes: int = 5
    eval_episodes: int = 1  # deterministic episodes per iteration for choosing the best seed


# Swimmer needs a long horizon: its reward for moving is small per step and the gait takes many
# steps to pay off, so gamma 0.995 settles on wriggling in place (as in the TRPO/PPO papers'
# swimmer settings, gamma 0.9999).
SPECS: dict[str, ExpertSpec] = {
    "swimmer": ExpertSpec(iterations=1500, num_envs=8, rollout_length=500, gamma=0.9999),
    "hopper": ExpertSpec(iterations=600, num_envs=16, rollout_length=250),
    "halfcheetah": ExpertSpec(iterations=600, num_envs=16, rollout_length=250),
    "reacher": ExpertSpec(iterations=400, num_envs=64, rollout_length=50, demo_episodes=30),
}


def data_dir() -> str:
    return str(resources.files("emgail_jax") / "data")


def checkpoint_dir(env_name: str, root: str | None = None) -> str:
    return os.path.join(os.path.abspath(root or data_dir()), "experts", env_name)


def _config(spec: ExpertSpec):
    from emgail_jax.method.config import (
        BStepConfig,
        MethodConfig,
        NetworkConfig,
        RolloutConfig,
        TRPOConfig,
    )

    return MethodConfig(
        rollout=RolloutConfig(num_envs=spec.num_envs, rollout_length=spec.rollout_length),
        networks=NetworkConfig(init_log_std=spec.init_log_std),
        b_step=BStepConfig(
            gamma=spec.gamma, value_epochs=spec.value_epochs, trpo=TRPOConfig(max_kl=spec.max_kl)
        ),
    )


def _trainer(env, spec: ExpertSpec):
    from emgail_jax.method.rl import make_rl_train

    return make_rl_train(_config(spec), env, eval_episodes=spec.eval_episodes)


def train(env, spec: ExpertSpec, seeds: int, key, progress: bool = True, intentions=None):
    """Trains ``seeds`` policies for each of ``intentions`` (indices; default all K).

    Returns ``(experts, own_returns [S, iterations, I], timings)`` where ``experts`` is
    ``{"policy", "normalizer"}`` of the best seed of every trained intention, stacked [I]."""
    import jax
    import jax.numpy as jnp

    from emgail_jax.host.progress import ProgressBar
    from emgail_jax.host.seed_runner import chunk_length, chunks, intention_runner

    trainer = _trainer(env, spec)
    intentions = jnp.arange(env.num_intentions) if intentions is None else jnp.asarray(intentions)
    k = len(intentions)
    runner = intention_runner(trainer, intentions, seeds)
    plan = chunks(0, spec.iterations, chunk_length(spec.iterations, 10))
    no_inputs = lambda first, length: np.zeros(length, bool)
    own = []
    with ProgressBar(
        f"experts {env.name}", spec.iterations, {"returns": "-"}, enabled=progress
    ) as bar:

        def after_chunk(first, length, states, metrics) -> bool:
            own.append(metrics["eval/own_return"])  # [S, chunk, K]
            latest = own[-1][:, -1].max(0)
            bar.update(length, returns=" ".join(f"{r:.1f}" for r in latest))
            return True

        states = runner.run(runner.init(key), plan, no_inputs, after_chunk)
    own = np.concatenate(own, axis=1)
    best = own[:, -10:].mean(1).argmax(0)  # [I] best seed of every intention
    states = jax.device_get(states)
    pick = lambda x: x[best, np.arange(k)]
    experts = {
        "policy": jax.tree.map(pick, states.policy),
        "normalizer": jax.tree.map(pick, states.normalizer),
    }
    return experts, own, runner.timings


def _target(env, spec: ExpertSpec):
    """Structure of ``{"policy", "normalizer"}`` stacked over all the env's intentions (what a
    checkpoint restores into; the networks do not depend on K)."""
    import jax

    trainer = _trainer(env, spec)
    keys = jax.random.split(jax.random.PRNGKey(0), env.max_intentions)
    shapes = jax.eval_shape(jax.vmap(trainer.init), keys)
    return {"policy": shapes.policy, "normalizer": shapes.normalizer}


def save(env_name: str, experts, meta: dict, root: str | None = None) -> str:
    """Writes the experts' checkpoint (orbax, atomically) and ``meta.json`` beside it."""
    import orbax.checkpoint as ocp

    from emgail_jax.host import records

    directory = checkpoint_dir(env_name, root)
    os.makedirs(directory, exist_ok=True)
    with ocp.StandardCheckpointer() as checkpointer:
        checkpointer.save(os.path.join(directory, "params"), experts, force=True)
    records.write_json(os.path.join(directory, "meta.json"), meta)
    return directory


class ExpertError(ValueError):
    """No usable expert checkpoint; the message says how to get one."""


def load(env, root: str | None = None, spec: ExpertSpec | None = None):
    """The experts of ``env`` (its first K intentions) as ``{"policy", "normalizer"}`` [K];
    ``spec`` defaults to the env's entry in :data:`SPECS`.

    Raises:
      ExpertError: no checkpoint for this env, or one that does not fit it.
    """
    import jax
    import orbax.checkpoint as ocp

    directory = checkpoint_dir(env.name, root)
    path = os.path.join(directory, "params")
    if not os.path.isdir(path):
        raise ExpertError(
            f"no experts for '{env.name}' in {directory}; train them with "
            f"`python -m emgail_jax.experts --env {env.name}`"
        )
    target = _target(env, spec or SPECS[env.name])
    try:
        with ocp.StandardCheckpointer() as checkpointer:
            experts = checkpointer.restore(path, target)
    except Exception as error:  # orbax raises many types for damaged or foreign files
        raise ExpertError(
            f"the experts' checkpoint in {path} cannot be read ({str(error)[:200]}); "
            f"retrain with `python -m emgail_jax.experts --env {env.name}`"
        ) from None
    return jax.tree.map(lambda x: x[: env.num_intentions], experts)


def make_policy(env, experts, spec: ExpertSpec | None = None):
    """``policy(obs [..., D], intention [...]) -> deterministic action [..., A]``."""
    import jax
    import jax.numpy as jnp

    from emgail_jax.method.networks import GaussianPolicy, policy_action

    config = _config(spec or SPECS[env.name])
    shape = config.networks
    net = GaussianPolicy(env.action_size, shape.hidden, shape.init_log_std)

    def mean_action(params, stats, obs):
        no_condition = jnp.zeros((*obs.shape[:-1], 0))
        return policy_action(net, params, stats, obs, no_condition, obs_clip=shape.obs_clip)

    def policy(obs, intention):
        every = jax.vmap(mean_action, in_axes=(0, 0, None))(
            experts["policy"], experts["normalizer"], obs
        )  # [K, ..., A]
        return jnp.take_along_axis(every, intention[None, ..., None], axis=0)[0]

    return policy


def load_expert_policy(env):
    """The shipped experts of ``env`` as ``policy(obs, intention)``; None if there are none."""
    try:
        return make_policy(env, load(env))
    except (ExpertError, KeyError):
        return None


def write_demos(env, policy, key, episodes: int, path: str):
    """The experts' deterministic episodes as a labelled demonstrations file (format: docs/usage.md,
    "Demonstrations format")."""
    from emgail_jax.host import demonstration_files
    from emgail_jax.method import demonstrations

    expert = lambda state, intention, _: policy(state.obs, intention)
    demos = demonstrations.generate(env, expert, episodes, key)
    demonstration_files.save(demos, path)
    return demos


def print_quality(env_name: str, results: list[dict]) -> None:
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"{env_name} experts (10 deterministic episodes each)")
    columns = ["intention", "return", "velocity", "upright", "turn", "reached", "bar", "meets_bar"]
    for column in columns:
        table.add_column(column)
    for q in results:
        cell = lambda v: "-" if v is None else (f"{v:.3f}" if isinstance(v, float) else str(v))
        table.add_row(*(cell(q.get(column)) for column in columns))
    Console(width=140).print(table)


def _replace_rows(old, new, rows: list[int]) -> np.ndarray:
    merged = np.array(old)
    merged[rows] = new
    return merged


def _intention_indices(env, names: list[str] | None) -> list[int] | None:
    if names is None:
        return None
    unknown = [name for name in names if name not in env.intention_names]
    if unknown:
        raise ValueError(
            f"'{env.name}' has no intention {', '.join(unknown)}; "
            f"its intentions are {', '.join(env.intention_names)}"
        )
    return [env.intention_names.index(name) for name in names]


def _train_and_save(env, spec: ExpertSpec, args, root: str, meta: dict, *, only, kept):
    """Trains the experts of every intention (or of the indices ``only``, taking the others
    from the saved experts ``kept``), saves them and returns them with ``meta`` updated by
    their training record."""
    import jax

    start = time.perf_counter()
    experts, own_returns, timings = train(
        env, spec, args.seeds, jax.random.PRNGKey(args.seed), not args.quiet, intentions=only
    )
    if kept is not None:
        experts = jax.tree.map(partial(_replace_rows, rows=only), kept, experts)
    trained = only if only is not None else range(env.num_intentions)
    if only is None:
        meta = {}
    meta.update(env=env.name, intentions=list(env.intention_names))
    training = meta.setdefault("training", {})
    for column, index in enumerate(trained):
        training[env.intention_names[index]] = {
            "spec": dataclasses.asdict(spec),
            "seeds": args.seeds,
            "seed": args.seed,
            "own_return_per_seed": own_returns[:, -10:, column].mean(1),
            "compile_time_s": timings.compile_s,
            "train_time_s": timings.train_s,
            "wall_time_s": time.perf_counter() - start,
        }
    save(env.name, experts, meta, root)
    return experts, meta


# A replay whose returns differ more than this from the stored expert returns is not written.
REPLAY_RETURN_TOLERANCE = 0.01


@dataclasses.dataclass(frozen=True)
class ReplayCheck:
    """How exact the replay of a set of demonstrations is (docs/environments.md)."""

    inside_pairs: int  # pairs whose next observation is recorded (all but each episode's last)
    next_observation_error: tuple[float, float]  # max and mean |replayed - recorded| over them
    unclipped_pairs: int  # of those, the pairs neither of whose observations is at the clip
    unclipped_error: tuple[float, float]  # max and mean over the unclipped pairs
    at_velocity_clip: int  # observations with a velocity at the observation's clip
    last_pairs_at_clip: int  # of those, the episodes' last pairs (their final observation)
    terminations_matched: bool  # the replay ends the episodes that ended early, and no other
    replayed_returns: np.ndarray  # [K] the mean episode return of the replayed rewards
    expert_returns: np.ndarray | None  # [K] the stored ones

    @property
    def worst_return_gap(self) -> float:
        """The largest relative gap of a replayed return from its stored one (0 if none)."""
        if self.expert_returns is None:
            return 0.0
        gap = np.abs(self.replayed_returns - self.expert_returns) / np.abs(self.expert_returns)
        return float(gap.max())


def replayed_rewards(env, demos):
    """``(rewards [N], final_observations [E, D], check)``: each pair's reward under its own
    intention and each episode's final observation, from a one-step replay of every pair
    (``method.demonstrations.replay``) in ``env`` (rewarding every labelled intention), and
    how well the replay reproduces what is recorded."""
    from emgail_jax.method import demonstrations

    replay = demonstrations.replay(env, demos)
    rewards = replay.rewards[np.arange(len(demos)), demos.intentions].astype(np.float32)
    last = np.append(demos.episode_starts[1:], True)  # [N] the last pair of its episode
    finals = replay.next_observations[last].astype(np.float32)
    error = np.abs(replay.next_observations[:-1] - demos.observations[1:])[~last[:-1]]
    velocities = demos.observations[:, env.mj_model.nq - env.position_dims :]
    clipped = np.any(np.abs(velocities) >= env.obs_max_velocity, axis=1)
    unclipped = ~(clipped[:-1] | clipped[1:])[~last[:-1]]
    ended_early = np.diff([*np.flatnonzero(demos.episode_starts), len(demos)])
    ended_early = ended_early < env.episode_length
    returns = [
        demonstrations.mean_episode_return(rewards[own], demos.episode_starts[own])
        for own in (demos.intentions == i for i in range(demos.num_intentions))
    ]
    spread = lambda e: (float(e.max()), float(e.mean())) if e.size else (0.0, 0.0)
    check = ReplayCheck(
        inside_pairs=len(error),
        next_observation_error=spread(error),
        unclipped_pairs=int(unclipped.sum()),
        unclipped_error=spread(error[unclipped]),
        at_velocity_clip=int(clipped.sum()),
        last_pairs_at_clip=int(clipped[last].sum()),
        terminations_matched=bool(replay.done[last][ended_early].all())
        and not replay.done[~last].any(),
        replayed_returns=np.array(returns, np.float32),
        expert_returns=demos.expert_returns,
    )
    return rewards, finals, check


def print_replay_check(env_name: str, check: ReplayCheck) -> None:
    print(
        f"{env_name}: replayed {check.inside_pairs} pairs against their recorded next "
        f"observation: max |error| {check.next_observation_error[0]:.3g}, mean "
        f"{check.next_observation_error[1]:.3g}; {check.unclipped_pairs} pairs with no velocity "
        f"at the clip: max {check.unclipped_error[0]:.3g}, mean {check.unclipped_error[1]:.3g}"
    )
    print(
        f"{env_name}: {check.at_velocity_clip} observations with a velocity at the clip "
        f"({check.last_pairs_at_clip} of them an episode's last); terminations "
        f"{'as recorded' if check.terminations_matched else 'NOT as recorded'}"
    )
    stored = check.expert_returns
    for i, replayed in enumerate(check.replayed_returns):
        line = f"{env_name}: intention {i} mean return replayed {replayed:.4f}"
        if stored is not None:
            gap = (replayed - stored[i]) / abs(stored[i])
            line += f", stored {stored[i]:.4f} ({gap:+.2e})"
        print(line)


def add_rewards(env, root: str) -> int:
    """Adds ``rewards`` and ``final_observations`` to ``ROOT/ENV.npz`` from a one-step replay of
    every pair, every other array unchanged; writes nothing when the replayed returns are more
    than :data:`REPLAY_RETURN_TOLERANCE` from the stored ones."""
    from emgail_jax.host import demonstration_files

    path = os.path.join(root, f"{env.name}.npz")
    try:
        demos = demonstration_files.load(path, env)
    except demonstration_files.DemonstrationError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    if demos.rewards is not None or demos.final_observations is not None:
        print(f"error: {path} already carries rewards or final_observations", file=sys.stderr)
        return 2
    if env.position_dims is None:
        print(
            f"error: {env.name}'s observations do not give back its state, so {path} cannot be "
            f"replayed; `python -m emgail_jax.experts --env {env.name} --demos-only` rewrites "
            "it from the experts with both arrays",
            file=sys.stderr,
        )
        return 2
    if demos.intentions is None:
        print(
            f"error: {path} has no intentions, which say whose reward a pair earns", file=sys.stderr
        )
        return 2
    rewards, finals, check = replayed_rewards(env, demos)
    print_replay_check(env.name, check)
    if check.worst_return_gap > REPLAY_RETURN_TOLERANCE:
        why = (
            f"its returns are up to {check.worst_return_gap:.2%} from the stored ones, more "
            f"than {REPLAY_RETURN_TOLERANCE:.0%}"
        )
    elif not check.terminations_matched:
        why = "its terminations differ from the recording's"
    else:
        demonstration_files.add_arrays(path, rewards=rewards, final_observations=finals)
        print(f"added rewards [{len(rewards)}], final_observations {list(finals.shape)} to {path}")
        return 0
    print(f"error: the replay does not reproduce {path}: {why}; nothing written", file=sys.stderr)
    return 2
    print(f"added rewards [{len(rewards)}] and final_observations {list(finals.shape)} to {path}")
    return 0


def export_minari(env, out: str | None) -> int:
    """Writes the shipped demonstrations of ``env`` as Minari datasets under ``out``."""
    from emgail_jax.host import demonstration_files, minari_datasets
    from emgail_jax.host.problem import shipped_demos_path

    root = os.path.abspath(out) if out else minari_datasets.datasets_root()
    try:
        demos = demonstration_files.load(shipped_demos_path(env.name), env)
        ids = minari_datasets.write(demos, env, root)
    except demonstration_files.DemonstrationError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    for identifier in ids:
        print(f"wrote minari:{identifier} under {root}")
    return 0


def parse_args(argv=None) -> argparse.Namespace:
    parser = ArgumentParser(prog="python -m emgail_jax.experts", description=__doc__.split("\n")[0])
    parser.add_argument("--env", required=True, choices=sorted(SPECS))
    parser.add_argument("--seeds", type=int, default=2, help="seeds per intention; best kept")
    parser.add_argument("--iterations", type=int, default=None, help="default: the env's spec")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--out",
        default=None,
        help="data root (default: the package's data; --add-rewards rewrites its ENV.npz); "
        "with --export-minari the Minari "
        "datasets directory (default: MINARI_DATASETS_PATH, else ~/.minari/datasets)",
    )
    parser.add_argument(
        "--only",
        nargs="+",
        metavar="INTENTION",
        help="retrain only these intentions (names), keeping the other saved experts",
    )
    what = parser.add_mutually_exclusive_group()
    what.add_argument("--evaluate", action="store_true", help="only score the saved experts")
    what.add_argument("--demos-only", action="store_true", help="rewrite demos from the checkpoint")
    what.add_argument(
        "--add-rewards",
        action="store_true",
        help="add each pair's reward and each episode's final observation to ENV.npz by "
        "replaying every pair one step (hopper, halfcheetah); every other array unchanged",
    )
    what.add_argument(
        "--export-minari",
        action="store_true",
        help="write the shipped demonstrations as Minari datasets, one per intention",
    )
    parser.add_argument("--quiet", action="store_true")
    return parser.parse_args(argv)


def main(argv=None) -> int:
    args = parse_args(argv)
    if args.seeds < 1 or (args.iterations is not None and args.iterations < 1):
        print("error: --seeds and --iterations must be at least 1", file=sys.stderr)
        return 2
    jax_setup.setup()

    import envs
    from emgail_jax.host import records

    env = envs.make(args.env)
    if args.export_minari:
        return export_minari(env, args.out)
    if args.add_rewards:
        return add_rewards(env, os.path.abspath(args.out or data_dir()))
    spec = SPECS[args.env]
    if args.iterations:
        spec = dataclasses.replace(spec, iterations=args.iterations)
    root = os.path.abspath(args.out or data_dir())
    key_quality, key_demos = evaluation_keys()
    meta_path = os.path.join(checkpoint_dir(env.name, root), "meta.json")
    meta = {}
    if os.path.exists(meta_path):
        with open(meta_path) as f:
            meta = json.load(f)
    try:
        experts, meta = _experts(env, spec, args, root, meta)
    except ExpertError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    policy = make_policy(env, experts)
    results = quality(env, policy, key_quality)
    print_quality(env.name, results)
    if not args.evaluate:
        path = os.path.join(root, f"{env.name}.npz")
        demos = write_demos(env, policy, key_demos, spec.demo_episodes, path)
        meta.update(quality=results, demo_pairs=len(demos), demo_returns=demos.expert_returns)
        records.write_json(meta_path, meta)
        print(f"wrote {len(demos)} pairs to {path}; expert returns {demos.expert_returns}")
    return 0


def _experts(env, spec: ExpertSpec, args: argparse.Namespace, root: str, meta: dict):
    """``(experts, meta)``: the saved experts (``--evaluate``, ``--demos-only``) or new ones,
    trained and saved (those of ``--only``, the others kept)."""
    if args.evaluate or args.demos_only:
        return load(env, root), meta
    try:
        only = _intention_indices(env, args.only)
    except ValueError as error:  # an unknown intention name
        raise ExpertError(str(error)) from None
    kept = load(env, root) if only is not None else None
    return _train_and_save(env, spec, args, root, meta, only=only, kept=kept)


if __name__ == "__main__":
    sys.exit(main())
