"""The reward a run hands its user: ``RUN/reward/``, written by ``python -m emgail_jax.refit``.

``seed-S.msgpack`` holds everything the reward of the run's seed S reads (as ``run --seed``
numbered it): the refitted discriminator, the posterior, the observation statistics and, where
episodes may end early and the refit learnt absorbing states, what a termination is paid per
step left (``absorbing_price [K]``). ``reward.json`` says how to read them: the reward form,
the termination, where the normalisation is, the refit's recipe, the snapshots it learnt from,
the seconds it took and the seeds. ``load_reward(RUN)`` returns it, and a check can read it
(:func:`opened`, :func:`parameters`); the refit it was made from stays in ``RUN/rewards/NAME``.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil

import jax
import jax.numpy as jnp
import numpy as np

from emgail_jax.host import checkpoints, records
from emgail_jax.host.run_spec import RunError
from emgail_jax.reward import saved
from emgail_jax.reward.refit import random_actions_reward, snapshots_used

DIRECTORY = "reward"
FORMAT = 1
# The entry of a seed's parameters that holds its termination's price, as the check's
# ``absorbing_reward=random`` parameters do (refit.priced_absorbing_reward reads it).
PRICE = "absorbing_price"


@dataclasses.dataclass(frozen=True)
class Reading:
    """How a refit is read: its reward ``form`` (``REWARD_FORMS``) and what a termination is
    paid per step left, ``price`` ``learned`` (the absorbing state's own reward) or ``random``
    (what random actions earn under the reward); None: a refit without absorbing states,
    whose episodes simply end."""

    form: str
    price: str | None = None


def directory(run_dir: str) -> str:
    return os.path.join(os.path.abspath(run_dir), DIRECTORY)


def exists(run_dir: str) -> bool:
    """Whether ``run_dir`` holds a saved reward (``RUN/reward/reward.json``)."""
    return os.path.exists(os.path.join(directory(run_dir), "reward.json"))


def termination_values(run, seed_parameters: dict, price: str | None) -> np.ndarray | None:
    """``[K]`` what a termination is paid per step left under ``run``'s reward (opened as the
    reward is read) of ``seed_parameters``, at ``price`` (:class:`Reading`); None without."""
    if price is None:
        return None
    if price == "random":
        return random_actions_reward(run, seed_parameters, run.reward_function())
    learned = run.absorbing_reward_function()
    if learned is None:
        raise RunError("a learned termination price needs a reward with an absorbing state")
    return np.asarray(learned(seed_parameters, jnp.arange(run.num_intentions)))


def read_as(run, reading: Reading, absorbing: bool):
    """``run`` as a refit (with absorbing states if it learnt them) is read by ``reading``."""
    run = run.with_absorbing_states() if absorbing else run
    return run.with_reward_form(reading.form)


def write(run, name: str, reading: Reading, recipe: dict) -> str:
    """Writes ``RUN/reward/`` from every seed of ``run`` refitted as the saved reward ``name``
    (``RUN/rewards/NAME``, ``run`` opened as it was refitted), read by ``reading``, made with
    the settings ``recipe``; the directory, replaced whole once written."""
    description = saved.read_description(run.run_dir, name)
    absorbing = description["refit"]["absorbing"]
    as_read = read_as(run, reading, absorbing)
    target = directory(run.run_dir)
    staging = target + ".tmp"
    shutil.rmtree(staging, ignore_errors=True)
    os.makedirs(staging)
    seeds, seconds, termination = [], {}, {}
    for seed in range(run.spec.seeds):
        found = saved.saved_parameters(run, name, seed)
        if found is None:
            continue
        number = run.seed_number(seed)
        price = termination_values(as_read, found, reading.price)
        if price is not None:
            found = {**found, PRICE: price}
            termination[str(number)] = price
        stored = {key: value for key, value in found.items() if value is not None}
        checkpoints.write_tree(os.path.join(staging, f"seed-{number}.msgpack"), stored)
        seeds.append(number)
        seconds[str(number)] = saved.read_losses(run.run_dir, name, number).get("seconds")
    description = {
        "format": FORMAT,
        "source": "refit",
        "form": reading.form,
        "termination": _termination(as_read, reading, termination),
        "observation_normalisation": {
            "stored": "seed-S.msgpack, under 'normalizer' (mean, var, count)",
            "clip": as_read.config.method.networks.obs_clip,
        },
        "recipe": recipe,
        "refit": description["refit"],
        "saved_reward": name,
        "networks": {"snapshot": description["snapshot"], "iteration": description["iteration"]},
        "snapshots": snapshots_used(run),
        "seconds": seconds,
        "seeds": seeds,
    }
    records.write_json(os.path.join(staging, "reward.json"), description)
    shutil.rmtree(target, ignore_errors=True)
    os.replace(staging, target)
    return target


def _termination(run, reading: Reading, values: dict) -> dict | None:
    """``reward.json``'s termination: the price and, per seed, its ``[K]`` values."""
    if reading.price is None:
        return None
    return {
        "price": reading.price,
        "per_step_left": values,
        "paid": "at a termination before the time limit, for every step left, discounted "
        "as the agent's return is (sum of gamma^j, j = 1 .. steps left)",
        "episode_length": run.problem.env.episode_length,
    }


def read(run_dir: str) -> dict:
    """``RUN/reward/reward.json``.

    Raises:
      RunError: ``run_dir`` holds no saved reward.
    """
    path = os.path.join(directory(run_dir), "reward.json")
    if not os.path.exists(path):
        raise RunError(
            f"'{run_dir}' has no refitted reward: python -m emgail_jax.refit {run_dir} makes one"
        )
    with open(path) as f:
        return json.load(f)


def opened(run_dir: str, reward_form: str | None = None):
    """``(run, description)``: the run opened as its saved reward is read (absorbing states
    if it learnt them, its form or ``reward_form``), and its ``reward.json``."""
    from emgail_jax.host.saved_run import SavedRun

    description = read(run_dir)
    run = SavedRun.open(run_dir)
    reading = Reading(reward_form or description["form"])
    return read_as(run, reading, description["refit"]["absorbing"]), description


def parameters(run, description: dict, seed: int) -> dict:
    """What ``run``'s reward function (:func:`opened`) reads of ``seed`` (an index of the
    run's seeds), from ``seed-S.msgpack``; with the termination's price (:data:`PRICE`) where
    the reward has one.

    Raises:
      RunError: the saved reward holds no such seed.
      CheckpointError: a file that cannot be read or does not fit the run's networks.
    """
    number = run.seed_number(seed)
    if number not in description["seeds"]:
        raise RunError(
            f"the saved reward of '{run.run_dir}' has no seed {number} (it has "
            f"{description['seeds']}): python -m emgail_jax.refit {run.run_dir} refits every seed"
        )
    template = {**run.reward_parameters(seed), "discriminator": saved.discriminator_shapes(run)}
    if description["termination"] is not None:
        template[PRICE] = np.zeros(run.num_intentions, np.float32)
    present = {key: value for key, value in template.items() if value is not None}
    path = os.path.join(directory(run.run_dir), f"seed-{number}.msgpack")
    found = checkpoints.read_tree(path, present, "the reward")
    return {**dict.fromkeys(template), **jax.tree.map(jnp.asarray, found)}
