"""Env throughput: batched MJX envs against native MuJoCo C on the same CPU, in one run.

MJX: ``reset`` and a ``lax.scan`` of ``vmap(env.step)`` over a batch of envs, the batch split
over the host's CPU devices with ``shard_map`` (this script asks XLA for one host device per
core before JAX is imported). Native: ``mujoco.rollout`` of the same model, with the same solver
settings, from the same initial states, with one thread per core. Both run the same open-loop
actions (a sinusoid per actuator with a random phase per env), held for the env's frame skip.

The MJX number is full env steps (physics, observation, rewards); the native number is physics
only (``mj_step`` x frame skip), and ``mujoco.rollout`` also writes the state after every
physics step. Each number is the best of ``--repeats`` timed runs after a warm-up run, MJX and
native runs alternating (another process on the machine only ever slows a run down, and then
both sides alike). Compile time (reset and rollout) is reported separately.

    python experiments/bench_env_throughput.py [--envs swimmer hopper] [--batch 1024]
"""

from __future__ import annotations

import os

_CORES = os.cpu_count() or 1
os.environ["XLA_FLAGS"] = (
    os.environ.get("XLA_FLAGS", "") + f" --xla_force_host_platform_device_count={_CORES}"
).strip()

import time  # noqa: E402

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import mujoco  # noqa: E402
import numpy as np  # noqa: E402
from jax.sharding import Mesh, PartitionSpec  # noqa: E402
from mujoco import rollout  # noqa: E402

import envs  # noqa: E402
from emgail_jax.host.command_line import ArgumentParser  # noqa: E402

# Target ratio MJX / native (env-steps/s) per env, and the batch that reaches it on 2 cores.
TARGETS = {"swimmer": 1.0, "hopper": 0.5, "halfcheetah": 0.5, "reacher": 1.0}
BATCH = {"swimmer": 1024, "hopper": 1024, "halfcheetah": 512, "reacher": 1024}


def open_loop_actions(phase: jax.Array, t: jax.Array, action_size: int) -> jax.Array:
    """``[B, nu]`` actions at env step ``t``: ``sin(2π f_j t + phase)``, ``f_j`` per env step."""
    frequency = 0.05 * (1.0 + jnp.arange(action_size))
    return jnp.sin(2 * jnp.pi * frequency * t + phase[:, None])


def make_mjx_run(env: envs.Env, batch: int, steps: int, key: jax.Array):
    """Compiles the sharded MJX rollout; returns (run, compile seconds, initial states, phases).

    ``run()`` steps ``batch`` envs ``steps`` times from fixed initial states and blocks.
    """
    devices = jax.devices()
    if batch % len(devices):
        raise SystemExit(f"--batch {batch} must be a multiple of {len(devices)} devices")
    mesh = Mesh(np.array(devices), ("batch",))
    spec = PartitionSpec("batch")

    def shard(fn):
        return jax.jit(jax.shard_map(fn, mesh=mesh, in_specs=spec, out_specs=spec, check_vma=False))

    def rollout_fn(state, phase):
        def body(state, t):
            return jax.vmap(env.step)(state, open_loop_actions(phase, t, env.action_size)), None

        state, _ = jax.lax.scan(body, state, jnp.arange(steps, dtype=jnp.float32))
        return state

    key_reset, key_phase = jax.random.split(key)
    keys = jax.random.split(key_reset, batch)
    phase = jax.random.uniform(key_phase, (batch,), maxval=2 * np.pi)
    start = time.perf_counter()
    state = jax.block_until_ready(shard(jax.vmap(env.reset))(keys))
    compiled = shard(rollout_fn).lower(state, phase).compile()
    compile_s = time.perf_counter() - start
    run = lambda: jax.block_until_ready(compiled(state, phase))
    run()  # warm-up
    return run, compile_s, jax.device_get(state.physics), np.asarray(phase)


def make_native_run(env, initial, phase: np.ndarray, batch: int, steps: int):
    """``run()``: ``mujoco.rollout`` with one thread per core, same model, states and actions."""
    model = env.mj_model
    datas = [mujoco.MjData(model) for _ in range(_CORES)]
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    states = np.zeros((batch, mujoco.mj_stateSize(model, spec)))
    for i in range(batch):
        data = datas[0]
        mujoco.mj_resetData(model, data)
        data.qpos[:] = initial.qpos[i]
        data.qvel[:] = initial.qvel[i]
        if model.nmocap:
            data.mocap_pos[:] = initial.mocap_pos[i]
        mujoco.mj_getState(model, data, states[i], spec)
    t = np.arange(steps, dtype=np.float32)
    actions = np.asarray(
        jax.vmap(lambda t: open_loop_actions(jnp.asarray(phase[:batch]), t, env.action_size))(t)
    )  # [T, B, nu]
    control = np.repeat(actions.transpose(1, 0, 2), env.frame_skip, axis=1).astype(np.float64)
    out = np.zeros((batch, steps * env.frame_skip, states.shape[1]))
    run = lambda: rollout.rollout(model, datas, states, control, state=out, persistent_pool=True)
    run()  # warm-up (and thread-pool creation)
    return run


def timed(run) -> float:
    start = time.perf_counter()
    run()
    return time.perf_counter() - start


def main() -> None:
    parser = ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", nargs="+", default=list(TARGETS))
    parser.add_argument("--batch", type=int, default=None, help="MJX batch (default: per env)")
    parser.add_argument("--native-batch", type=int, default=256)
    parser.add_argument("--steps", type=int, default=100, help="env steps per timed rollout")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    print(
        f"jax {jax.__version__} ({len(jax.devices())} {jax.default_backend()} devices), "
        f"mujoco {mujoco.__version__}, {_CORES} cores; best of {args.repeats} alternating runs"
    )
    rows = []
    for name in args.envs:
        env = envs.make(name)
        batch = args.batch or BATCH.get(name, 1024)
        native_batch = min(batch, args.native_batch)
        key = jax.random.PRNGKey(args.seed)
        mjx_run, compile_s, initial, phase = make_mjx_run(env, batch, args.steps, key)
        native_run = make_native_run(env, initial, phase, native_batch, args.steps)
        # Alternate, so that both see the same load from anything else on the machine.
        times = np.array([(timed(mjx_run), timed(native_run)) for _ in range(args.repeats)])
        mjx_rate = batch * args.steps / times[:, 0].min()
        native_rate = native_batch * args.steps / times[:, 1].min()
        s = env.solver
        off = "-".join(s.disable) or "none"
        solver = f"{s.solver} {s.iterations}/{s.ls_iterations} {s.jacobian} off:{off}"
        rows.append((name, batch, mjx_rate, native_rate, TARGETS.get(name), compile_s, solver))
        print(f"  {name}: MJX {mjx_rate:,.0f}/s, native {native_rate:,.0f}/s", flush=True)

    header = (
        f"{'env':12s} {'batch':>6s} {'MJX steps/s':>12s} {'native steps/s':>15s} "
        f"{'MJX/native':>10s} {'target':>6s} {'compile s':>9s}  solver (iters/ls, jacobian, off)"
    )
    print("\n" + header + "\n" + "-" * len(header))
    for name, batch, mjx_rate, native_rate, target, compile_s, solver in rows:
        ratio = mjx_rate / native_rate
        verdict = "" if target is None else ("ok" if ratio >= target else "miss")
        print(
            f"{name:12s} {batch:6d} {mjx_rate:12,.0f} {native_rate:15,.0f} {ratio:10.2f} "
            f"{(target or 0):>6.1f} {compile_s:9.1f}  {solver}  {verdict}"
        )


if __name__ == "__main__":
    main()
