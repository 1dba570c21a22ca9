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

Solver: Newton, 1 iteration, 4 line-search iterations, sparse factorisation, contacts and
``eulerdamp`` off (nothing can collide, no joint is damped); the joint limits are the only
constraints. Measured against native MuJoCo: docs/environments.md.
"""

from __future__ import annotations

from typing import Any, ClassVar

import jax
import jax.numpy as jnp

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
    # Its gait pays off over many steps: TRPO on the true reward finds the fast gait on most
    # draws only with its experts' discount and a GAE lambda that carries the credit that far.
    rl_budget: ClassVar[dict[str, Any]] = {"iterations": 1500, "gamma": 0.9999, "gae_lambda": 0.995}

    ctrl_cost = 1e-4
    position_dims = 2
    reset_noise = 0.1

    @property
    def observation_size(self) -> int:
        return 8

    def rewards(self, before, after, action: jax.Array) -> jax.Array:
        x_velocity = self.forward_velocity(before, after)
        ctrl_cost = self.ctrl_cost * jnp.sum(action**2)
        return jnp.stack([x_velocity, -x_velocity])[: self.num_intentions] - ctrl_cost

    def _obs(self, data) -> jax.Array:
        return jnp.concatenate([data.qpos[2:], data.qvel])
