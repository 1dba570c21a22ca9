"""Multi-intention Reacher (paper §5.1, Fig. 3d): reach one of four balls.

Model: brax's ``reacher.xml`` (two-link arm, ``timestep`` 0.01, no contacts) with its single
target replaced by four balls ``ball1..ball4``, added with :class:`mujoco.MjSpec` as mocap
bodies with a small non-colliding sphere each. ``frame_skip`` = 2 as in gym, so ``dt`` = 0.02.

Why mocap bodies: the balls are part of the model, so a renderer of the env's ``mjx.Data``
shows them, and their positions live in ``State.physics.mocap_pos [4, 3]`` and travel with the
physics state through the wrappers; but they add no degrees of freedom, so they cost the
dynamics nothing (slide joints would have grown the arm's 2 dofs to 10, and the mass matrix,
the solver and ``qpos`` with them).

Balls: at reset ball k is placed uniformly (by area) at random in quarter k of the disc of
radius 0.2 around the arm's base (the disc gym's reacher draws its target from; the arm reaches
0.21): ball 1 in the quarter of +x and +y, ball 2 in -x +y, ball 3 in -x -y, ball 4 in +x -y.

Observation (26): ``cos q`` (2), ``sin q`` (2), ``q̇`` (2) of the two joints, the xy position of
every ball (8), and ``fingertip - ball_k`` for every ball, 3-D (12).

Rewards: intention k (reach ball k) is ``-‖fingertip - ball_k‖ - c ‖a‖²`` with ``c = 1`` (gym's
control cost), the distance measured after the step (gym measures it before).

No termination; 50-step episodes. Reset as gym: joint angles uniform in ±0.1, joint velocities
uniform in ±0.005.

Solver: Newton, 1 iteration, 4 line-search iterations, sparse factorisation, contacts off
(nothing can collide); the elbow's limit is the one constraint. Fewer line-search iterations
resolve it badly (docs/environments.md).
"""

from __future__ import annotations

import functools
import math
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import mujoco

from envs.core import State
from envs.mjx_base import MjxEnv, Solver

NUM_BALLS = 4
BALL_COLORS = ((0.9, 0.2, 0.2, 1), (0.2, 0.8, 0.2, 1), (0.2, 0.4, 0.9, 1), (0.9, 0.8, 0.1, 1))


class ReacherEnv(MjxEnv):
    name = "reacher"
    intention_names = tuple(f"ball{k + 1}" for k in range(NUM_BALLS))
    xml = "reacher.xml"
    frame_skip = 2
    unroll_frame_skip = True  # ~6% more env-steps/s under vmap on CPU (swimmer: no gain)
    episode_steps = 50
    default_solver = Solver(
        "newton", iterations=1, ls_iterations=4, disable=("contact",), jacobian="sparse"
    )
    # TRPO on its true reward reaches the ball as its experts do (their bar) only with more
    # iterations than an IRL run's: its ERD settles sooner than its success (docs/reward.md,
    # "The check").
    rl_budget: ClassVar[dict[str, Any]] = {"iterations": 1000}

    ctrl_cost = 1.0
    ball_disc_radius = 0.2
    ball_height = 0.01
    ball_size = 0.009
    reset_qpos_noise = 0.1
    reset_qvel_noise = 0.005

    @functools.cached_property
    def fingertip_id(self) -> int:
        return self.mj_model.body("fingertip").id

    def edit_spec(self, spec: mujoco.MjSpec) -> None:
        spec.delete(spec.body("target"))
        for k in range(NUM_BALLS):
            ball = spec.worldbody.add_body(
                name=f"ball{k + 1}", mocap=True, pos=[0.0, 0.0, self.ball_height]
            )
            ball.add_geom(
                type=mujoco.mjtGeom.mjGEOM_SPHERE,
                size=[self.ball_size, 0, 0],
                rgba=BALL_COLORS[k],
                contype=0,
                conaffinity=0,
            )

    @property
    def observation_size(self) -> int:
        return 6 + 2 * NUM_BALLS + 3 * NUM_BALLS

    def sample_balls(self, key: jax.Array) -> jax.Array:
        """``[4, 3]`` ball positions, ball k uniform in quarter k of the disc (module docstring)."""
        key_radius, key_angle = jax.random.split(key)
        radius = self.ball_disc_radius * jnp.sqrt(jax.random.uniform(key_radius, (NUM_BALLS,)))
        quarter = jnp.arange(NUM_BALLS)
        angle = 0.5 * math.pi * (quarter + jax.random.uniform(key_angle, (NUM_BALLS,)))
        height = jnp.full((NUM_BALLS,), self.ball_height)
        return jnp.stack([radius * jnp.cos(angle), radius * jnp.sin(angle), height], axis=1)

    def reset(self, key: jax.Array) -> State:
        key_arm, key_balls = jax.random.split(key)
        qpos, qvel = self.reset_qpos_qvel(key_arm, self.reset_qpos_noise, self.reset_qvel_noise)
        data = self.physics_reset(qpos, qvel, mocap_pos=self.sample_balls(key_balls))
        # The observation holds the fingertip's position: the kinematics give it.
        return self.initial_state(self.physics_kinematics(data))

    def advance(self, state: State, action: jax.Array):
        action, data = super().advance(state, action)
        # mj_step leaves positions of the state before the last integration: recompute them.
        return action, self.physics_kinematics(data)

    def rewards(self, before, after, action: jax.Array) -> jax.Array:
        distance = jnp.linalg.norm(self._fingertip_to_balls(after), axis=-1)
        return -distance[: self.num_intentions] - self.ctrl_cost * jnp.sum(action**2)

    def trace(self, state: State) -> dict[str, jax.Array]:
        distance = jnp.linalg.norm(self._fingertip_to_balls(state.physics), axis=-1)
        return {f"distance to ball {k + 1}": distance[k] for k in range(distance.shape[0])}

    def _fingertip_to_balls(self, data) -> jax.Array:
        """``[4, 3]`` fingertip minus every ball."""
        return data.xpos[self.fingertip_id][None, :] - data.mocap_pos

    def _obs(self, data) -> jax.Array:
        q, qd = data.qpos, data.qvel
        return jnp.concatenate(
            [
                jnp.cos(q),
                jnp.sin(q),
                qd,
                data.mocap_pos[:, :2].reshape(-1),
                self._fingertip_to_balls(data).reshape(-1),
            ]
        )
