"""The flat namespace of a run's settings: every hyper-parameter by one key (``--set
discriminator_steps=5``, ``summary.json``'s ``config``), where it lives in the layers of
:mod:`emgail_jax.method.config`, how ``KEY=VALUE`` text becomes its value, and how a config
saved by an earlier version reads. Pure: the layers check the values themselves.
"""

from __future__ import annotations

import ast
import dataclasses
from collections.abc import Iterable, Mapping, Sequence

# Every hyper-parameter by its flat key, in summary.json's order: its path in the layers
# (attribute names from ``RunConfig`` down). ``trpo.FIELD`` keys reach into ``TRPOConfig``.
SETTINGS: dict[str, tuple[str, ...]] = {
    "algo": ("method", "algo"),
    "iterations": ("schedule", "iterations"),
    "num_envs": ("method", "rollout", "num_envs"),
    "rollout_length": ("method", "rollout", "rollout_length"),
    "eval_every": ("schedule", "eval_every"),
    "hidden": ("method", "networks", "hidden"),
    "intention_input": ("method", "networks", "intention_input"),
    "responsibilities": ("method", "e_step", "responsibilities"),
    "trajectory_temper_iterations": ("method", "e_step", "trajectory_temper_iterations"),
    "prior": ("method", "e_step", "prior"),
    "reseed": ("method", "e_step", "reseed"),
    "reseed_patience": ("method", "e_step", "reseed_patience"),
    "reseed_window": ("method", "e_step", "reseed_window"),
    "reseed_attempts": ("method", "e_step", "reseed_attempts"),
    "choose_intentions": ("method", "choose_intentions"),
    "init_log_std": ("method", "networks", "init_log_std"),
    "obs_clip": ("method", "networks", "obs_clip"),
    "gamma": ("method", "b_step", "gamma"),
    "gae_lambda": ("method", "b_step", "gae_lambda"),
    "trpo": ("method", "b_step", "trpo"),
    "value_learning_rate": ("method", "b_step", "value_learning_rate"),
    "value_epochs": ("method", "b_step", "value_epochs"),
    "value_minibatches": ("method", "b_step", "value_minibatches"),
    "value_target_scaling": ("method", "b_step", "value_target_scaling"),
    "discriminator_learning_rate": ("method", "m_step", "learning_rate"),
    "discriminator_steps": ("method", "m_step", "steps"),
    "discriminator_gradient_penalty": ("method", "m_step", "gradient_penalty"),
    "discriminator_replay": ("method", "m_step", "replay"),
    "discriminator_support_noise": ("method", "m_step", "support_noise"),
    "discriminator_form": ("method", "m_step", "form"),
    "posterior_learning_rate": ("method", "e_step", "learning_rate"),
    "posterior_steps": ("method", "e_step", "steps"),
    "reward_from": ("method", "reward", "source"),
    "reward_form": ("method", "reward", "form"),
    "absorbing_state": ("method", "reward", "absorbing_state"),
    "info_weight": ("info_weight",),
    "chunk_size": ("schedule", "chunk_size"),
    "seed_batch": ("schedule", "seed_batch"),
    "checkpoint_every": ("schedule", "checkpoint_every"),
    "snapshot_every": ("schedule", "snapshot_every"),
}

_KEYS = {path: key for key, path in SETTINGS.items()}

# Settings deleted as refuted (docs/defaults.md, "Deleted settings"), with the value every run
# saved before then held unless it tried them: such a config still loads, one that tried them
# cannot be rebuilt.
DELETED = {"discriminator_gradient_penalty_from": 0, "discriminator_support_in_box": False}

# Settings added after runs were saved, with the value those runs ran with.
_ADDED = {
    "intention_input": "onehot",
    "seed_batch": None,
    "responsibilities": "pair",
    "eval_every": 1,
    "reward_from": "updated",
    "reward_form": "gail",
    "reseed": False,
}


def path_of(key: str) -> tuple[str, ...]:
    """The layered path of a key: a flat key (``discriminator_steps``, ``trpo.max_kl``) or a
    path itself (``method.m_step.steps``)."""
    head, *rest = key.split(".")
    if head in SETTINGS:
        return (*SETTINGS[head], *rest)
    if head in ("method", "schedule"):
        return tuple(key.split("."))
    raise ValueError(
        f"unknown setting '{key}'; choose one of {', '.join(SETTINGS)} "
        "(or a path such as method.m_step.steps)"
    )


def key_of(path: Sequence[str]) -> str:
    """The flat key of a layered path (``trpo.max_kl`` for a field of TRPO's config)."""
    path = tuple(path)
    if path in _KEYS:
        return _KEYS[path]
    return f"{_KEYS[path[:-1]]}.{path[-1]}"


def layered(values: Mapping[str, object]) -> dict:
    """The flat ``values`` (any key :func:`path_of` takes) as a nested dict of changes by
    layer; of two keys of one setting, the later wins."""
    changes: dict = {}
    for key, value in values.items():
        node = changes
        *parents, name = path_of(key)
        for parent in parents:
            node = node.setdefault(parent, {})
        node[name] = value
    return changes


def parsed(settings: Iterable[str], like) -> dict[str, object]:
    """``KEY=VALUE`` texts (``run --set``) as values by flat key, each typed like the value it
    replaces in the config ``like``."""
    values = {}
    for setting in settings:
        key, sep, text = setting.partition("=")
        key = key.strip()
        if not sep or not key:
            raise ValueError(f"a setting is KEY=VALUE, e.g. trpo.max_kl=0.02; got '{setting}'")
        path = path_of(key)
        current = _current(like, path, key)
        values[key_of(path)] = _parse(text.strip(), current, key)
    return values


def saved(values: Mapping[str, object]) -> dict[str, object]:
    """The config dict of a ``summary.json`` (also one written before some settings existed,
    or after some were deleted) as values by flat key."""
    values = {**_ADDED, **values}
    values.pop("eval_episodes", None)  # runs written before evaluation used num_envs
    for key, default in DELETED.items():
        if key in values and values.pop(key) != default:
            raise ValueError(
                f"{key} was deleted as refuted; this version cannot rebuild a run that set it"
            )
    unknown = sorted(set(values) - set(SETTINGS))
    if unknown:
        raise TypeError(f"unknown settings {', '.join(unknown)}")
    values["hidden"] = tuple(values["hidden"])
    return values


def _current(config, path: Sequence[str], key: str):
    """The value at ``path`` in ``config``, each name of the path checked."""
    node = config
    for depth, name in enumerate(path):
        if not dataclasses.is_dataclass(node):
            raise ValueError(f"'{'.'.join(path[:depth])}' of '{key}' has no fields")
        names = [f.name for f in dataclasses.fields(node)]
        if name not in names:
            raise ValueError(f"unknown setting '{key}'; choose one of {', '.join(names)}")
        node = getattr(node, name)
    return node


def _parse(text: str, current, key: str):
    """``text`` as a value of the type of ``current`` (the value it replaces)."""
    if isinstance(current, str):  # an option's name; its domain checks it
        return text
    if dataclasses.is_dataclass(current):
        raise ValueError(f"'{key}' has fields: set one of them, e.g. {key}.<field>=...")
    if isinstance(current, bool) and text.lower() in ("true", "false"):
        return text.lower() == "true"  # the shell's spelling as well as Python's
    try:
        value = ast.literal_eval(text)
    except (ValueError, SyntaxError):
        raise ValueError(f"'{key}={text}': '{text}' is not a number, tuple or boolean") from None
    if isinstance(current, bool) or current is None:
        return value
    if isinstance(current, tuple):
        return tuple(value) if isinstance(value, (list, tuple)) else (value,)
    number = isinstance(value, (int, float)) and not isinstance(value, bool)
    if isinstance(current, float) and number:
        return float(value)
    if isinstance(current, int) and number and isinstance(value, int):
        return value
    raise ValueError(f"'{key}' takes a value like its default {current!r}; got '{text}'")
