"""Rollouts of every intention at once: training samples and evaluation returns.

Env states are batched ``[K, B]``: B envs for each of the K intentions; row k is driven by the
policy of intention k. A policy here is a function ``(obs [K, B, D], key) -> actions [K, B, A]``
that already knows which intention each row belongs to.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from flax import struct

import envs

Policy = Callable[[jax.Array, jax.Array], jax.Array]


@struct.dataclass
class Transitions:
    """A rollout of T steps of ``[K, B]`` envs, time-major."""

    obs: jax.Array  # [T, K, B, D] raw observation the action was taken in
    action: jax.Array  # [T, K, B, A]
    time: jax.Array  # [T, K, B] t / episode_length of `obs`
    done: jax.Array  # [T, K, B] 1.0 where the episode ended with this transition
    true_reward: jax.Array  # [T, K, B, K] true reward of every intention (evaluation only)
    # Where asked for only (AIRL's s'; None otherwise): the raw observation each transition
    # reached, at an episode's end its last one (the auto-reset replaced it in the state).
    next_obs: jax.Array | None = None  # [T, K, B, D]

    @classmethod
    def zeros(
        cls, t: int, k: int, b: int, obs_size: int, action_size: int, next_obs: bool = False
    ) -> Transitions:
        return cls(
            obs=jnp.zeros((t, k, b, obs_size)),
            action=jnp.zeros((t, k, b, action_size)),
            time=jnp.zeros((t, k, b)),
            done=jnp.zeros((t, k, b)),
            true_reward=jnp.zeros((t, k, b, k)),
            next_obs=jnp.zeros((t, k, b, obs_size)) if next_obs else None,
        )


def steps_left(time: jax.Array, episode_length: int) -> jax.Array:
    """``[...]`` int32: the steps an episode has left to its time limit after a transition taken
    at ``time [...]`` (t / episode_length of the observation it was taken in); 0 after the last."""
    return episode_length - 1 - jnp.round(time * episode_length).astype(jnp.int32)


def terminations(transitions: Transitions, episode_length: int) -> jax.Array:
    """``[T, K, B]`` 1.0 where the env itself ended the episode before its time limit (a
    termination, not a truncation). Told by the time: after an auto-reset the state holds the
    next episode's ``info['truncation']``. An end at the limit itself counts as the limit's:
    no step is left after it."""
    return transitions.done * (steps_left(transitions.time, episode_length) > 0)


def intention_major(x: jax.Array) -> jax.Array:
    """``[T, K, B, ...] -> [K, T * B, ...]``: a rollout's samples grouped by intention, the
    layout the networks take with ``intention_major=True``."""
    t, k, b = x.shape[:3]
    return jnp.swapaxes(x, 0, 1).reshape(k, t * b, *x.shape[3:])


def time_major(x: jax.Array, length: int) -> jax.Array:
    """``[K, T * B, ...] -> [T, K, B, ...]``: the inverse of :func:`intention_major`."""
    k, tb = x.shape[:2]
    return jnp.swapaxes(x.reshape(k, length, tb // length, *x.shape[2:]), 0, 1)


def batch_reset(env: envs.Env, key: jax.Array, shape: tuple[int, ...]) -> envs.State:
    """Independent resets of ``shape`` envs (e.g. ``(K, B)``)."""
    keys = jax.random.split(key, shape)
    reset = env.reset
    for _ in shape:
        reset = jax.vmap(reset)
    return reset(keys)


def _batch_step(env: envs.Env, ndim: int, step=None):
    step = step or env.step
    for _ in range(ndim):
        step = jax.vmap(step)
    return step


def rollout(
    env: envs.Env,
    policy: Policy,
    state: envs.State,
    key: jax.Array,
    length: int,
    next_obs: bool = False,
) -> tuple[envs.State, Transitions]:
    """``length`` steps of the ``[K, B]`` envs in ``state`` (an auto-resetting env), with
    ``next_obs`` the observations they reached too (``Transitions.next_obs``).

    The initial states of the episodes that start during this rollout are drawn first (see
    :class:`envs.AutoResetWrapper`).
    """
    if next_obs:
        step = _batch_step(env, 2, env.step_and_observe)
    else:
        step = lambda state, action: (_batch_step(env, 2)(state, action), None)
    key_starts, key = jax.random.split(key)
    starts = jax.random.split(key_starts, state.done.shape)
    state = jax.vmap(jax.vmap(env.refresh))(state, starts)

    def body(state, step_key):
        action = policy(state.obs, step_key)
        next_state, reached = step(state, action)
        transition = Transitions(
            obs=state.obs,
            action=action,
            time=state.info["steps"] / env.episode_length,
            done=next_state.done,
            true_reward=next_state.reward,
            next_obs=reached,
        )
        return next_state, transition

    return jax.lax.scan(body, state, jax.random.split(key, length))


def tree_where(condition: jax.Array, a, b):
    """``a`` where ``condition`` (a scalar, or batch dims leading every leaf), else ``b``."""

    def pick(x, y):
        c = jnp.reshape(condition, jnp.shape(condition) + (1,) * (x.ndim - jnp.ndim(condition)))
        return jnp.where(c, x, y)

    return jax.tree.map(pick, a, b)


def fresh_starts(state: envs.State) -> envs.State:
    """The ``next_start`` states an auto-resetting env drew (see :meth:`AutoResetWrapper.refresh`),
    as states of their own: fresh episodes."""
    start = state.info["next_start"]
    return start.replace(info={**start.info, "next_start": start})


def episode_totals(transitions: Transitions, alive: jax.Array):
    """Sums of the true rewards of ``transitions`` over the steps still in the first episode.

    Args:
      alive: ``[K, B]`` 1.0 for an env whose episode had not ended before these transitions.

    Returns ``(totals [K, B, K], alive [K, B])``: the reward of the step that ends an episode
    counts, later ones do not (an auto-reset env has started another episode by then).
    """

    def body(alive, step):
        reward, done = step
        total = jnp.where(alive[..., None] > 0, reward, 0.0)
        return alive * (1.0 - done), total

    alive, totals = jax.lax.scan(body, alive, (transitions.true_reward, transitions.done))
    return totals.sum(0), alive


def episodes(
    env: envs.Env,
    act: Callable[[envs.State, jax.Array], jax.Array],
    key: jax.Array,
    num_policies: int,
    episodes_per_policy: int,
    traces: bool = False,
):
    """Fresh episodes of ``num_policies`` policy rows, ``episodes_per_policy`` each.

    ``act(state [P, E], key) -> action [P, E, A]`` sees whole env states (an analytic expert
    needs more than the observation). ``env`` has a time limit and no auto-reset; rewards after
    a termination are not counted.

    Returns ``(returns [P, E, K], alive [T, P, E], trace {name: [T, P, E]})``: the true return of
    every episode under every intention, whether each step was still in its episode, and, with
    ``traces``, the env's :meth:`~envs.Env.trace` after every step (empty otherwise).
    """
    key_reset, key_steps = jax.random.split(key)
    state = batch_reset(env, key_reset, (num_policies, episodes_per_policy))
    step = _batch_step(env, 2)
    trace = jax.vmap(jax.vmap(env.trace)) if traces else (lambda state: {})

    def body(carry, step_key):
        state, alive, total = carry
        next_state = step(state, act(state, step_key))
        # `where`, not a product: a diverged state after the end may reward NaN.
        total = total + jnp.where(alive[..., None] > 0, next_state.reward, 0.0)
        out = (alive, trace(next_state))
        return (next_state, alive * (1.0 - next_state.done), total), out

    alive = jnp.ones((num_policies, episodes_per_policy))
    total = jnp.zeros((num_policies, episodes_per_policy, env.num_intentions))
    (_, _, total), (alive, trace_values) = jax.lax.scan(
        body, (state, alive, total), jax.random.split(key_steps, env.episode_length)
    )
    return total, alive, trace_values


def episode_returns(
    env: envs.Env, policy: Policy, key: jax.Array, num_policies: int, episodes_per_policy: int
) -> jax.Array:
    """``[num_policies, K]`` mean true return of each policy row (``policy`` acts on
    observations) under every intention, over fresh episodes (see :func:`episodes`)."""
    act = lambda state, step_key: policy(state.obs, step_key)
    returns, _, _ = episodes(env, act, key, num_policies, episodes_per_policy)
    return returns.mean(1)


def uniform_random_policy(env: envs.Env) -> Policy:
    """Uniformly random actions in the action box (the ERD's reference point 1)."""

    def policy(obs, key):
        shape = (*obs.shape[:-1], env.action_size)
        return jax.random.uniform(key, shape, minval=env.action_low, maxval=env.action_high)

    return policy


def still_policy(env: envs.Env) -> Policy:
    """Every actuator held at the middle of its range (no torque in the MJX envs): an agent
    that does nothing, a reference below any learner that acts."""

    def policy(obs, key):
        del key
        middle = (jnp.asarray(env.action_low) + jnp.asarray(env.action_high)) / 2
        return jnp.broadcast_to(middle, (*obs.shape[:-1], env.action_size))

    return policy
