"""Multi-intention Swimmer (paper §5.1, Fig. 3a): swim forward or backward.

Model: brax's ``swimmer.xml`` unchanged (three capsules in a viscous fluid, two actuated hinges,
``timestep`` 0.01), stepped ``frame_skip`` = 4 times per env step as in gym, so ``dt`` = 0.04.

Observation (8): ``qpos[2:]`` (torso angle, two joint angles) and ``qvel`` (5); the torso's
x, y position is left out as in the standard env.

Rewards, with ``vx = Δx / dt`` the velocity of the torso slider ``qpos[0]`` over the step and
``c = 1e-4`` (the reference swimmer's control cost):

- forward: ``vx - c ‖a‖²``
- backward: ``-vx - c ‖a‖²``

No termination; 500-step episodes. Reset as gym: ``qpos0`` and zero velocity plus uniform noise
in ±0.1.

Solver (the XML has Newton, 8 iterations, 50 line-search iterations): Newton, 1 iteration,
4 line-search iterations, sparse (tree) mass-matrix factorisation, and the ``contact`` and
``eulerdamp`` flags off. The joint limits (±100°) are the only constraints. The flags only skip
work: no geom pair of the swimmer can collide (its capsules have ``contype`` 0), and no joint
has damping for the Euler integrator to treat implicitly. The sparse factorisation is the same
maths, faster under ``vmap`` on CPU. ``experiments/check_mjx_dynamics.py``, against native
MuJoCo at its defaults (Newton 100/50), 8 starts x 2 gaits of 500 steps: mean velocity -0.052
vs -0.052 and 0.026 vs 0.025 m/s, largest joint error over the first 100 steps 0.010 rad.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from envs.core import State
from envs.mjx_base import MjxEnv, Solver


class SwimmerEnv(MjxEnv):
    name = "swimmer"
    intention_names = ("forward", "backward")
    xml = "swimmer.xml"
    frame_skip = 4
    episode_steps = 500
    default_solver = Solver(
        "newton", iterations=1, ls_iterations=4, disable=("contact", "eulerdamp"), jacobian="sparse"
    )

    ctrl_cost = 1e-4
    reset_noise = 0.1

    @property
    def observation_size(self) -> int:
        return 8

    def reset(self, key: jax.Array) -> State:
        qpos, qvel = self.reset_qpos_qvel(key, self.reset_noise, self.reset_noise)
        data = self.physics_reset(qpos, qvel)
        return self.initial_state(data)

    def step(self, state: State, action: jax.Array) -> State:
        action = self.clip_action(action)
        data = self.physics_step(state.physics, action)
        x_velocity = self.forward_velocity(state.physics, data)
        ctrl_cost = self.ctrl_cost * jnp.sum(action**2)
        reward = jnp.stack([x_velocity, -x_velocity])[: self.num_intentions] - ctrl_cost
        return state.replace(physics=data, obs=self._obs(data), reward=reward, done=jnp.zeros(()))

    def _obs(self, data) -> jax.Array:
        return jnp.concatenate([data.qpos[2:], data.qvel])
