"""The demonstrations of a run from its ``--demos`` sources (docs/usage.md, "Demonstrations
format").

A source is a ``.npz`` file (:mod:`~emgail_jax.host.demonstration_files`), a Minari dataset id
``minari:ID`` or a Minari dataset directory (:mod:`~emgail_jax.host.minari_datasets`). One
source is taken as it is: its labels, if it has any, are the hidden ones. Several sources are
one unlabelled mix of one intention each: source i demonstrates the env's intention i, its
index is the hidden label (used only for the clustering accuracy) and its expert return is its
episodes' mean return.
"""

from __future__ import annotations

import os
from collections.abc import Sequence

import numpy as np

import envs
from emgail_jax.host import demonstration_files, minari_datasets
from emgail_jax.host.demonstration_files import DemonstrationError
from emgail_jax.method.demonstrations import Demonstrations, mean_episode_return


def canonical(source: str) -> str:
    """The source as a run stores it: files and directories by their absolute path."""
    return source if source.startswith(minari_datasets.SCHEME) else os.path.abspath(source)


def load_one(source: str, env: envs.Env | None = None) -> Demonstrations:
    if minari_datasets.is_minari_source(source):
        return minari_datasets.read(source, env)
    return demonstration_files.load(source, env)


def load(sources: Sequence[str], env: envs.Env | None = None) -> Demonstrations:
    """The demonstrations of ``sources`` (one, or a mix of one intention each); ``env`` checks
    they fit it. Raises ``DemonstrationError`` with a one-line message."""
    if len(sources) == 1:
        return load_one(sources[0], env)
    parts = [_one_intention(source, index, env) for index, source in enumerate(sources)]
    optional = lambda name: (
        None
        if any(getattr(part, name) is None for part in parts)
        else np.concatenate([getattr(part, name) for part in parts])
    )
    demos = Demonstrations(
        observations=np.concatenate([part.observations for part in parts]),
        actions=np.concatenate([part.actions for part in parts]),
        episode_starts=np.concatenate([part.episode_starts for part in parts]),
        intentions=np.concatenate([part.intentions for part in parts]),
        expert_returns=optional("expert_returns"),
        rewards=optional("rewards"),
        final_observations=optional("final_observations"),
    )
    demonstration_files.validate(demos, env, source=" + ".join(sources))
    return demos


def _one_intention(source: str, index: int, env: envs.Env | None) -> Demonstrations:
    """One source of a mix: all its pairs labelled ``index``, its expert return ``[1]`` the
    mean return of its episodes (or the one its file gives)."""
    demos = load_one(source, env)
    held = None if demos.intentions is None else np.unique(demos.intentions)
    if held is not None and len(held) > 1:
        raise DemonstrationError(
            f"'{source}' holds {len(held)} labelled intentions; each of several --demos "
            "sources demonstrates one (or give this one alone)"
        )
    if env is not None and minari_datasets.is_minari_source(source):
        _check_recorded_intention(source, index, env)
    if demos.rewards is not None:
        returns = np.array([mean_episode_return(demos.rewards, demos.episode_starts)])
    elif demos.expert_returns is not None and held is not None:
        returns = demos.expert_returns[held]
    else:
        returns = None
    return Demonstrations(
        observations=demos.observations,
        actions=demos.actions,
        episode_starts=demos.episode_starts,
        intentions=np.full(len(demos), index, np.int32),
        expert_returns=None if returns is None else returns.astype(np.float32),
        rewards=demos.rewards,
        final_observations=demos.final_observations,
    )


def _check_recorded_intention(source: str, index: int, env: envs.Env) -> None:
    """A dataset that names its env and intention (this package's export) must stand at that
    intention's place in the list: the hidden label and the ERD's reward follow the order."""
    metadata = minari_datasets.metadata(source)
    recorded_env = metadata.get(minari_datasets.ENV_KEY)
    if recorded_env is not None and recorded_env != env.name:
        raise DemonstrationError(
            f"'{source}' was recorded in env '{recorded_env}', not '{env.name}'"
        )
    intention = metadata.get(minari_datasets.INTENTION_KEY)
    names = env.intention_names
    if intention is not None and (index >= len(names) or names[index] != intention):
        raise DemonstrationError(
            f"'{source}' demonstrates '{intention}' but stands at place {index + 1} of the "
            f"--demos sources; list them in the env's order: {', '.join(names)}"
        )
