"""Expert demonstrations: the file format (README, "Demonstrations format"), its validation
and generation.

A dataset is one ``.npz`` with

============== ============== ================================================================
key            shape          meaning
============== ============== ================================================================
observations   [N, obs_dim]   float32, raw (unnormalised)
actions        [N, act_dim]   float32
episode_starts [N]            bool, True on the first pair of each episode
intentions     [N] optional   int, hidden intention labels (used only by the metrics)
expert_returns [K] optional   true return of each intention's expert (for ERD)
============== ============== ================================================================
"""

from __future__ import annotations

import dataclasses
import os
import zipfile
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

import envs


class DemonstrationError(ValueError):
    """The demonstrations cannot be used; the message says what is wrong and how to fix it."""


@dataclasses.dataclass(frozen=True)
class Demonstrations:
    observations: np.ndarray
    actions: np.ndarray
    episode_starts: np.ndarray
    intentions: np.ndarray | None = None
    expert_returns: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.observations)

    @property
    def num_intentions(self) -> int | None:
        if self.intentions is not None:
            return int(self.intentions.max()) + 1
        if self.expert_returns is not None:
            return len(self.expert_returns)
        return None

    def save(self, path: str) -> None:
        """Writes the dataset atomically (a temporary file renamed into place)."""
        arrays = {k: v for k, v in dataclasses.asdict(self).items() if v is not None}
        tmp = f"{path}.tmp.npz"
        np.savez_compressed(tmp, **arrays)
        os.replace(tmp, path)


REQUIRED = ("observations", "actions", "episode_starts")


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
    for name in ("observations", "actions", "episode_starts", "intentions", "expert_returns"):
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
    )
    validate(demos, env, source=f"'{path}'")
    return demos


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
    if env is not None:
        if obs.shape[1] != env.observation_size or act.shape[1] != env.action_size:
            raise DemonstrationError(
                f"{source}: pairs have obs dim {obs.shape[1]} and action dim {act.shape[1]}, "
                f"but env '{env.name}' has {env.observation_size} and {env.action_size}"
            )
        k = demos.num_intentions
        if k is not None and k > env.max_intentions:
            raise DemonstrationError(
                f"{source}: labels name {k} intentions but env '{env.name}' has only "
                f"{env.max_intentions}"
            )


def first_intentions(demos: Demonstrations, k: int) -> Demonstrations:
    """The pairs of the first ``k`` intentions (labels required)."""
    if demos.intentions is None:
        return demos
    keep = demos.intentions < k
    returns = demos.expert_returns[:k] if demos.expert_returns is not None else None
    return Demonstrations(
        observations=demos.observations[keep],
        actions=demos.actions[keep],
        episode_starts=demos.episode_starts[keep],
        intentions=demos.intentions[keep],
        expert_returns=returns,
    )


def executed_actions(demos: Demonstrations, env: envs.Env) -> Demonstrations:
    """The demonstrations with their actions clipped to ``env``'s action range: the actions the
    env executed, which is what the discriminator and the posterior compare with the policy's
    (clipped) samples. A file may hold raw actions outside the range; they are clipped here."""
    actions = np.clip(demos.actions, env.action_low, env.action_high).astype(np.float32)
    return dataclasses.replace(demos, actions=actions)


Expert = Callable[[envs.State, jax.Array, jax.Array], jax.Array]


def generate(env: envs.Env, expert: Expert, episodes: int, key: jax.Array) -> Demonstrations:
    """Rolls ``expert(state, intention, key) -> action`` for ``episodes`` episodes of every
    intention of ``env`` and returns the labelled pairs (with the actions the env executed,
    i.e. clipped to its range) and each expert's mean true return.

    Pairs after an episode terminated early are dropped. Deterministic for a given ``key``.
    """
    k = env.num_intentions
    limited = envs.EpisodeWrapper(env)
    intention = jnp.broadcast_to(jnp.arange(k)[:, None], (k, episodes))

    @jax.jit
    def roll(key):
        key_reset, key_steps = jax.random.split(key)
        states = jax.vmap(jax.vmap(limited.reset))(jax.random.split(key_reset, (k, episodes)))
        act = jax.vmap(jax.vmap(expert))
        step = jax.vmap(jax.vmap(limited.step))

        def body(carry, step_key):
            state, alive = carry
            action = limited.clip_action(
                act(state, intention, jax.random.split(step_key, (k, episodes)))
            )
            next_state = step(state, action)
            out = (state.obs, action, next_state.reward, alive)
            return (next_state, alive * (1.0 - next_state.done)), out

        alive = jnp.ones((k, episodes))
        _, (obs, actions, rewards, alive) = jax.lax.scan(
            body, (states, alive), jax.random.split(key_steps, env.episode_length)
        )
        return obs, actions, rewards, alive

    obs, actions, rewards, alive = jax.device_get(roll(key))  # [T, K, E, ...]
    # Episode-major order: intention, episode, time.
    obs, actions, rewards, alive = (np.moveaxis(x, 0, 2) for x in (obs, actions, rewards, alive))
    keep = alive.astype(bool)
    starts = np.zeros_like(keep)
    starts[..., 0] = True
    labels = np.broadcast_to(np.arange(k)[:, None, None], keep.shape)
    own_reward = np.take_along_axis(rewards, labels[..., None], -1)[..., 0]
    expert_returns = np.where(keep, own_reward, 0.0).sum(-1).mean(-1)
    return Demonstrations(
        observations=obs[keep].astype(np.float32),
        actions=actions[keep].astype(np.float32),
        episode_starts=starts[keep],
        intentions=labels[keep].astype(np.int32),
        expert_returns=np.asarray(expert_returns, np.float32),
    )
