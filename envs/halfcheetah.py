"""Multi-intention HalfCheetah (paper §5.1, Fig. 3c): run forward, run backward, or flip.

Model: brax's ``half_cheetah.xml`` (``timestep`` 0.01, Euler; the head, thighs and feet collide
with the floor), its ``settotalmass`` applied after compiling (see ``mjx_base.compile_spec``),
stepped ``frame_skip`` = 5 times per env step as in gym, so ``dt`` = 0.05.

Observation (17): ``qpos[1:]`` (torso height, torso pitch, six joint angles) and ``qvel`` (9);
the torso's x position is left out, as in gym. One deliberate difference from gym: the torso
pitch ``qpos[2]`` is wrapped to [-π, π). It is an unbounded hinge angle that grows by 2π with
every flip, and a flipping policy should not see ever larger inputs; a running cheetah's pitch
stays well inside (-π, π), where wrapping changes nothing.

Rewards, with ``vx = Δx / dt`` the velocity of ``qpos[0]`` over the step, ``c = 0.1`` (gym's
control cost) and ``ω = Δpitch / dt`` the torso's pitch rate over the step (the unwrapped
``qpos[2]``; positive about the +y axis, which turns the nose down, i.e. a front flip, so that
the "increasing body angle" of the paper is rewarded):

- forward: ``vx - c ‖a‖²``
- backward: ``-vx - c ‖a‖²``
- flip: ``-m |vx| + w ω - c ‖a‖²`` with ``m = 3``, ``w = 1``

With ``w = 1`` a turn pays as well as running; ``m = 3`` keeps the flipping expert in place
(docs/environments.md).

No termination; 500-step episodes. Reset as gym: ``qpos0`` plus uniform noise in ±0.1, zero
velocity plus normal noise of std 0.1.

Solver: Newton, 3 iterations, 1 line-search iteration, sparse factorisation; five capsules'
contacts and six joint limits are the constraints. Fewer iterations let the cheetah turn over
where native MuJoCo keeps it upright (docs/environments.md).
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import jax
import jax.numpy as jnp

from envs.core import State
from envs.mjx_base import MjxEnv, Solver


class HalfCheetahEnv(MjxEnv):
    name = "halfcheetah"
    intention_names = ("forward", "backward", "flip")
    xml = "half_cheetah.xml"
    frame_skip = 5
    episode_steps = 500
    default_solver = Solver("newton", iterations=3, ls_iterations=1, jacobian="sparse")
    # Its agents are still closing on the experts' speed at an IRL run's 400 TRPO iterations,
    # and a return of several per step makes value targets of hundreds, which the value baseline
    # follows only standardised (docs/defaults.md, `value_target_scaling`).
    rl_budget: ClassVar[dict[str, Any]] = {"iterations": 1000, "value_target_scaling": True}

    ctrl_cost = 0.1
    flip_weight = 1.0
    flip_move_weight = 3.0
    position_dims = 1
    reset_noise = 0.1
    reset_velocity_normal = True

    @property
    def observation_size(self) -> int:
        return 17

    def rewards(self, before, after, action: jax.Array) -> jax.Array:
        x_velocity = self.forward_velocity(before, after)
        pitch_rate = (after.qpos[2] - before.qpos[2]) / self.dt
        flip = -self.flip_move_weight * jnp.abs(x_velocity) + self.flip_weight * pitch_rate
        reward = jnp.stack([x_velocity, -x_velocity, flip])[: self.num_intentions]
        return reward - self.ctrl_cost * jnp.sum(action**2)

    def trace(self, state: State) -> dict[str, jax.Array]:
        """The root's x position and the torso's unwrapped pitch (a flip turns it by 2π)."""
        return {**super().trace(state), "pitch": state.physics.qpos[2]}

    def _obs(self, data) -> jax.Array:
        pitch = jnp.mod(data.qpos[2] + math.pi, 2 * math.pi) - math.pi
        return jnp.concatenate([data.qpos[1:2], pitch[None], data.qpos[3:], data.qvel])
