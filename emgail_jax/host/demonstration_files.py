"""Demonstration files: the format (docs/usage.md, "Demonstrations format"), loading with
validation, and saving.

A dataset is one ``.npz`` with

============== ============== ================================================================
key            shape          meaning
============== ============== ================================================================
observations   [N, obs_dim]   float32, raw (unnormalised)
actions        [N, act_dim]   float32
episode_starts [N]            bool, True on the first pair of each episode
intentions     [N] optional   int, hidden intention labels (used only by the metrics)
expert_returns [K] optional   true return of each intention's expert (for ERD)
rewards        [N] optional   float32, each pair's true reward under its own intention
final_obs...   [E, obs_dim]   ``final_observations``, optional: the observation after each
                              episode's last action
============== ============== ================================================================

The last two are what a Minari dataset holds beside the pairs (``minari_datasets``); training
reads neither.
"""

from __future__ import annotations

import dataclasses
import os
import zipfile

import numpy as np

import envs
from emgail_jax.method.demonstrations import Demonstrations


class DemonstrationError(ValueError):
    """The demonstrations cannot be used; the message says what is wrong and how to fix it."""


def save(demos: Demonstrations, path: str) -> None:
    """Writes the dataset atomically (a temporary file renamed into place)."""
    _write({k: v for k, v in dataclasses.asdict(demos).items() if v is not None}, path)


def add_arrays(path: str, **arrays: np.ndarray) -> None:
    """Adds ``arrays`` to the file at ``path``, atomically, every array it holds kept as stored
    (dtype and bytes)."""
    with np.load(path, allow_pickle=False) as stored:
        _write({**{k: stored[k] for k in stored.files}, **arrays}, path)


def _write(arrays: dict[str, np.ndarray], path: str) -> None:
    tmp = f"{path}.tmp.npz"
    np.savez_compressed(tmp, **arrays)
    os.replace(tmp, path)


REQUIRED = ("observations", "actions", "episode_starts")
OPTIONAL = ("intentions", "expert_returns", "rewards", "final_observations")


def _starts_like_numpy(path: str) -> bool:
    """Whether the file starts as a zip archive (.npz) or a .npy array does."""
    with open(path, "rb") as file:
        head = file.read(6)
    return head.startswith((b"PK\x03\x04", b"PK\x05\x06")) or head == b"\x93NUMPY"


def load(path: str, env: envs.Env | None = None) -> Demonstrations:
    """Reads and validates a demonstrations file; ``env`` checks it fits that env.

    Raises:
      DemonstrationError: with a one-line message naming the problem.
    """
    if not os.path.exists(path):
        raise DemonstrationError(f"demonstrations file '{path}' does not exist")
    if os.path.getsize(path) == 0:
        raise DemonstrationError(f"demonstrations file '{path}' is empty")
    if not _starts_like_numpy(path):
        # np.load takes anything else for a pickle and says so, which misleads.
        raise DemonstrationError(
            f"'{path}' is not an .npz file (not a zip archive); write it with numpy.savez"
        )
    try:
        data = np.load(path, allow_pickle=False)
    except (zipfile.BadZipFile, ValueError, OSError, EOFError) as error:
        raise DemonstrationError(
            f"'{path}' is not a readable .npz file ({error}); write it with numpy.savez"
        ) from None
    if not isinstance(data, np.lib.npyio.NpzFile):
        raise DemonstrationError(
            f"'{path}' is a single .npy array, not an .npz archive; write it with numpy.savez"
        )
    with data:
        arrays = {k: data[k] for k in data.files}
    missing = [k for k in REQUIRED if k not in arrays]
    if missing:
        raise DemonstrationError(
            f"'{path}' lacks the key(s) {', '.join(missing)}; "
            f"a demonstrations file needs {', '.join(REQUIRED)}"
        )
    for name in (*REQUIRED, *OPTIONAL):
        if name in arrays and not (
            np.issubdtype(arrays[name].dtype, np.number) or arrays[name].dtype == bool
        ):
            raise DemonstrationError(
                f"'{path}': {name} must be numeric; got dtype {arrays[name].dtype}"
            )
    demos = Demonstrations(
        observations=arrays["observations"].astype(np.float32),
        actions=arrays["actions"].astype(np.float32),
        episode_starts=arrays["episode_starts"].astype(bool),
        intentions=arrays.get("intentions"),
        expert_returns=arrays.get("expert_returns"),
        rewards=_float32(arrays.get("rewards")),
        final_observations=_float32(arrays.get("final_observations")),
    )
    validate(demos, env, source=f"'{path}'")
    return demos


def _float32(values: np.ndarray | None) -> np.ndarray | None:
    return None if values is None else values.astype(np.float32)


def validate(demos: Demonstrations, env: envs.Env | None = None, source: str = "demos") -> None:
    obs, act = demos.observations, demos.actions
    if obs.ndim != 2 or act.ndim != 2:
        raise DemonstrationError(
            f"{source}: observations and actions must be 2-D [N, dim]; "
            f"got shapes {obs.shape} and {act.shape}"
        )
    n = len(obs)
    if n == 0:
        raise DemonstrationError(f"{source} holds no state-action pairs")
    if len(act) != n or demos.episode_starts.shape != (n,):
        raise DemonstrationError(
            f"{source}: observations [N, obs_dim], actions [N, act_dim] and episode_starts [N] "
            f"must agree; got shapes {obs.shape}, {act.shape} and {demos.episode_starts.shape}"
        )
    if not demos.episode_starts[0]:
        # Else the pairs before the first start belong to no episode (all of them, if no pair
        # starts one: the trajectory E-step would take the file for one demonstration).
        raise DemonstrationError(
            f"{source}: episode_starts[0] is False, but the first pair must start an episode "
            f"({int(demos.episode_starts.sum())} of {n} pairs start one); set it True"
        )
    for name, values in (("observations", obs), ("actions", act)):
        if not np.all(np.isfinite(values)):
            raise DemonstrationError(f"{source}: {name} contain NaN or inf values")
    if demos.intentions is not None:
        labels = demos.intentions
        if labels.shape != (n,) or not np.issubdtype(labels.dtype, np.integer):
            raise DemonstrationError(f"{source}: intentions must be [N] integers")
        if labels.min() < 0:
            raise DemonstrationError(f"{source}: intentions must be non-negative labels")
    if demos.expert_returns is not None:
        returns = demos.expert_returns
        if returns.ndim != 1 or not np.all(np.isfinite(returns)):
            raise DemonstrationError(f"{source}: expert_returns must be a finite [K] vector")
        if demos.intentions is not None and len(returns) != demos.num_intentions:
            raise DemonstrationError(
                f"{source}: expert_returns has {len(returns)} entries but the labels name "
                f"{demos.num_intentions} intentions"
            )
    if demos.rewards is not None and (
        demos.rewards.shape != (n,) or not np.all(np.isfinite(demos.rewards))
    ):
        raise DemonstrationError(f"{source}: rewards must be a finite [N] vector, one per pair")
    finals = demos.final_observations
    if finals is not None and (
        finals.shape != (demos.episodes, obs.shape[1]) or not np.all(np.isfinite(finals))
    ):
        raise DemonstrationError(
            f"{source}: final_observations must be finite [episodes, obs_dim] = "
            f"[{demos.episodes}, {obs.shape[1]}]; got shape {finals.shape}"
        )
    if env is not None:
        check_dimensions(source, obs.shape[1], act.shape[1], env)
        k = demos.num_intentions
        if k is not None and k > env.max_intentions:
            raise DemonstrationError(
                f"{source}: labels name {k} intentions but env '{env.name}' has only "
                f"{env.max_intentions}"
            )


def check_dimensions(source: str, obs_dim: int, act_dim: int, env: envs.Env) -> None:
    """Refuses pairs of another observation or action layout than ``env``'s (recorded in
    another simulator, or for another env)."""
    if obs_dim != env.observation_size or act_dim != env.action_size:
        raise DemonstrationError(
            f"{source}: pairs have obs dim {obs_dim} and action dim {act_dim}, but env "
            f"'{env.name}' expects obs dim {env.observation_size} and action dim "
            f"{env.action_size}"
        )
