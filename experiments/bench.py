"""Where the time goes: EM-GAIL's iteration, its pieces, its compile, its memory, and two floors.

    python experiments/bench.py [--envs driver:2 halfcheetah:3] [--seeds 1 2 4] [--chunks 2]

For every ``ENV:K`` (default: driver-2 and halfcheetah-3, EM-GAIL, default settings), in a fresh
process of its own (so that its compilation cache starts empty and its peak memory is its own):

- seconds per seed-iteration with 1, 2 and 4 seeds (seeds sharded over the cores), timed over
  ``--chunks`` chunks of 10 iterations in the steady state of a run: one iteration in ten runs
  the evaluation episodes (``--eval-every 10``), as in the middle of a 400-iteration run;
- the same iteration in pieces, each compiled alone on the same shapes for one seed and timed
  on one core: the rollout, the E-step, the M-step, the B-step (TRPO and the value fit) and the
  evaluation episodes (shown per evaluation and per iteration at the default cadence);
- compile time of the 2-seed run (``init`` and a chunk of 10 iterations) with an empty
  compilation cache, and again with the cache that compile filled (a new process would see the
  same: only the cache carries over); where the cold compile goes: ``init`` alone, each piece
  compiled alone, and for the MJX envs one physics step alone (``frame_skip`` MJX steps);
- peak resident memory of the process;
- two ratios: against the native-MuJoCo floor (the time ``mujoco.rollout``, one thread per
  core, takes for the env steps one iteration takes at the env's solver settings: physics only,
  no learning) and against the reference implementation (tue-mps/EM-GAIL, PyTorch + mujoco-py,
  timed on this CPU: swimmer-2 5.14 s, halfcheetah-3 8.49 s per iteration without its
  per-iteration evaluation, 8.53 s and 15.0 s with it).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time

from emgail_jax.host.command_line import ArgumentParser

# Seconds per iteration of the reference implementation on this CPU (one seed): training only,
# and with the evaluation it runs after every iteration.
REFERENCE_S = {"swimmer-2": (5.14, 8.53), "halfcheetah-3": (8.49, 15.0)}
CHUNK = 10
EVAL_EVERY = 10


def child(env_name: str, k: int, seed_counts: list[int], chunks: int, cache: str) -> dict:
    """Everything measured for one env, in this process (see the module docstring)."""
    from emgail_jax.host import jax_setup

    jax_setup.setup(cache_dir=cache)
    import jax

    from emgail_jax.host.problem import make_problem
    from emgail_jax.method.batches import DemonstrationPairs
    from emgail_jax.method.config import RunConfig, RunSchedule
    from emgail_jax.method.training import RunData, evaluation_phases, make_train

    problem = make_problem(env_name, k)
    env = problem.env
    run_config = RunConfig(schedule=RunSchedule(eval_every=EVAL_EVERY)).resolved(env)
    config = run_config.method
    pairs = DemonstrationPairs.create(problem.demos, problem.random_returns, env.num_intentions)
    data = RunData.create(pairs, env, run_config.info_weight)
    trainer = make_train(config, env)
    result = {"env": f"{env_name}-{k}"}
    result.update(time_runs(trainer, data, seed_counts, chunks))

    state = jax.jit(trainer.init)(jax.random.PRNGKey(0), data)
    pieces = piece_programs(config, env, state, data)
    result["pieces_s"], result["pieces_compile_s"] = time_pieces(pieces, env_name)
    if hasattr(env, "mj_model"):  # the physics alone, compiled only: its share of the rollout's
        # [K, B] -> [K * B], shapes explicit: some MJX leaves have zero size.
        flatten = lambda x: x.reshape(x.shape[0] * x.shape[1], *x.shape[2:])
        flat = jax.tree.map(flatten, state.env_state.physics)
        physics = (jax.vmap(env.physics_step), (flat, flat.ctrl))
        result["pieces_compile_s"]["physics step"] = compile_timed(*physics)[1]

    result["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    phases = evaluation_phases(config, env)
    rollout = config.rollout
    steps_per_iteration = k * rollout.num_envs * rollout.rollout_length * (1 + phases / EVAL_EVERY)
    result["env_steps_per_iteration"] = steps_per_iteration
    if hasattr(env, "mj_model"):
        result["native_s"] = native_seconds(env, steps_per_iteration)
    return result


def time_runs(trainer, data, seed_counts: list[int], chunks: int) -> dict:
    """Seconds per seed-iteration of whole chunks for every seed count, and the 2-seed run's
    compile times (cold, its ``init`` alone, and warm)."""
    import jax

    from emgail_jax.host.schedule import evaluation_plan
    from emgail_jax.host.seed_runner import Runner

    # A chunk in the middle of a 400-iteration run: one evaluation in ten iterations.
    steady = evaluation_plan(100, CHUNK, 400, EVAL_EVERY)
    result = {"seconds_per_seed_iteration": {}}
    for seeds in seed_counts:
        runner = Runner(trainer.init, trainer.update, seeds, data)
        state = runner.init(jax.random.PRNGKey(0))
        init_s = runner.timings.compile_s
        runner.compile(state, steady)
        if seeds == 2:
            result["compile_cold_s"] = runner.timings.compile_s
            result["compile_cold_init_s"] = init_s
            warm = Runner(trainer.init, trainer.update, seeds, data)
            warm.compile(warm.init(jax.random.PRNGKey(0)), steady)
            result["compile_warm_s"] = warm.timings.compile_s
        state, _ = runner.step(state, steady)  # the first call allocates; not timed
        start = time.perf_counter()
        for _ in range(chunks):
            state, _ = runner.step(state, steady)
        elapsed = time.perf_counter() - start
        result["seconds_per_seed_iteration"][seeds] = elapsed / (chunks * CHUNK * seeds)
    return result


def piece_programs(config, env, state, data) -> dict:
    """``{piece: (function, args)}``: the pieces of one update, composed of the trainer's
    public stages on the shapes of a real iteration (one seed): the rollout, the E-step, the
    M-step, the B-step (the learned reward, TRPO and the value fit) and the evaluation."""
    import jax
    import jax.numpy as jnp

    from emgail_jax.method import normalizer as obs_norm
    from emgail_jax.method import training
    from emgail_jax.method.batches import LearningBatch
    from emgail_jax.method.rollout import episode_totals, fresh_starts, time_major

    networks = training.make_networks(config, env)
    stages = training.make_policy_stages(config, env, networks)
    learned = training.LearnedRewardStage.create(
        config, env, networks, training.make_optimizers(config)
    )
    algorithm = training.algorithm_of(config, data)
    key, k = jax.random.PRNGKey(1), env.num_intentions

    def rollout(state, data, explore=True):
        policy = stages.acting(state.policy, state.normalizer, explore)
        return stages.collect(training.training_env(env, data), policy, state.env_state, key)

    end, transitions = jax.jit(rollout)(state, data)
    batch = LearningBatch.of(transitions, end, env.episode_length)
    normalizer = obs_norm.update(state.normalizer, transitions.obs)
    seen = training.normalized_batch(
        normalizer, transitions, data.demos, env, config.networks.obs_clip
    )
    e = jax.jit(learned.e_step)(state.posterior, seen, data.demos, state.intention_weights)
    m_step = lambda discriminator, seen, gamma: learned.m_step(
        discriminator, seen, gamma, algorithm
    )
    discriminator = jax.jit(m_step)(state.discriminator, seen, e.gamma).discriminator

    def b_step(state, batch, seen, discriminator, own_log_posterior):
        reward = learned.pseudo_reward(discriminator, algorithm, seen, own_log_posterior)
        reward = time_major(reward, config.rollout.rollout_length)
        return stages.improve(state, batch, seen.normalizer, reward, key)

    def evaluation(state, data):
        def phase(carry, index):
            env_state, totals, alive = carry
            # Explore off as a traced flag, as in training's evaluation phases.
            policy = stages.acting(state.policy, state.normalizer, jnp.asarray(False))
            train_env = training.training_env(env, data)
            end, batch = stages.collect(
                train_env, policy, env_state, jax.random.fold_in(key, index)
            )
            more, alive = episode_totals(batch, alive)
            return (end, totals + more, alive), None

        shape = (k, config.rollout.num_envs)
        carry = (fresh_starts(state.env_state), jnp.zeros((*shape, k)), jnp.ones(shape))
        phases = jnp.arange(training.evaluation_phases(config, env))
        return jax.lax.scan(phase, carry, phases)[0][1]

    return {
        "rollout": (rollout, (state, data)),
        "E-step": (learned.e_step, (state.posterior, seen, data.demos, state.intention_weights)),
        "M-step": (m_step, (state.discriminator, seen, e.gamma)),
        "B-step": (b_step, (state, batch, seen, discriminator, e.own_log_posterior)),
        "evaluation": (evaluation, (state, data)),
    }


def compile_timed(function, args):
    import jax

    start = time.perf_counter()
    compiled = jax.jit(function).lower(*args).compile()
    return compiled, time.perf_counter() - start


def time_pieces(pieces: dict, env_name: str) -> tuple[dict, dict]:
    """``(seconds per call, compile seconds)`` of every piece, each compiled alone."""
    import jax

    seconds, compile_seconds = {}, {}
    for name, (function, args) in pieces.items():
        compiled, compile_seconds[name] = compile_timed(function, args)
        jax.block_until_ready(compiled(*args))
        repeats = 5 if env_name == "driver" else 3
        start = time.perf_counter()
        for _ in range(repeats):
            jax.block_until_ready(compiled(*args))
        seconds[name] = (time.perf_counter() - start) / repeats
    return seconds, compile_seconds


def native_seconds(env, env_steps: float) -> float:
    """Seconds native MuJoCo (``mujoco.rollout``, one thread per core, the env's model and
    solver settings, open-loop actions) takes for ``env_steps`` env steps."""
    import jax
    import numpy as np

    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from bench_env_throughput import make_native_run, timed

    batch, steps = 256, 100
    keys = jax.random.split(jax.random.PRNGKey(0), batch)
    initial = jax.device_get(jax.jit(jax.vmap(env.reset))(keys).physics)
    phase = np.random.default_rng(0).uniform(0, 2 * np.pi, batch)
    run = make_native_run(env, initial, phase, batch, steps)
    seconds = min(timed(run) for _ in range(3))
    return env_steps * seconds / (batch * steps)


def print_table(results: list[dict], seed_counts: list[int]) -> None:
    print()
    for r in results:
        per_seed = r["seconds_per_seed_iteration"]
        name = r["env"]
        print(f"== {name} (EM-GAIL, default settings, eval every {EVAL_EVERY}) ==")
        for seeds in seed_counts:
            print(f"  {seeds} seed(s): {per_seed[str(seeds)]:.3f} s per seed-iteration")
        pieces = r["pieces_s"]
        amortised = dict(pieces)
        amortised["evaluation"] = pieces["evaluation"] / EVAL_EVERY
        total = sum(amortised.values())
        print("  pieces, one seed on one core (evaluation: per evaluation / per iteration):")
        for piece, seconds in pieces.items():
            extra = f" / {amortised[piece]:.3f}" if piece == "evaluation" else ""
            print(f"    {piece:11s} {seconds:7.3f} s{extra}  ({amortised[piece] / total:5.1%})")
        print(f"    {'sum':11s} {total:7.3f} s per iteration")
        print(
            f"  compile (2 seeds, init + chunk): cold {r['compile_cold_s']:.1f} s, "
            f"warm cache {r['compile_warm_s']:.1f} s"
        )
        compiles = ", ".join(f"{n} {s:.1f}" for n, s in r["pieces_compile_s"].items())
        init_s = r["compile_cold_init_s"]
        print(f"    cold, init alone {init_s:.1f} s; pieces alone (s): {compiles}")
        print(f"  peak resident memory {r['peak_rss_mb']:.0f} MB")
        reference_seconds = per_seed[str(2)] if "2" in per_seed else per_seed[str(seed_counts[0])]
        if "native_s" in r:
            steps = r["env_steps_per_iteration"]
            print(
                f"  native MuJoCo floor: {r['native_s']:.3f} s for the {steps:,.0f} env steps of "
                f"an iteration -> ours / floor = {reference_seconds / r['native_s']:.1f}"
            )
        if name in REFERENCE_S:
            train_only, with_eval = REFERENCE_S[name]
            print(
                f"  reference implementation: {train_only} s per iteration training only "
                f"({train_only / reference_seconds:.0f}x ours), {with_eval} s with its "
                f"evaluation every iteration"
            )
    print()


def main(argv=None) -> int:
    parser = ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--envs", nargs="+", default=["driver:2", "halfcheetah:3"])
    parser.add_argument("--seeds", nargs="+", type=int, default=[1, 2, 4])
    parser.add_argument("--chunks", type=int, default=2, help="timed chunks of 10 iterations")
    parser.add_argument("--child", nargs=2, metavar=("ENV", "K"), help=argparse.SUPPRESS)
    parser.add_argument("--json", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if 2 not in args.seeds:
        parser.error("--seeds must include 2 (the compile times are measured there)")

    if args.child:
        with tempfile.TemporaryDirectory() as cache:
            result = child(args.child[0], int(args.child[1]), args.seeds, args.chunks, cache)
        with open(args.json, "w") as f:
            json.dump(result, f)
        return 0

    results = []
    with tempfile.TemporaryDirectory() as tmp:
        for spec in args.envs:
            name, k = spec.split(":")
            out = os.path.join(tmp, f"{name}.json")
            command = [sys.executable, os.path.abspath(__file__), "--child", name, k]
            command += ["--json", out, "--chunks", str(args.chunks), "--seeds"]
            command += [str(s) for s in args.seeds]
            print(f"measuring {name}-{k} ...", flush=True)
            subprocess.run(command, check=True)
            with open(out) as f:
                results.append(json.load(f))
    print_table(results, args.seeds)
    return 0


if __name__ == "__main__":
    sys.exit(main())
