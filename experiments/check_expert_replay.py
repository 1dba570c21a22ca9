"""Do the shipped experts behave the same in native MuJoCo at its default solver settings?

The closed-loop companion of ``check_mjx_dynamics.py``: every MJX env trades solver iterations
(and, for the swimmer and the reacher, contacts) for speed, and its experts were trained on
those fast dynamics. Here each expert is scored twice with
``emgail_jax.host.expert_bars.quality`` (10 deterministic episodes per intention, the same
start states):

- ``mjx``: the env as shipped (MJX, float32, the env's solver settings);
- ``native``: the same env, rewards, termination and observations, but every physics step
  taken by native MuJoCo (``mj_step``, float64) on the model compiled with MuJoCo's defaults
  (Newton, 100 iterations, 50 line-search iterations, contacts on), through ``jax.pure_callback``.

An expert that exploited an artefact of the fast settings (a solver too weak to stop a foot
sinking, a contact that is switched off) would lose its behaviour under the reference. The
check passes if every expert that meets its bar (docs/environments.md, "Experts and shipped
demonstrations") in MJX meets it natively.
Exits with status 1 otherwise.

    python experiments/check_expert_replay.py [--envs hopper reacher]
"""

from __future__ import annotations

import sys

import jax
import mujoco
import numpy as np

import envs
from emgail_jax import experts
from emgail_jax.host import expert_bars, jax_setup
from emgail_jax.host.command_line import ArgumentParser
from envs.mjx_base import mujoco_default_solver

MJX_ENVS = ("swimmer", "hopper", "halfcheetah", "reacher")


def _cell(q: dict, field: str, width: int) -> str:
    value = q.get(field)
    return " " * (width - 1) + "–" if value is None else f"{value:{width}.2f}"


def use_native_physics(env: envs.Env, model: mujoco.MjModel) -> envs.Env:
    """``env`` with its ``physics_step`` replaced by native MuJoCo stepping ``model``.

    Only ``qpos`` and ``qvel`` come back from MuJoCo: every env's rewards and observations are
    functions of them (and of ``mocap_pos``, which no step changes), recomputed by the env.
    """
    frame_skip = env.frame_skip
    native = mujoco.MjData(model)

    def step_natively(qpos, qvel, mocap_pos, ctrl):
        native.qpos[:], native.qvel[:], native.ctrl[:] = qpos, qvel, ctrl
        if model.nmocap:
            native.mocap_pos[:] = mocap_pos
        native.qacc_warmstart[:] = 0.0  # every call starts afresh, as a vmapped batch would
        mujoco.mj_step(model, native, nstep=frame_skip)
        return native.qpos.astype(np.float32), native.qvel.astype(np.float32)

    def physics_step(data, ctrl):
        shapes = (
            jax.ShapeDtypeStruct(data.qpos.shape, data.qpos.dtype),
            jax.ShapeDtypeStruct(data.qvel.shape, data.qvel.dtype),
        )
        qpos, qvel = jax.pure_callback(
            step_natively, shapes, data.qpos, data.qvel, data.mocap_pos, ctrl,
            vmap_method="sequential",
        )  # fmt: skip
        return env.physics_kinematics(data.replace(qpos=qpos, qvel=qvel, ctrl=ctrl))

    env.physics_step = physics_step
    return env


def main() -> int:
    parser = ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", nargs="+", default=list(MJX_ENVS), choices=MJX_ENVS)
    parser.add_argument("--episodes", type=int, default=10)
    args = parser.parse_args()
    jax_setup.setup(host_devices=1)
    key, _ = expert_bars.evaluation_keys()  # the start states `python -m emgail_jax.experts` scores
    print(
        f"{'env':12s} {'intention':10s} {'bar':34s} {'':7s} {'return':>9s} {'velocity':>8s} "
        f"{'upright':>7s} {'turn':>6s} {'reached':>7s}  met"
    )
    failed = False
    for name in args.envs:
        env = envs.make(name)
        policy = experts.load_expert_policy(env)
        if policy is None:
            print(f"{name:12s} no shipped experts")
            failed = True
            continue
        reference = use_native_physics(envs.make(name), env.native_model(mujoco_default_solver()))
        scores = {
            "mjx": expert_bars.quality(env, policy, key, args.episodes),
            "native": expert_bars.quality(reference, policy, key, args.episodes),
        }
        for i, intention in enumerate(env.intention_names):
            for label, rows in scores.items():
                q = rows[i]
                print(
                    f"{name:12s} {intention:10s} {q['bar'] or '':34s} {label:7s} "
                    f"{_cell(q, 'return', 9)} {_cell(q, 'velocity', 8)} "
                    f"{_cell(q, 'upright', 7)} {_cell(q, 'turn', 6)} {_cell(q, 'reached', 7)}  "
                    f"{'yes' if q['meets_bar'] else 'NO'}",
                    flush=True,
                )
            if scores["mjx"][i]["meets_bar"] and not scores["native"][i]["meets_bar"]:
                failed = True
    print("FAILED: an expert loses its behaviour natively" if failed else "ok")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
