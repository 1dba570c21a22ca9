"""Multi-intention environments: a pure-JAX driver and MJX locomotion/reacher tasks.

>>> import envs
>>> env = envs.make("driver", intentions=2, radius=20.0)
>>> state = env.reset(jax.random.PRNGKey(0))

Every env returns the true reward of each of its K intentions as a vector ``State.reward [K]``.
"""

from __future__ import annotations

import importlib
import inspect
from typing import Any

from envs.core import Env, EnvError, State
from envs.wrappers import AutoResetWrapper, EpisodeWrapper, Wrapper, wrap_for_training

# name -> "module:Class"; imported lazily so that the driver never pays for importing MuJoCo.
_REGISTRY: dict[str, str] = {
    "driver": "envs.driver:DriverEnv",
    "swimmer": "envs.swimmer:SwimmerEnv",
    "hopper": "envs.hopper:HopperEnv",
    "halfcheetah": "envs.halfcheetah:HalfCheetahEnv",
    "reacher": "envs.reacher:ReacherEnv",
}


def names() -> list[str]:
    return sorted(_REGISTRY)


def env_class(name: str) -> type[Env]:
    if name not in _REGISTRY:
        raise EnvError(f"unknown env '{name}': choose one of {', '.join(names())}")
    module, cls = _REGISTRY[name].split(":")
    return getattr(importlib.import_module(module), cls)


def make(name: str, intentions: int | None = None, **options: Any) -> Env:
    """Creates env ``name`` rewarding its first ``intentions`` intentions (all by default).

    Raises:
      EnvError: unknown name, an intention count the env does not have, or an unknown option.
    """
    cls = env_class(name)
    accepted = [
        p for p in inspect.signature(cls.__init__).parameters if p not in ("self", "intentions")
    ]
    unknown = sorted(set(options) - set(accepted))
    if unknown:
        raise EnvError(
            f"env '{name}' has no option {', '.join(map(repr, unknown))}: "
            f"its options are {', '.join(accepted) or 'none'}"
        )
    if intentions is not None:
        options = {**options, "intentions": intentions}
    return cls(**options)


__all__ = [
    "AutoResetWrapper",
    "Env",
    "EnvError",
    "EpisodeWrapper",
    "State",
    "Wrapper",
    "env_class",
    "make",
    "names",
    "wrap_for_training",
]
