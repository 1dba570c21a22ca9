"""What the MJX envs share: their MuJoCo model, its solver settings and a frame-skipped step.

Every MJX env starts from an MJCF file that ships inside the installed ``brax`` package
(``brax/envs/assets/*.xml``), read at runtime, edited with :class:`mujoco.MjSpec` where the env
needs it (:meth:`MjxEnv.edit_spec`), compiled to a native :class:`mujoco.MjModel` (kept as
``env.mj_model`` for native comparisons and rendering) and put on the device as an
:class:`mjx.Model`. ``State.physics`` is the env's :class:`mjx.Data`.

Solver settings are chosen per env for speed on CPU (:class:`Solver`, documented in each env's
docstring) and applied to the compiled model, so the native model and the MJX model always step
with the same settings. ``experiments/check_mjx_dynamics.py`` compares the dynamics under them
with native MuJoCo at MuJoCo's own default settings.
"""

from __future__ import annotations

import contextlib
import dataclasses
import importlib.util
import io
import math
import pathlib
import sys
from collections.abc import Sequence
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from envs.core import Env, EnvError, State

# MJX tries to import its optional Warp backend on import and prints two harmless lines
# ("Failed to import warp: ...") when it is not installed; drop just those lines.
with contextlib.redirect_stdout(io.StringIO()) as _import_output:
    from mujoco import mjx
for _line in _import_output.getvalue().splitlines():
    if not _line.startswith(("Failed to import warp", "Failed to import mujoco_warp")):
        print(_line, file=sys.stdout)

_SOLVERS = {"cg": mujoco.mjtSolver.mjSOL_CG, "newton": mujoco.mjtSolver.mjSOL_NEWTON}
_JACOBIANS = {
    "dense": mujoco.mjtJacobian.mjJAC_DENSE,
    "sparse": mujoco.mjtJacobian.mjJAC_SPARSE,
    "auto": mujoco.mjtJacobian.mjJAC_AUTO,
}


@dataclasses.dataclass(frozen=True)
class Solver:
    """Constraint-solver settings written into ``MjModel.opt`` (the rest of ``opt`` is the XML's).

    Attributes:
      solver: ``'newton'`` or ``'cg'``.
      iterations: maximum solver iterations per physics step.
      ls_iterations: maximum line-search iterations per solver iteration.
      disable: names of ``mjtDisableBit`` flags to set, e.g. ``('contact',)``.
    """

    solver: str = "newton"
    iterations: int = 1
    ls_iterations: int = 4
    disable: tuple[str, ...] = ()
    jacobian: str = "auto"

    def apply(self, model: mujoco.MjModel) -> None:
        if self.solver not in _SOLVERS:
            raise EnvError(f"unknown solver '{self.solver}': choose one of {', '.join(_SOLVERS)}")
        if self.iterations < 1 or self.ls_iterations < 1:
            raise EnvError(
                f"solver iterations and ls_iterations must be >= 1; got {self.iterations}, "
                f"{self.ls_iterations}"
            )
        if self.jacobian not in _JACOBIANS:
            raise EnvError(
                f"unknown jacobian '{self.jacobian}': choose one of {', '.join(_JACOBIANS)}"
            )
        model.opt.solver = _SOLVERS[self.solver]
        model.opt.jacobian = _JACOBIANS[self.jacobian]
        model.opt.iterations = self.iterations
        model.opt.ls_iterations = self.ls_iterations
        for flag in self.disable:
            bit = getattr(mujoco.mjtDisableBit, f"mjDSBL_{flag.upper()}", None)
            if bit is None:
                raise EnvError(f"unknown MuJoCo disable flag '{flag}'")
            model.opt.disableflags |= int(bit)


@dataclasses.dataclass(frozen=True)
class Dynamics:
    """A variant of an env's physics, each entry a factor on the model's own value: the test
    of a learned reward in changed dynamics (``reoptimize --env-set KEY=VALUE``).

    Keys: ``mass.BODY`` (one body's mass and inertia, its geoms' density scaled), ``gravity``,
    ``friction`` (every geom's sliding friction) and ``viscosity`` (the medium's; only where the
    model has one, the swimmer). Applied to the model's spec before it is compiled, so that the
    derived statistics the solver uses (``stat.meaninertia``) follow.
    """

    factors: tuple[tuple[str, float], ...] = ()  # (key, factor), in the order given

    KEYS: ClassVar[tuple[str, ...]] = ("mass.BODY", "gravity", "friction", "viscosity")

    @classmethod
    def parse(cls, settings: Sequence[str]) -> Dynamics:
        """From ``KEY=FACTOR`` strings; an unknown key or a factor that is not a positive
        number is an :class:`EnvError` naming what to give."""
        factors = []
        for setting in settings:
            key, _, text = setting.partition("=")
            if not (key in cls.KEYS[1:] or (key.startswith("mass.") and len(key) > 5)):
                raise EnvError(
                    f"unknown dynamics key '{key}' in '{setting}': use {', '.join(cls.KEYS)}"
                )
            try:
                factor = float(text)
            except ValueError:
                factor = math.nan
            if not (math.isfinite(factor) and factor > 0):
                raise EnvError(f"'{setting}': the factor must be a positive number (KEY=FACTOR)")
            factors.append((key, factor))
        return cls(tuple(factors))

    def as_settings(self) -> list[str]:
        return [f"{key}={factor:g}" for key, factor in self.factors]

    def apply(self, spec: mujoco.MjSpec) -> None:
        for key, factor in self.factors:
            if key.startswith("mass."):
                self._scale_body(spec, key.removeprefix("mass."), factor)
            elif key == "gravity":
                spec.option.gravity = np.asarray(spec.option.gravity) * factor
            elif key == "friction":
                for geom in spec.geoms:
                    geom.friction = np.asarray(geom.friction) * [factor, 1.0, 1.0]
            elif spec.option.viscosity == 0:
                raise EnvError("this env's model has no viscosity to scale (its medium is empty)")
            else:
                spec.option.viscosity *= factor

    @staticmethod
    def _scale_body(spec: mujoco.MjSpec, name: str, factor: float) -> None:
        body = spec.body(name)
        if body is None or name == "world":
            names = [b.name for b in spec.bodies if b.name and b.name != "world"]
            raise EnvError(f"no body '{name}' in this env's model; its bodies: {', '.join(names)}")
        if body.explicitinertial:
            body.mass *= factor
            body.inertia = np.asarray(body.inertia) * factor
        for geom in body.geoms:
            if math.isnan(geom.mass):
                geom.density *= factor
            else:
                geom.mass *= factor


def mujoco_default_solver() -> Solver:
    """MuJoCo's own defaults (Newton, 100 iterations, 50 line-search iterations): the reference."""
    default = mujoco.MjOption()
    return Solver("newton", int(default.iterations), int(default.ls_iterations))


def native_rollout(
    model: mujoco.MjModel,
    frame_skip: int,
    qpos: np.ndarray,
    qvel: np.ndarray,
    actions: np.ndarray,
    mocap_pos: np.ndarray | None = None,
) -> np.ndarray:
    """Steps native MuJoCo from ``qpos``, ``qvel`` with ``actions [T, nu]``, each held for
    ``frame_skip`` physics steps; returns ``qpos [T + 1, nq]`` after every env step."""
    data = mujoco.MjData(model)
    data.qpos[:], data.qvel[:] = qpos, qvel
    if mocap_pos is not None:
        data.mocap_pos[:] = mocap_pos
    trajectory = [data.qpos.copy()]
    for action in actions:
        data.ctrl[:] = action
        mujoco.mj_step(model, data, nstep=frame_skip)
        trajectory.append(data.qpos.copy())
    return np.stack(trajectory)


def brax_asset(filename: str) -> pathlib.Path:
    """Path of ``filename`` in the installed brax's ``envs/assets`` (without importing brax)."""
    spec = importlib.util.find_spec("brax")
    if spec is None or not spec.submodule_search_locations:
        raise EnvError("the MJX envs read their models from the brax package: pip install brax")
    path = pathlib.Path(spec.submodule_search_locations[0]) / "envs" / "assets" / filename
    if not path.is_file():
        raise EnvError(f"brax asset {filename} not found at {path}; is brax >= 0.14 installed?")
    return path


def compile_spec(spec: mujoco.MjSpec) -> mujoco.MjModel:
    """Compiles ``spec``, replacing the deprecated ``compiler.settotalmass`` by scaled densities.

    MuJoCo warns on every compile of a model with ``settotalmass``. Scaling the density of every
    geom by ``settotalmass / total mass`` gives the same masses and inertias, and, unlike
    ``mj_setTotalmass`` on the compiled model, the same derived statistics
    (``stat.meaninertia``, which the solver uses). Valid for models whose inertias all come from
    their geoms, as in brax's ``half_cheetah.xml``; checked below.
    """
    total_mass = spec.compiler.settotalmass
    if total_mass <= 0:
        return spec.compile()
    spec.compiler.settotalmass = -1.0
    factor = total_mass / float(spec.compile().body_mass.sum())
    for geom in spec.geoms:
        geom.density *= factor
    model = spec.compile()
    if not math.isclose(float(model.body_mass.sum()), total_mass, rel_tol=1e-6):
        raise EnvError(f"could not scale the model's mass to settotalmass={total_mass}")
    return model


class MjxEnv(Env):
    """An env stepping an MJX model; subclasses define the task (obs, rewards, termination).

    Class attributes a subclass sets:
      xml: file name in brax's ``envs/assets``.
      frame_skip: physics steps per env step; ``dt = frame_skip * opt.timestep``.
      default_solver: the env's :class:`Solver` (documented in its docstring).
      episode_steps: episode length T.
      unroll_frame_skip: unroll the frame-skip loop (longer compile; faster for some envs).
      reset_noise, reset_velocity_normal: gym's reset noise (see :meth:`reset`).
      position_dims: the leading qpos entries the observation leaves out (see :meth:`replay`).
    """

    xml: ClassVar[str]
    frame_skip: ClassVar[int]
    default_solver: ClassVar[Solver]
    episode_steps: ClassVar[int]
    unroll_frame_skip: ClassVar[bool] = False
    reset_noise: ClassVar[float] = 0.1
    reset_velocity_normal: ClassVar[bool] = False
    # The observation is qpos[position_dims:] then qvel (velocities possibly clipped, angles
    # possibly wrapped): the root's position it leaves out, on which the dynamics do not
    # depend. None where the observation is not of that form (the reacher's).
    position_dims: ClassVar[int | None] = None
    obs_max_velocity: ClassVar[float] = math.inf  # the observation's clip of qvel

    def __init__(
        self,
        intentions: int | None = None,
        solver_iterations: int | None = None,
        ls_iterations: int | None = None,
        dynamics: Sequence[str] = (),
    ):
        super().__init__(intentions)
        overrides = {"iterations": solver_iterations, "ls_iterations": ls_iterations}
        self.solver = dataclasses.replace(
            self.default_solver, **{k: int(v) for k, v in overrides.items() if v is not None}
        )
        self.dynamics = Dynamics.parse(dynamics)
        self.mj_model = self.native_model(self.solver)
        self.mjx_model = mjx.put_model(self.mj_model, impl="jax")
        self._mjx_model_one_iteration = self.mjx_model.replace(
            opt=self.mjx_model.opt.replace(iterations=1)
        )
        self.dt = float(self.mj_model.opt.timestep) * self.frame_skip

    # ---- model ---------------------------------------------------------------------------

    def edit_spec(self, spec: mujoco.MjSpec) -> None:
        """Env-specific edits of the brax model before it is compiled (default: none)."""

    def native_model(self, solver: Solver | None = None) -> mujoco.MjModel:
        """The env's model compiled for native MuJoCo with ``solver`` (default: the env's own)."""
        spec = mujoco.MjSpec.from_file(str(brax_asset(self.xml)))
        self.edit_spec(spec)
        model = compile_spec(spec)
        if self.dynamics.factors:
            # On the spec as compiled (its total mass already set), so each factor is exact.
            self.dynamics.apply(spec)
            model = spec.compile()
        (solver or self.solver).apply(model)
        return model

    # ---- interface -----------------------------------------------------------------------

    @property
    def action_size(self) -> int:
        return int(self.mj_model.nu)

    @property
    def episode_length(self) -> int:
        return self.episode_steps

    def options(self) -> dict[str, Any]:
        options = {
            "solver_iterations": self.solver.iterations,
            "ls_iterations": self.solver.ls_iterations,
        }
        if self.dynamics.factors:  # the envs' own dynamics add nothing to a run's summary
            options["dynamics"] = self.dynamics.as_settings()
        return options

    def reset(self, key: jax.Array) -> State:
        """Gym's reset: ``qpos0`` plus uniform noise in ±``reset_noise``, zero velocity plus
        uniform noise in ±``reset_noise`` (normal noise of that std if
        ``reset_velocity_normal``)."""
        qpos, qvel = self.reset_qpos_qvel(
            key, self.reset_noise, self.reset_noise, qvel_normal=self.reset_velocity_normal
        )
        return self.initial_state(self.physics_reset(qpos, qvel))

    def step(self, state: State, action: jax.Array) -> State:
        """One env step: the physics advanced by the clipped ``action``, then the task's
        :meth:`rewards` and :meth:`terminated` of the step."""
        action, data = self.advance(state, action)
        return state.replace(
            physics=data,
            obs=self._obs(data),
            reward=self.rewards(state.physics, data, action),
            done=self.terminated(data),
        )

    def advance(self, state: State, action: jax.Array) -> tuple[jax.Array, mjx.Data]:
        """The executed (clipped) action and the physics one env step later."""
        action = self.clip_action(action)
        return action, self.physics_step(state.physics, action)

    def replay(
        self, observations: jax.Array, actions: jax.Array, steps: jax.Array, fits: int = 4
    ) -> tuple[jax.Array, jax.Array, jax.Array]:
        """Every pair of one episode of ``steps`` pairs (padded to ``observations [T, D]`` and
        ``actions [T, A]``) stepped once from the state its observation stands for: ``(next
        observations [T, D], rewards [T, K], done [T])``.

        The left-out position is 0 (the dynamics and rewards do not depend on it), and the
        solver starts warm from the previous pair's step, as the episode did (the first pair
        from zero, as after a reset). A velocity the observation clipped is fitted, where the
        next observation is recorded (every pair but the last), to the position that
        observation records: ``fits`` corrections, each by the position's gap over ``dt`` (a
        joint moves about ``dt`` times its velocity in a step), kept beyond the clip. What the
        observation cannot give back (a clipped velocity of the last pair, the last bits of the
        position's effect and of the warm start) leaves the replay approximate:
        docs/environments.md measures it on the shipped demonstrations. Needs one qpos entry
        per qvel entry (no free or ball joints), as the envs that set ``position_dims`` have.
        """
        if self.position_dims is None or self.mj_model.nq != self.mj_model.nv:
            raise EnvError(f"'{self.name}' observations do not give back the env's state")
        skip, nq = self.position_dims, self.mj_model.nq
        positions = lambda obs: obs[: nq - skip]
        velocities = lambda obs: obs[nq - skip :]

        def step_from(obs, qvel, warm_start, action):
            qpos = jnp.concatenate([jnp.zeros(skip, obs.dtype), positions(obs)])
            physics = self.physics_reset(qpos, qvel).replace(qacc_warmstart=warm_start)
            return self.step(self.initial_state(physics), action)

        def replay_pair(warm_start, pair):
            obs, action, next_obs, has_next = pair
            clipped_qvel = velocities(obs)
            clipped = (jnp.abs(clipped_qvel) >= self.obs_max_velocity) & has_next
            clipped = clipped & (jnp.arange(nq) >= skip)  # the root's has no recorded position

            def fit(_, qvel):
                after = step_from(obs, qvel, warm_start, action)
                gap = jnp.concatenate([jnp.zeros(skip), positions(after.obs - next_obs)])
                direction = jnp.sign(clipped_qvel)
                beyond = jnp.maximum(direction * (qvel - gap / self.dt), self.obs_max_velocity)
                return jnp.where(clipped, direction * beyond, qvel)

            clips = math.isfinite(self.obs_max_velocity)  # else nothing to fit
            qvel = jax.lax.fori_loop(0, fits, fit, clipped_qvel) if fits and clips else clipped_qvel
            after = step_from(obs, qvel, warm_start, action)
            return after.physics.qacc_warmstart, (after.obs, after.reward, after.done)

        t = jnp.arange(len(observations))
        next_observations = jnp.roll(observations, -1, axis=0)
        pairs = (observations, actions, next_observations, t + 1 < steps)
        warm_start = jnp.zeros(self.mj_model.nv, observations.dtype)
        _, replayed = jax.lax.scan(replay_pair, warm_start, pairs)
        return replayed

    # ---- the task ------------------------------------------------------------------------

    def rewards(self, before: mjx.Data, after: mjx.Data, action: jax.Array) -> jax.Array:
        """``[K]`` the reward of every learned intention for the step from ``before`` to
        ``after`` with the executed ``action``."""
        raise NotImplementedError

    def terminated(self, data: mjx.Data) -> jax.Array:
        """``[]`` 1.0 where the episode ends in ``data`` (default: never)."""
        return jnp.zeros(())

    # ---- physics -------------------------------------------------------------------------

    def _obs(self, data: mjx.Data) -> jax.Array:
        raise NotImplementedError

    def initial_state(self, data: mjx.Data) -> State:
        """The env state of a freshly reset ``data``: no reward yet, not done."""
        return State(
            physics=data,
            obs=self._obs(data),
            reward=jnp.zeros(self.num_intentions),
            done=jnp.zeros(()),
        )

    def forward_velocity(self, before: mjx.Data, after: mjx.Data) -> jax.Array:
        """``Δx / dt`` of the root over one env step."""
        return (after.qpos[0] - before.qpos[0]) / self.dt

    def trace(self, state: State) -> dict[str, jax.Array]:
        """The root's horizontal position, which the observation leaves out."""
        return {"x": state.physics.qpos[0]}

    def physics_reset(self, qpos: jax.Array, qvel: jax.Array, **fields: jax.Array) -> mjx.Data:
        """Fresh data at ``qpos [nq]``, ``qvel [nv]`` (and e.g. ``mocap_pos``).

        No ``mjx.forward``: a step recomputes every derived quantity from ``qpos`` and ``qvel``
        (and MJX's forward pass leaves the solver's warm start at zero), so the next state is the
        same to the bit with or without it (``tests/test_envs_mjx.py``), and leaving it out keeps
        a second copy of the forward dynamics out of every compiled program that resets an env.
        An env whose first observation needs positions of bodies computes them itself
        (:meth:`physics_kinematics`).
        """
        return mjx.make_data(self.mjx_model).replace(qpos=qpos, qvel=qvel, **fields)

    def physics_step(self, data: mjx.Data, ctrl: jax.Array) -> mjx.Data:
        """``frame_skip`` physics steps holding ``ctrl [nu]``.

        As in ``mj_step``, position-dependent quantities (``xpos``, ...) of the result belong to
        the state before the last integration; recompute them if an observation needs them.
        """
        data = data.replace(ctrl=ctrl)
        if self.unroll_frame_skip:
            for _ in range(self.frame_skip):
                data = self._substep(data)
            return data
        return jax.lax.fori_loop(0, self.frame_skip, lambda _, d: self._substep(d), data)

    def _substep(self, data: mjx.Data) -> mjx.Data:
        """One ``mjx.step`` (Euler), with the solver's iterations unrolled.

        ``mjx.solve`` runs more than one iteration in a ``while_loop`` (under ``vmap``, every
        env runs the most iterations any env needs; measurements: docs/environments.md).
        Newton's iterations are memoryless (each starts from the current accelerations), so
        ``n`` one-iteration solves, each warm-started from the previous result, are ``n``
        Newton iterations without the loop; only the tolerance test, which can merely end the
        loop early, is dropped. CG keeps the loop (its iterations depend on the previous search
        direction).
        """
        m, m1 = self.mjx_model, self._mjx_model_one_iteration
        if self.solver.iterations == 1 or m.opt.solver != mjx.SolverType.NEWTON:
            return mjx.step(m, data)
        d = mjx.fwd_position(m, data)
        d = mjx.sensor_pos(m, d)
        d = mjx.fwd_velocity(m, d)
        d = mjx.sensor_vel(m, d)
        d = mjx.fwd_actuation(m, d)
        d = mjx.fwd_acceleration(m, d)
        for i in range(self.solver.iterations):
            d = mjx.solve(m1, d if i == 0 else d.replace(qacc_warmstart=d.qacc))
        d = mjx.sensor_acc(m, d)
        return mjx.euler(m, d)

    def physics_kinematics(self, data: mjx.Data) -> mjx.Data:
        """Recomputes the positions and orientations of bodies, geoms, ... from ``data.qpos``."""
        return mjx.kinematics(self.mjx_model, data)

    def reset_qpos_qvel(
        self, key: jax.Array, qpos_scale: float, qvel_scale: float, qvel_normal: bool = False
    ) -> tuple[jax.Array, jax.Array]:
        """The model's ``qpos0`` plus uniform noise in ±``qpos_scale`` and zero velocity plus
        uniform noise in ±``qvel_scale`` (or normal noise of std ``qvel_scale``), as gym does."""
        key_qpos, key_qvel = jax.random.split(key)
        nq, nv = self.mj_model.nq, self.mj_model.nv
        qpos = jnp.asarray(self.mj_model.qpos0, jnp.float32) + jax.random.uniform(
            key_qpos, (nq,), minval=-qpos_scale, maxval=qpos_scale
        )
        if qvel_normal:
            qvel = qvel_scale * jax.random.normal(key_qvel, (nv,))
        else:
            qvel = jax.random.uniform(key_qvel, (nv,), minval=-qvel_scale, maxval=qvel_scale)
        return qpos, qvel
