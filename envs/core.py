"""The multi-intention environment interface that every env in this package implements.

An env is a static description (a Python object holding constants and a model) with two pure
functions over a single, unbatched :class:`State`: ``reset(key) -> State`` and
``step(state, action) -> State``. Batching is the caller's business (``jax.vmap``).

The difference from a single-task env: ``State.reward`` is the true reward of *every* intention as a
vector ``[K]``. The IRL learner never reads it; it is there for evaluation (ERD) and for training
the experts that produce demonstrations.
"""

from __future__ import annotations

import abc
from collections.abc import Hashable
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
from flax import struct


class EnvError(ValueError):
    """A request the env registry or an env cannot serve; the message says what to change."""


@struct.dataclass
class State:
    """State of one env (unbatched).

    Attributes:
      physics: env-specific pytree (driver kinematics, ``mjx.Data``, ...).
      obs: ``[obs_dim]`` observation.
      reward: ``[K]`` true reward of every intention for the transition that led here.
      done: ``[]`` 1.0 once the episode has ended (termination or time limit), else 0.0.
      info: per-env arrays added by the env and its wrappers (``steps``, ``truncation``, ...).
    """

    physics: Any
    obs: jax.Array
    reward: jax.Array
    done: jax.Array
    info: dict[str, Any] = struct.field(default_factory=dict)


class Env(abc.ABC):
    """A multi-intention env: the first ``intentions`` of the env's ``intention_names``."""

    name: ClassVar[str]
    intention_names: ClassVar[tuple[str, ...]]
    # Whether an episode may end before its time limit (a fall): what an absorbing state is for.
    terminates: ClassVar[bool] = False
    # The RL budget a policy trained from scratch on a reward of this env needs where an IRL
    # run's own falls short, as its experts did: ``iterations``, ``gamma``, ``gae_lambda``,
    # ``value_target_scaling`` in place of the run's (the reward check's fresh agents and its
    # true-reward baseline train with it). Empty: the run's own.
    rl_budget: ClassVar[dict[str, Any]] = {}

    def __init__(self, intentions: int | None = None):
        max_k = len(self.intention_names)
        intentions = max_k if intentions is None else int(intentions)
        if not 1 <= intentions <= max_k:
            raise EnvError(
                f"env '{self.name}' has {max_k} intentions ({', '.join(self.intention_names)}); "
                f"got intentions={intentions}: choose a number from 1 to {max_k}"
            )
        self._intentions = intentions

    @property
    def num_intentions(self) -> int:
        """K, the number of intentions this instance rewards (the first K of the env's)."""
        return self._intentions

    @property
    def max_intentions(self) -> int:
        return len(self.intention_names)

    @property
    @abc.abstractmethod
    def observation_size(self) -> int: ...

    @property
    @abc.abstractmethod
    def action_size(self) -> int: ...

    @property
    @abc.abstractmethod
    def episode_length(self) -> int:
        """Number of steps of one episode (the horizon T of the paper's experiments)."""

    @property
    def action_low(self) -> float:
        return -1.0

    @property
    def action_high(self) -> float:
        return 1.0

    @abc.abstractmethod
    def reset(self, key: jax.Array) -> State: ...

    @abc.abstractmethod
    def step(self, state: State, action: jax.Array) -> State: ...

    def clip_action(self, action: jax.Array) -> jax.Array:
        return jnp.clip(action, self.action_low, self.action_high)

    def trace(self, state: State) -> dict[str, jax.Array]:
        """Named scalars that show what the agent is doing (plotted by ``emgail_jax.evaluate``
        against time, e.g. the position the observation leaves out); none by default."""
        return {}

    def options(self) -> dict[str, Any]:
        """The options this instance was made with (stored in run summaries)."""
        return {}

    def data(self) -> Any:
        """The arrays of this instance that runs of the same env may differ in (the driver's
        path curvatures): a compiled program takes them as an argument and reads them through
        :meth:`bind`, so that such runs share one program. ``None`` when there are none."""
        return None

    def bind(self, data: Any) -> Env:
        """This env reading ``data`` (the structure :meth:`data` returns, possibly traced)."""
        return self

    # The options that only set :meth:`data` (the driver's radii): programs do not depend on them.
    data_options: ClassVar[tuple[str, ...]] = ()

    def program_key(self) -> Hashable:
        """Equal for two instances whose compiled programs are identical once bound to their
        :meth:`data`: the class, K and every option but the :attr:`data_options`."""
        options = {k: v for k, v in self.options().items() if k not in self.data_options}
        return (type(self), self.num_intentions, tuple(sorted(options.items())))

    @property
    def unwrapped(self) -> Env:
        return self

    def __repr__(self) -> str:
        opts = ", ".join(f"{k}={v}" for k, v in self.options().items())
        return (
            f"{type(self).__name__}(intentions={self.num_intentions}{', ' if opts else ''}{opts})"
        )
