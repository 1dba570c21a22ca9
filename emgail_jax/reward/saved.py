"""A refitted reward saved in its run's directory: ``RUN/rewards/NAME/seed-S.msgpack`` (the
discriminator's parameters of the run's seed S), ``seed-S.json`` (the refit's losses and time)
beside ``reward.json`` (the refit's options and the networks it was made from), so that
``load_reward(RUN, refit=NAME)`` returns it and a later check (another RL seed, reward form or
changed env) reuses it rather than refitting (:func:`saved_or_refitted`).
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import asdict

import jax
import numpy as np

from emgail_jax.host import checkpoints, records
from emgail_jax.host.run_spec import RunError
from emgail_jax.reward.refit import (
    Refit,
    consolidated_parameters,
    new_discriminator_weights,
    snapshot_policy_samples,
    snapshots_used,
)

# Refit options deleted since refits were first saved, at the one value a refit still has: a
# reward.json saved before reads as this refit, and a check records its refit as before.
RETIRED_OPTIONS = {"agent_rounds": 0, "state_only": False}


def saved_or_refitted(run, seeds: list[int], refit: Refit, name: str, progress: bool = True):
    """Every seed's refitted reward parameters and the refit's losses; each seed's refit is
    read from the run's saved reward ``name`` when it was made before, and made and saved
    there when not.

    Raises:
      RunError: a reward ``name`` saved with other options.
      CheckpointError: one refitted from the networks of another iteration than ``run``'s.
    """
    description = refit_description(refit, run.snapshot, run.snapshot or run.iteration)
    saved_before = name in saved_refits(run.run_dir)
    if saved_before:
        check_refitted_from(run, name)
    if saved_before and read_description(run.run_dir, name) != description:
        raise RunError(
            f"the saved reward '{name}' of '{run.run_dir}' was refitted otherwise: "
            "delete its directory under rewards/ to refit it"
        )
    parameters, metrics = [], []
    for seed in seeds:
        number = run.seed_number(seed)
        found = saved_parameters(run, name, seed)
        if found is not None:
            losses = read_losses(run.run_dir, name, number)
            if progress:
                print(f"seed {number}: the refitted reward '{name}' saved before, reused")
        else:
            found, losses = _refitted(run, seed, refit, progress)
            save_refitted(run.run_dir, name, number, found["discriminator"], description, losses)
        parameters.append(found)
        metrics.append({"run_seed": number, **asdict(refit), **RETIRED_OPTIONS, **losses})
    return parameters, metrics


def _refitted(run, seed: int, refit: Refit, progress: bool) -> tuple[dict, dict]:
    """``seed``'s refit (:func:`consolidated_parameters`, its key the seed's number's) and its
    losses with the seconds it took; with ``progress``, a bar of its steps and a line when
    its samples are drawn and when it is done."""
    from emgail_jax.host.progress import ProgressBar

    started = time.monotonic()
    number = run.seed_number(seed)
    key = jax.random.PRNGKey(number + 2000)
    samples = snapshot_policy_samples(run, seed, key)
    if progress:
        print(
            f"refit seed {number}: one rollout of each of {len(snapshots_used(run))} "
            f"snapshots, {samples[0].shape[1]} samples per intention, "
            f"{time.monotonic() - started:.0f} s; {refit.steps} steps to go",
            flush=True,
        )
    label = f"refit seed {number}"
    with ProgressBar(label, refit.steps, {"loss": "-"}, enabled=progress) as bar:
        shown = lambda steps, metrics: bar.update(
            steps, loss=f"{float(metrics['discriminator/loss']):.3f}"
        )
        found, losses = consolidated_parameters(
            run, seed, refit, key, samples=samples, on_steps=shown if progress else None
        )
    # What this seed's refit cost, compiles included: the sweep's estimate reads it.
    seconds = time.monotonic() - started
    if progress:
        print(f"refit seed {number}: done, {seconds:.0f} s", flush=True)
    return found, {**losses, "seconds": seconds}


def rewards_directory(run_dir: str) -> str:
    return os.path.join(os.path.abspath(run_dir), "rewards")


def saved_refits(run_dir: str) -> list[str]:
    """The names of the refitted rewards saved in ``run_dir``, in order."""
    root = rewards_directory(run_dir)
    if not os.path.isdir(root):
        return []
    names = os.listdir(root)
    return sorted(n for n in names if os.path.exists(os.path.join(root, n, "reward.json")))


def _seed_path(run_dir: str, name: str, number: int) -> str:
    """The file of the run's seed ``number`` (as ``run --seed`` numbered it)."""
    return os.path.join(rewards_directory(run_dir), name, f"seed-{number}.msgpack")


def save_refitted(
    run_dir: str, name: str, number: int, discriminator, description: dict, losses: dict
) -> None:
    """Writes the refitted discriminator parameters of the run's seed ``number`` (as ``run
    --seed`` numbered it) as the saved reward ``name``, with
    ``description`` (``reward.json``: :func:`refit_description`) and
    the refit's ``losses`` (``seed-S.json``); each file renamed into place once written."""
    directory = os.path.join(rewards_directory(run_dir), name)
    os.makedirs(directory, exist_ok=True)
    path = _seed_path(run_dir, name, number)
    checkpoints.write_tree(path, jax.device_get(discriminator))
    records.write_json(path.removesuffix(".msgpack") + ".json", losses)
    records.write_json(os.path.join(directory, "reward.json"), description)


def read_losses(run_dir: str, name: str, number: int) -> dict:
    """The refit's losses of the run's seed ``number`` saved with the reward ``name`` (empty
    if none)."""
    path = _seed_path(run_dir, name, number).removesuffix(".msgpack") + ".json"
    if not os.path.exists(path):
        return {}
    with open(path) as f:
        return json.load(f)


def refit_description(refit: Refit, snapshot: int | None, iteration: int) -> dict:
    """What ``reward.json`` says of a saved refit: its options, the snapshot whose networks
    (observation statistics, posterior) the reward reads beside the refit (None: the final
    ones), and the iteration of those networks, so that a run resumed since is not read with
    the refit of its earlier networks."""
    return {"refit": asdict(refit), "snapshot": snapshot, "iteration": iteration}


def read_description(run_dir: str, name: str) -> dict:
    """The ``reward.json`` of the saved reward ``name``, its refit's options completed with the
    defaults of those added since it was saved.

    Raises:
      CheckpointError: ``run_dir`` saved no reward of that name (the message lists those it did).
    """
    path = os.path.join(rewards_directory(run_dir), name, "reward.json")
    if not os.path.exists(path):
        saved = ", ".join(saved_refits(run_dir)) or "none; python -m emgail_jax.refit saves one"
        raise checkpoints.CheckpointError(
            f"'{run_dir}' saved no refitted reward '{name}' (saved: {saved})"
        )
    with open(path) as f:
        description = json.load(f)
    # Refits saved before the iteration was recorded: a snapshot's is its iteration, the final
    # networks' is unknown (None).
    iteration = description.get("iteration", description["snapshot"])
    options = dict(description["refit"])
    for option, value in RETIRED_OPTIONS.items():
        if options.pop(option, value) != value:
            raise checkpoints.CheckpointError(
                f"the saved reward '{name}' of '{run_dir}' was refitted with {option}, an "
                "option since deleted: delete its directory under rewards/ to refit it"
            )
    return {**description, "refit": asdict(Refit(**options)), "iteration": iteration}


def check_refitted_from(run, name: str) -> None:
    """Raises CheckpointError unless the saved reward ``name`` was refitted from the networks
    ``run`` holds (a run resumed since has others)."""
    refitted_from = read_description(run.run_dir, name)["iteration"]
    networks = run.snapshot or run.iteration
    if refitted_from != networks:
        of = "an unrecorded iteration" if refitted_from is None else f"iteration {refitted_from}"
        raise checkpoints.CheckpointError(
            f"the saved reward '{name}' of '{run.run_dir}' was refitted from the networks of "
            f"{of}, not those of iteration {networks}: delete "
            f"{os.path.join(rewards_directory(run.run_dir), name)} to refit it"
        )


def saved_parameters(run, name: str, seed: int) -> dict | None:
    """:meth:`SavedRun.reward_parameters` of ``seed`` with the discriminator of the saved
    refitted reward ``name``; None when that seed was not refitted under that name.

    Raises:
      CheckpointError: a file that cannot be read or does not fit the run's discriminator,
        or one refitted from the networks of another iteration than ``run``'s.
    """
    path = _seed_path(run.run_dir, name, run.seed_number(seed))
    if not os.path.exists(path):
        return None
    check_refitted_from(run, name)
    saved = checkpoints.read_tree(path, discriminator_shapes(run), "the reward")
    return {**run.reward_parameters(seed), "discriminator": saved}


def discriminator_shapes(run) -> dict:
    """Zeros in the shapes of ``run``'s discriminator network, not of the run's own weights:
    a refit with absorbing states reads one input more than a run trained without them."""
    shapes = jax.eval_shape(lambda key: new_discriminator_weights(run, key), jax.random.PRNGKey(0))
    return jax.tree.map(lambda x: np.zeros(x.shape, x.dtype), shapes)


def run_to_refit(run, refit: Refit):
    """``run`` as ``refit`` reads it: with absorbing states if the refit learns them.

    Raises:
      RunError: an absorbing refit from the run's own weights, trained without them.
    """
    if not refit.absorbing:
        return run
    if not (refit.fresh or run.trained_with_absorbing_states):
        raise RunError(
            "consolidate_absorbing needs consolidate_fresh=true: the run's discriminator was "
            "trained without absorbing states"
        )
    return run.with_absorbing_states()
