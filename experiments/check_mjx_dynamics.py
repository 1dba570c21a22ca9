"""Are the MJX envs' fast solver settings still the same physics? An open-loop check.

For every MJX env, fixed open-loop gaits (a sinusoid per actuator, phase-shifted from one
actuator to the next) are run from the same initial states (``env.reset`` of seeds 0..N-1)
through

- ``reference``: native MuJoCo with MuJoCo's default solver settings (Newton, 100 iterations,
  50 line-search iterations, the XML's flags), the dynamics of the standard envs;
- ``native``: native MuJoCo with the env's chosen settings (isolates the effect of the settings);
- ``mjx``: the env itself (MJX, float32, chosen settings), stepped with ``env.step``.

Contacts make the hopper's and the cheetah's trajectories chaotic (in the reference itself, a
1e-6 change of the initial state moves the cheetah's joints by ~1 rad within 5 s), so the long
runs are compared statistically and only a short start deterministically:

- ``v``: forward velocity over the run, mean over the initial states (the locomotion rewards);
  MJX passes if ``|v_mjx - v_ref| <= 0.1 |v_ref| + 0.02 + 2 se_ref``, with ``se_ref`` the
  standard error of the reference's mean (chaotic runs spread, and so do their means).
- ``max|pitch|``: largest torso pitch over all runs (hopper, cheetah), which exposes spurious
  flips (too few solver iterations let the cheetah bounce off the floor and turn over);
  MJX passes if it is within 1 rad of the reference's.
- ``err``: largest joint-position difference to the reference (root x excluded) over the first
  ``short`` env steps of every run; MJX passes if it is below ``err_tol``.

Exits with status 1 if a check fails.

    python experiments/check_mjx_dynamics.py [--envs hopper] [--starts 8]
    python experiments/check_mjx_dynamics.py --envs halfcheetah --iterations 1 --ls-iterations 4
"""

from __future__ import annotations

import dataclasses
import sys

import jax
import jax.numpy as jnp
import numpy as np

import envs
from emgail_jax.host.command_line import ArgumentParser
from envs.mjx_base import mujoco_default_solver, native_rollout


@dataclasses.dataclass(frozen=True)
class Check:
    steps: int  # env steps per run
    short: int  # env steps of the deterministic comparison
    err_tol: float  # on the largest joint-position error over the short start
    gaits: tuple[tuple[float, float, float], ...]  # (amplitude, Hz, phase step / π)
    locomotion: bool = True  # qpos[0] is the forward position, qpos[2] the torso pitch


CHECKS = {
    # The swimmer is smooth: a whole episode, and a long deterministic stretch.
    "swimmer": Check(500, 100, 0.05, ((1.0, 0.5, 0.5), (1.0, 1.0, 0.5))),
    # Open loop, the hopper falls over after ~0.5 s and then tumbles on the floor.
    "hopper": Check(125, 30, 0.05, ((0.5, 2.0, 0.5), (1.0, 2.0, 0.66), (1.0, 4.0, 0.5))),
    # Vigorous gaits, where too few solver iterations flip the cheetah over.
    "halfcheetah": Check(200, 10, 0.05, ((0.6, 2.0, 0.5), (0.6, 4.0, 1.0), (1.0, 4.0, 1.0))),
    # Gaits that drive the elbow into its joint limit.
    "reacher": Check(50, 50, 0.05, ((1.0, 1.0, 0.5), (1.0, 0.5, 0.5)), locomotion=False),
}


def gait(env: envs.Env, steps: int, amplitude: float, hz: float, phase: float) -> np.ndarray:
    """``[T, nu]`` open-loop actions ``A sin(2π f t + j φ π)`` for actuator j."""
    t = np.arange(steps)[:, None] * env.dt
    shift = phase * np.pi * np.arange(env.action_size)[None, :]
    return (amplitude * np.sin(2 * np.pi * hz * t + shift)).astype(np.float32)


def mjx_rollouts(env: envs.Env, states: envs.State, actions: np.ndarray) -> np.ndarray:
    """``qpos [N, T + 1, nq]`` of ``N`` batched envs all given ``actions [T, nu]``."""
    step = jax.jit(jax.vmap(env.step, in_axes=(0, None)))
    trajectory = [np.asarray(states.physics.qpos)]
    for action in actions:
        states = step(states, jnp.asarray(action))
        trajectory.append(np.asarray(states.physics.qpos))
    return np.stack(trajectory, axis=1)


def compare(name: str, check: Check, starts: int, **options) -> list[dict]:
    env = envs.make(name, **options)
    reference_model = env.native_model(mujoco_default_solver())
    states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), starts))
    physics = jax.device_get(states.physics)
    mocap = physics.mocap_pos if env.mj_model.nmocap else [None] * starts
    rows = []
    for amplitude, hz, phase in check.gaits:
        actions = gait(env, check.steps, amplitude, hz, phase)
        runs = {
            label: np.stack(
                [
                    native_rollout(model, env.frame_skip, q, v, actions, p)
                    for q, v, p in zip(physics.qpos, physics.qvel, mocap, strict=True)
                ]
            )
            for label, model in (("reference", reference_model), ("native", env.mj_model))
        }
        runs["mjx"] = mjx_rollouts(env, states, actions)
        row = {"gait": f"A={amplitude} f={hz}Hz φ={phase}π"}
        skip = 1 if check.locomotion else 0
        for label, q in runs.items():
            velocity = (q[:, -1, 0] - q[:, 0, 0]) / (check.steps * env.dt)
            row[f"{label}/v"] = float(np.mean(velocity))
            row[f"{label}/v_se"] = float(np.std(velocity) / np.sqrt(starts))
            row[f"{label}/pitch"] = float(np.max(np.abs(q[..., 2]))) if check.locomotion else 0.0
            error = q[:, : check.short + 1, skip:] - runs["reference"][:, : check.short + 1, skip:]
            row[f"{label}/err"] = float(np.max(np.abs(error)))
        v_ref = row["reference/v"]
        v_tol = 0.1 * abs(v_ref) + 0.02 + 2 * row["reference/v_se"]
        row["ok"] = (
            row["mjx/err"] <= check.err_tol
            and (not check.locomotion or abs(row["mjx/v"] - v_ref) <= v_tol)
            and abs(row["mjx/pitch"] - row["reference/pitch"]) <= 1.0
        )
        rows.append(row)
    return rows


def main() -> int:
    parser = ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", nargs="+", default=list(CHECKS))
    parser.add_argument("--starts", type=int, default=8, help="initial states per gait")
    parser.add_argument("--iterations", type=int, help="override the env's solver iterations")
    parser.add_argument("--ls-iterations", type=int, help="override its line-search iterations")
    args = parser.parse_args()
    options = {"solver_iterations": args.iterations, "ls_iterations": args.ls_iterations}
    failed = False
    print(
        f"{'env':12s} {'solver':18s} {'gait':22s} {'v ref':>13s} {'v native':>8s} {'v mjx':>7s} "
        f"{'pitch ref':>9s} {'pitch mjx':>9s} {'err native':>10s} {'err mjx':>8s}  short  ok"
    )
    for name in args.envs:
        check = CHECKS[name]
        s = envs.make(name, **options).solver
        solver = f"{s.solver} {s.iterations}/{s.ls_iterations} {s.jacobian}"
        for r in compare(name, check, args.starts, **options):
            print(
                f"{name:12s} {solver:18s} {r['gait']:22s} "
                f"{r['reference/v']:7.3f}±{r['reference/v_se']:5.3f} "
                f"{r['native/v']:8.3f} {r['mjx/v']:7.3f} {r['reference/pitch']:9.2f} "
                f"{r['mjx/pitch']:9.2f} {r['native/err']:10.4f} {r['mjx/err']:8.4f}  "
                f"{check.short:5d}  {'ok' if r['ok'] else 'FAILED'}",
                flush=True,
            )
            failed |= not r["ok"]
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
