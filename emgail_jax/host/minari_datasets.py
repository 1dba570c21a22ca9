"""Minari datasets (Farama's standard offline format) as demonstrations, read and written.

A Minari episode holds observations ``[T + 1, obs_dim]`` (the last one follows the last action
and belongs to no pair), actions ``[T, act_dim]``, rewards, terminations and truncations
``[T]`` and infos. Read, its ``T`` pairs become one demonstration, its rewards the pairs'
rewards and its last observation the demonstration's final one; ``infos["intention"]`` (``[T]``
or ``[T + 1]`` integers), where a dataset carries it, labels the pairs. Written
(:func:`write`), every intention of a labelled set becomes one dataset
``emgail/ENV/INTENTION-v0`` (Minari's ``namespace/env/name-vN`` convention) with the intention
named in the dataset's metadata (:data:`INTENTION_KEY`).

A source names a dataset as ``minari:ID`` (under the local Minari datasets directory,
``MINARI_DATASETS_PATH`` or ``~/.minari/datasets``) or as its directory.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import warnings

import numpy as np

import envs
from emgail_jax.host.demonstration_files import DemonstrationError, check_dimensions, validate
from emgail_jax.method.demonstrations import Demonstrations, mean_episode_return

SCHEME = "minari:"
NAMESPACE = "emgail"
INTENTION_KEY = "intention"  # dataset metadata: the name of the intention it demonstrates
ENV_KEY = "emgail_env"  # dataset metadata: the env of this package it was recorded in
METADATA_FILE = "metadata.json"


def is_minari_source(source: str) -> bool:
    return source.startswith(SCHEME) or os.path.isdir(source)


def datasets_root() -> str:
    """Where ``minari:ID`` sources are looked up and datasets written by default: Minari's
    own choice (``MINARI_DATASETS_PATH``, else ``~/.minari/datasets``)."""
    from minari.storage import get_dataset_path

    return str(get_dataset_path())


def dataset_id(env_name: str, intention: str) -> str:
    return f"{NAMESPACE}/{env_name}/{intention}-v0"


def data_path(source: str) -> str:
    """The directory holding a source's ``metadata.json`` (Minari's ``DATASET/data``)."""
    if source.startswith(SCHEME):
        from minari.dataset.minari_dataset import parse_dataset_id

        name = source[len(SCHEME) :]
        try:
            parse_dataset_id(name)
        except ValueError:
            raise DemonstrationError(
                f"'{source}': a Minari dataset id is (NAMESPACE/)NAME-vVERSION, e.g. "
                f"minari:{dataset_id('swimmer', 'forward')}"
            ) from None
        path = os.path.join(datasets_root(), name, "data")
        if not os.path.isdir(path):
            raise DemonstrationError(
                f"no Minari dataset '{name}' in {datasets_root()} (MINARI_DATASETS_PATH): "
                f"download it with `minari download {name}` or give its directory"
            )
        return path
    inner = os.path.join(source, "data")
    if os.path.exists(os.path.join(inner, METADATA_FILE)):
        return inner
    if os.path.exists(os.path.join(source, METADATA_FILE)):
        return source
    raise DemonstrationError(
        f"'{source}' is not a Minari dataset directory (it has no {METADATA_FILE}, nor "
        f"data/{METADATA_FILE})"
    )


def metadata(source: str) -> dict:
    """The dataset's metadata as stored (``metadata.json``)."""
    from minari.dataset.minari_storage import MinariStorage

    with _readable(source):
        return MinariStorage.read_raw_metadata(data_path(source))


@contextlib.contextmanager
def _readable(source: str):
    """Turns whatever Minari, h5py or gymnasium raise on a malformed dataset into one line."""
    try:
        yield
    except DemonstrationError:
        raise
    except ImportError as error:  # a storage backend not installed (pyarrow for arrow datasets)
        raise DemonstrationError(f"'{source}': {error}") from None
    # Minari checks its files with asserts and lets h5py's and json's errors through.
    except (ValueError, KeyError, TypeError, AssertionError, OSError, AttributeError) as error:
        message = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise DemonstrationError(
            f"'{source}' is not a readable Minari dataset ({message})"
        ) from None


def read(source: str, env: envs.Env | None = None) -> Demonstrations:
    """The demonstrations of one Minari dataset; ``env`` checks they fit that env.

    Labels come from ``infos["intention"]`` where every episode carries them, and then each
    label's expert return is the mean return of its episodes. Raises ``DemonstrationError``
    with a one-line message.
    """
    import gymnasium
    import minari

    with _readable(source):
        dataset = minari.MinariDataset(data_path(source))
        spaces = {"observation": dataset.observation_space, "action": dataset.action_space}
        for name, space in spaces.items():
            if not (isinstance(space, gymnasium.spaces.Box) and len(space.shape) == 1):
                raise DemonstrationError(
                    f"'{source}': the {name} space must be a flat Box vector; got {space}"
                )
        if env is not None:
            obs_dim, act_dim = (space.shape[0] for space in spaces.values())
            check_dimensions(f"'{source}'", obs_dim, act_dim, env)
        episodes = [_episode(source, index, e) for index, e in enumerate(dataset)]
    if not episodes:
        raise DemonstrationError(f"'{source}' holds no episodes")
    obs, actions, rewards, finals, labels = zip(*episodes, strict=True)
    starts = [np.arange(len(a)) == 0 for a in actions]
    demos = Demonstrations(
        observations=np.concatenate(obs).astype(np.float32),
        actions=np.concatenate(actions).astype(np.float32),
        episode_starts=np.concatenate(starts),
        rewards=np.concatenate(rewards).astype(np.float32),
        final_observations=np.stack(finals).astype(np.float32),
    )
    labelled = [label is not None for label in labels]
    if any(labelled) and not all(labelled):
        raise DemonstrationError(
            f"'{source}': {sum(labelled)} of {len(labels)} episodes carry infos['intention']; "
            "label every episode or none"
        )
    if all(labelled):
        demos = _labelled(source, demos, labels)
    validate(demos, env, source=f"'{source}'")
    return demos


def _episode(source: str, index: int, episode):
    """``(observations [T], actions [T], rewards [T], final observation, labels [T] or None)``
    of one Minari episode."""
    actions = np.asarray(episode.actions)
    observations = np.asarray(episode.observations)
    rewards = np.asarray(episode.rewards)
    where = f"'{source}' episode {index}"
    steps = len(actions)
    if steps == 0 or actions.ndim != 2 or observations.ndim != 2:
        raise DemonstrationError(f"{where}: no steps, or not [T, dim] observations and actions")
    if len(observations) != steps + 1:
        raise DemonstrationError(
            f"{where}: {len(observations)} observations for {steps} actions; a Minari episode "
            "keeps T + 1 observations (the last one after the last action)"
        )
    if rewards.shape != (steps,) or not np.issubdtype(rewards.dtype, np.number):
        raise DemonstrationError(f"{where}: rewards must be [T] numbers; got {rewards.shape}")
    labels = (episode.infos or {}).get("intention")
    if labels is not None:
        labels = np.asarray(labels)
        if labels.shape not in ((steps,), (steps + 1,)) or not np.issubdtype(
            labels.dtype, np.integer
        ):
            raise DemonstrationError(
                f"{where}: infos['intention'] must be [T] or [T + 1] integer labels; got "
                f"shape {labels.shape} of {labels.dtype}"
            )
        labels = labels[:steps]
    return observations[:-1], actions, rewards, observations[-1], labels


def _labelled(source: str, demos: Demonstrations, labels) -> Demonstrations:
    """The demonstrations with their labels and each intention's expert return, the mean
    return of its episodes."""
    labels = np.concatenate(labels).astype(np.int32)
    if labels.min() < 0:
        raise DemonstrationError(f"'{source}': infos['intention'] must be non-negative")
    episode_label = labels[demos.episode_starts]
    if np.any(labels != episode_label[demos.episode]):
        raise DemonstrationError(
            f"'{source}': infos['intention'] changes within an episode; a demonstration "
            "demonstrates one intention"
        )
    returns = []
    for intention in range(int(labels.max()) + 1):
        own = labels == intention
        if not own.any():
            raise DemonstrationError(
                f"'{source}': infos['intention'] labels no episode with intention {intention}; "
                f"label the intentions 0 .. K-1"
            )
        returns.append(mean_episode_return(demos.rewards[own], demos.episode_starts[own]))
    return dataclasses.replace(
        demos, intentions=labels, expert_returns=np.array(returns, np.float32)
    )


def write(demos: Demonstrations, env: envs.Env, root: str) -> list[str]:
    """Writes every intention of ``demos`` (labels, rewards and final observations required)
    as the Minari dataset :func:`dataset_id` under the datasets directory ``root``; returns
    their ids. Refuses, writing nothing, when one of them exists already."""
    if demos.intentions is None or demos.rewards is None or demos.final_observations is None:
        raise DemonstrationError(
            "a Minari dataset holds every step's reward and every episode's final observation, "
            f"which these {env.name} demonstrations lack: `python -m emgail_jax.experts --env "
            f"{env.name} --add-rewards` adds both to an MJX env's demonstrations file"
        )
    names = env.intention_names[: demos.num_intentions]
    ids = [dataset_id(env.name, name) for name in names]
    taken = [i for i in ids if os.path.exists(os.path.join(root, i))]
    if taken:
        raise DemonstrationError(
            f"{', '.join(taken)} already in {root}: delete them (`minari delete ID`) or choose "
            "another --out"
        )
    for intention, (name, identifier) in enumerate(zip(names, ids, strict=True)):
        _write_one(demos, env, intention, name, identifier, root)
    return ids


def _write_one(demos, env, intention: int, name: str, identifier: str, root: str) -> None:
    import gymnasium
    import minari
    from minari.data_collector import EpisodeBuffer

    obs_dim, act_dim = demos.observations.shape[1], demos.actions.shape[1]
    observation_space = gymnasium.spaces.Box(-np.inf, np.inf, (obs_dim,), np.float32)
    low, high = (np.full(act_dim, x, np.float32) for x in (env.action_low, env.action_high))
    action_space = gymnasium.spaces.Box(low, high, (act_dim,), np.float32)
    bounds = [*np.flatnonzero(demos.episode_starts), len(demos)]
    buffers = []
    for episode in np.unique(demos.episode[demos.intentions == intention]):
        first, end = bounds[episode], bounds[episode + 1]
        steps = end - first
        last = np.arange(steps) == steps - 1
        ended_early = steps < env.episode_length  # the env terminated it; else its time limit
        observations = [demos.observations[first:end], demos.final_observations[episode][None]]
        buffers.append(
            EpisodeBuffer(
                observations=np.concatenate(observations),
                actions=demos.actions[first:end],
                rewards=demos.rewards[first:end],
                terminations=last & ended_early,
                truncations=last & (not ended_early),
            )
        )
    with _datasets_directory(root), warnings.catch_warnings():
        # Minari warns about the env spec, code link and e-mail it has not been given.
        warnings.simplefilter("ignore", UserWarning)
        dataset = minari.create_dataset_from_buffers(
            identifier,
            buffers,
            observation_space=observation_space,
            action_space=action_space,
            algorithm_name="the TRPO expert of emgail_jax.experts, deterministic episodes",
            author="emgail-jax",
            description=f"{env.name} demonstrations of the intention '{name}' "
            f"({env.intention_names.index(name)} of {env.name}'s {len(env.intention_names)})",
        )
    dataset.storage.update_metadata({INTENTION_KEY: name, ENV_KEY: env.name})


@contextlib.contextmanager
def _datasets_directory(root: str):
    """Minari writes under ``MINARI_DATASETS_PATH``: pointed at ``root`` for the duration."""
    previous = os.environ.get("MINARI_DATASETS_PATH")
    os.environ["MINARI_DATASETS_PATH"] = root
    try:
        yield
    finally:
        if previous is None:
            del os.environ["MINARI_DATASETS_PATH"]
        else:
            os.environ["MINARI_DATASETS_PATH"] = previous
