"""The synthetic driver (paper §5.1, Fig. 3e, Fig. 4b): separability under direct control.

A point leaves the origin heading along +x at constant speed; the action steers it. Intention k is
to follow path k, a circular arc that starts at the origin tangent to +x and ends at destination k,
``path_length`` further along the arc. The true reward of intention k is minus the distance from
the new position to path k.

Paths, by signed curvature (positive turns left):

====  ======================  ==========================================
path  curvature               role
====  ======================  ==========================================
1     +1 / ``path1_radius``   fixed
2     +1 / ``radius``         the knob: lower ``radius`` -> closer to 1
3     -1 / ``path1_radius``   path 1 mirrored (K >= 3)
4     -1 / ``radius``         path 2 mirrored (K = 4)
====  ======================  ==========================================

Paths 1 and 2 turn the same way and touch at the origin, so their first stretch is shared; as
``radius`` falls towards ``path1_radius`` the shared stretch grows and destination 2 moves onto
destination 1, which lowers the separability of the demonstrations smoothly (see
``experiments/driver_separability.py``).

Observation: the positions at t-4..t, ``[x_{t-4}, y_{t-4}, ..., x_t, y_t]`` (10 numbers); before
the start the history is extrapolated backwards along the initial heading, as if the car had
been driving straight. The heading itself is not observed.

The expert is analytic: curvature feed-forward plus feedback on the lateral and heading error to
the closest point of its path. Demonstrations use it with Gaussian steering noise
(``expert_noise``), so that each intention's pairs form a distribution rather than one curve.
"""

from __future__ import annotations

import copy
import math

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from envs.core import Env, EnvError, State

HISTORY = 5  # positions t-4..t in the observation


@struct.dataclass
class DriverPhysics:
    heading: jax.Array  # [] radians
    history: jax.Array  # [HISTORY, 2] positions t-4..t; the last row is the current position


class DriverEnv(Env):
    name = "driver"
    intention_names = ("path1", "path2", "path3", "path4")
    data_options = ("radius", "path1_radius")

    def __init__(
        self,
        intentions: int | None = 2,
        *,
        radius: float = 20.0,
        path1_radius: float = 3.5,
        speed: float = 0.1,
        max_turn: float = 0.2,
        episode_length: int = 100,
        init_position_noise: float = 0.05,
        init_heading_noise: float = 0.1,
        expert_noise: float = 0.2,
        expert_lateral_gain: float = 0.5,
        expert_heading_gain: float = 0.5,
    ):
        super().__init__(intentions)
        if not radius > 0 or not path1_radius > 0:
            raise EnvError(f"driver radii must be positive; got radius={radius}")
        min_radius = speed / max_turn
        if min(radius, path1_radius) < min_radius:
            raise EnvError(
                f"driver radius {min(radius, path1_radius)} is tighter than the car can turn; "
                f"use a radius of at least speed/max_turn = {min_radius:g}"
            )
        self.radius = float(radius)
        self.path1_radius = float(path1_radius)
        self.speed = float(speed)
        self.max_turn = float(max_turn)
        self._episode_length = int(episode_length)
        self.init_position_noise = float(init_position_noise)
        self.init_heading_noise = float(init_heading_noise)
        self.expert_noise = float(expert_noise)
        self.expert_lateral_gain = float(expert_lateral_gain)
        self.expert_heading_gain = float(expert_heading_gain)
        all_curvatures = [1 / path1_radius, 1 / radius, -1 / path1_radius, -1 / radius]
        # [K] signed curvature of every rewarded path.
        self.curvatures = np.asarray(all_curvatures[: self.num_intentions], np.float32)
        # Long enough that a car on its path never runs off the end of it within an episode.
        self.path_length = 1.25 * self.speed * self._episode_length

    # ---- interface -----------------------------------------------------------------------

    @property
    def observation_size(self) -> int:
        return 2 * HISTORY

    @property
    def action_size(self) -> int:
        return 1

    @property
    def episode_length(self) -> int:
        return self._episode_length

    def options(self):
        return {
            "radius": self.radius,
            "path1_radius": self.path1_radius,
            "speed": self.speed,
            "max_turn": self.max_turn,
            "episode_length": self._episode_length,
            "init_position_noise": self.init_position_noise,
            "init_heading_noise": self.init_heading_noise,
            "expert_noise": self.expert_noise,
        }

    def data(self) -> dict[str, np.ndarray]:
        """The path curvatures, which the ``radius`` option sets: runs at different radii
        differ only here."""
        return {"curvatures": self.curvatures}

    def bind(self, data) -> DriverEnv:
        bound = copy.copy(self)
        bound.curvatures = data["curvatures"]
        return bound

    def trace(self, state: State) -> dict[str, jax.Array]:
        position = state.physics.history[-1]
        return {"x": position[0], "y": position[1]}

    def reset(self, key: jax.Array) -> State:
        key_position, key_heading = jax.random.split(key)
        position = self.init_position_noise * jax.random.normal(key_position, (2,))
        heading = self.init_heading_noise * jax.random.normal(key_heading, ())
        lags = jnp.arange(HISTORY - 1, -1, -1, dtype=jnp.float32)  # 4, 3, 2, 1, 0 steps ago
        direction = jnp.stack([jnp.cos(heading), jnp.sin(heading)])
        history = position[None, :] - self.speed * lags[:, None] * direction[None, :]
        physics = DriverPhysics(heading=heading, history=history)
        return State(
            physics=physics,
            obs=history.reshape(-1),
            reward=jnp.zeros(self.num_intentions),
            done=jnp.zeros(()),
        )

    def step(self, state: State, action: jax.Array) -> State:
        steer = self.clip_action(action)[0]
        heading = state.physics.heading + self.max_turn * steer
        position = state.physics.history[-1] + self.speed * jnp.stack(
            [jnp.cos(heading), jnp.sin(heading)]
        )
        history = jnp.concatenate([state.physics.history[1:], position[None]], axis=0)
        distance = self.path_distances(position)
        return state.replace(
            physics=DriverPhysics(heading=heading, history=history),
            obs=history.reshape(-1),
            reward=-distance,
            done=jnp.zeros(()),
        )

    # ---- path geometry -------------------------------------------------------------------

    def path_frames(self, position: jax.Array):
        """Closest point of every path to ``position [2]``.

        Returns ``(distance [K], tangent_heading [K], lateral_offset [K])``; the offset is signed,
        positive to the left of the path's direction of travel.
        """
        return jax.vmap(lambda k: _arc_frame(position, k, self.path_length))(
            jnp.asarray(self.curvatures)
        )

    def path_distances(self, position: jax.Array) -> jax.Array:
        return self.path_frames(position)[0]

    def path_points(self, intention: int, num: int = 200) -> np.ndarray:
        """``[num, 2]`` points along path ``intention`` up to its destination (for plots)."""
        kappa = float(self.curvatures[intention])
        s = np.linspace(0.0, self.speed * self._episode_length, num)
        if abs(kappa) < 1e-9:
            return np.stack([s, np.zeros_like(s)], 1)
        return np.stack([np.sin(kappa * s) / kappa, (1 - np.cos(kappa * s)) / kappa], 1)

    def destinations(self) -> np.ndarray:
        """``[K, 2]`` where a car on each path is at the end of an episode."""
        return np.stack([self.path_points(k)[-1] for k in range(self.num_intentions)])

    # ---- analytic expert -----------------------------------------------------------------

    def expert_action(self, state: State, intention: jax.Array) -> jax.Array:
        """The noiseless expert of ``intention`` (an int array): ``[1]`` steering in [-1, 1]."""
        position = state.physics.history[-1]
        _, tangent, lateral = self.path_frames(position)
        kappa = jnp.asarray(self.curvatures)[intention]
        heading_error = _wrap_angle(state.physics.heading - tangent[intention])
        turn = (
            self.speed * kappa
            - self.expert_lateral_gain * lateral[intention]
            - self.expert_heading_gain * heading_error
        )
        return self.clip_action(jnp.atleast_1d(turn / self.max_turn))

    def expert_policy(self, state: State, intention: jax.Array, key: jax.Array) -> jax.Array:
        """The demonstrating expert: the analytic controller plus Gaussian steering noise."""
        noise = self.expert_noise * jax.random.normal(key, (1,))
        return self.clip_action(self.expert_action(state, intention) + noise)


def _wrap_angle(angle: jax.Array) -> jax.Array:
    return jnp.arctan2(jnp.sin(angle), jnp.cos(angle))


def _arc_frame(position: jax.Array, kappa: jax.Array, length: float):
    """Distance, tangent heading and signed lateral offset of ``position`` to one arc.

    The arc starts at the origin heading +x with signed curvature ``kappa`` and has arc length
    ``length``. A right turn is the mirror image of a left turn, so it is computed as a left turn
    of ``position`` mirrored in the x axis.
    """
    mirror = jnp.where(kappa < 0, -1.0, 1.0)
    curvature = jnp.abs(kappa)
    px, py = position[0], position[1] * mirror
    straight = curvature < 1e-6
    radius = 1.0 / jnp.where(straight, 1.0, curvature)
    # Angle swept from the origin around the centre (0, radius), in [-pi/2, 3pi/2).
    swept = jnp.arctan2(px, radius - py)
    swept = jnp.where(swept < -0.5 * math.pi, swept + 2 * math.pi, swept)
    progress = jnp.where(straight, px, swept * radius)
    progress = jnp.clip(progress, 0.0, length)
    tangent = jnp.where(straight, 0.0, progress * curvature)
    closest_x = jnp.where(straight, progress, radius * jnp.sin(tangent))
    closest_y = jnp.where(straight, 0.0, radius * (1.0 - jnp.cos(tangent)))
    dx, dy = px - closest_x, py - closest_y
    distance = jnp.sqrt(dx**2 + dy**2 + 1e-12)
    lateral = -jnp.sin(tangent) * dx + jnp.cos(tangent) * dy
    return distance, mirror * tangent, mirror * lateral
