"""Multi-intention Hopper (paper §5.1, Fig. 3b): hop forward, hop backward, or stand.

Model: brax's ``hopper.xml`` (``timestep`` 0.002, Euler; only the foot collides with the floor)
with one edit: the ``rootz`` slide joint gets ``ref`` = 1.25, the torso's initial height, so
that ``qpos[1]`` is the torso height as in gym's Hopper (brax moved the root joints to the torso
and dropped the ``ref``). ``frame_skip`` = 4 as in gym, so ``dt`` = 0.008.

Observation (11): ``qpos[1:]`` (height, torso pitch, three joint angles) and ``qvel`` (6)
clipped to ±10, as gym; the torso's x position is left out.

Rewards, with ``vx = Δx / dt`` the velocity of ``qpos[0]`` over the step, ``c = 1e-3`` and the
healthy bonus ``h = 1`` (both gym's):

- forward: ``vx + h - c ‖a‖²``
- backward: ``-vx + h - c ‖a‖²``
- stand: ``-|vx| + h - c ‖a‖²``

Termination (gym's Hopper): the episode ends when the hopper is unhealthy after a step, that is
when any of these fails: every entry of ``qpos`` and ``qvel`` is finite; ``|x| < 100`` for
every ``x`` in ``qpos[2:]`` and ``qvel``; height ``qpos[1] > 0.7``; ``|pitch| = |qpos[2]| < 0.2``.
As in gym (with ``terminate_when_unhealthy``), the healthy bonus is paid on every step,
including the terminating one. 500-step episodes. Reset as gym: ``qpos0`` and zero velocity plus
uniform noise in ±5e-3.

Solver: Newton, 2 iterations, 1 line-search iteration, sparse factorisation; the foot's
contact and three joint limits are the constraints. Fewer iterations change the gait
(measured against native MuJoCo: docs/environments.md).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco

from envs.mjx_base import MjxEnv, Solver


class HopperEnv(MjxEnv):
    name = "hopper"
    intention_names = ("forward", "backward", "stand")
    terminates = True
    xml = "hopper.xml"
    frame_skip = 4
    episode_steps = 500
    default_solver = Solver("newton", iterations=2, ls_iterations=1, jacobian="sparse")

    ctrl_cost = 1e-3
    healthy_reward = 1.0
    position_dims = 1
    reset_noise = 5e-3
    init_height = 1.25
    healthy_min_height = 0.7
    healthy_max_pitch = 0.2
    healthy_max_state = 100.0
    obs_max_velocity = 10.0  # gym's

    def edit_spec(self, spec: mujoco.MjSpec) -> None:
        spec.joint("rootz").ref = self.init_height

    @property
    def observation_size(self) -> int:
        return 11

    def rewards(self, before, after, action: jax.Array) -> jax.Array:
        x_velocity = self.forward_velocity(before, after)
        common = self.healthy_reward - self.ctrl_cost * jnp.sum(action**2)
        reward = jnp.stack([x_velocity, -x_velocity, -jnp.abs(x_velocity)])
        return reward[: self.num_intentions] + common

    def terminated(self, data) -> jax.Array:
        return 1.0 - self.is_healthy(data.qpos, data.qvel)

    def is_healthy(self, qpos: jax.Array, qvel: jax.Array) -> jax.Array:
        """``[]`` 1.0 while gym's Hopper would go on (see the module docstring), else 0.0."""
        height, pitch = qpos[1], qpos[2]
        rest = jnp.concatenate([qpos[2:], qvel])
        healthy = (
            jnp.all(jnp.isfinite(qpos))
            & jnp.all(jnp.isfinite(qvel))
            & jnp.all(jnp.abs(rest) < self.healthy_max_state)
            & (height > self.healthy_min_height)
            & (jnp.abs(pitch) < self.healthy_max_pitch)
        )
        return healthy.astype(jnp.float32)

    def _obs(self, data) -> jax.Array:
        qvel = jnp.clip(data.qvel, -self.obs_max_velocity, self.obs_max_velocity)
        return jnp.concatenate([data.qpos[1:], qvel])
