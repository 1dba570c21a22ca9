"""Where a fresh agent trained on a learned reward goes: one run seed's reward check, traced.

    python experiments/fresh_agent_drive.py RUN_DIR [--seed S] [--rl-seed R] [--every N]

Trains the fresh TRPO agents of ``python -m emgail_jax.reoptimize RUN_DIR --seed S --rl-seed R``
(the same keys, reward and budget) and prints, for each learned intention, its deterministic
episode from the env's first reset: the true returns under every true intention, the learned
reward per step it earns there, and the env's trace (the driver's x, y) every N steps. A
failing agent's trace shows what the learned reward pays off the demonstrations
(docs/notebook/rewards-that-reoptimise.md, experiment 18). Then where the episode sits in the
discriminator's input box: each observation dimension the normalisation clips (with the share
of steps at the clip and the mean |z|), the mean |action| against the demonstrations', and the
learned reward per step with the agent's own actions against zero actions in the same states
(experiment 26).
"""

from __future__ import annotations

import numpy as np

from emgail_jax.host.command_line import ArgumentParser


def main(argv=None) -> int:
    parser = ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("run_dir")
    parser.add_argument(
        "--seed", type=int, default=None, help="as run --seed numbers it (default: the first)"
    )
    parser.add_argument("--rl-seed", type=int, default=0)
    parser.add_argument("--every", type=int, default=10, help="trace every N steps")
    args = parser.parse_args(argv)

    from emgail_jax.host import jax_setup

    jax_setup.setup(host_devices=1)
    import jax

    from emgail_jax.host.saved_run import SavedRun, stacked
    from emgail_jax.reward import check

    run = SavedRun.open(args.run_dir)
    env, k = run.problem.env, run.num_intentions
    seed = run.seed_index(args.seed)
    learned, parameters = run.reward_function(), run.reward_parameters(seed)
    budget = check.default_budget(run)
    trainer = check.learned_reward_trainer(run, budget, learned)
    keys = check.fresh_keys(run, [seed], args.rl_seed)
    fresh = check.train_fresh(
        trainer, keys, stacked([parameters]), budget.iterations, label="fresh agents"
    )
    env_step, reset = jax.jit(env.step), jax.jit(env.reset)
    for intention in range(k):
        policy = jax.jit(trainer.policy(jax.tree.map(lambda x, i=intention: x[0, i], fresh.states)))
        state = reset(jax.random.PRNGKey(0))
        true, earned, trace, visited = [], [], [], []
        for _ in range(env.episode_length):  # until the time limit or a termination
            action = policy(state.obs, None)
            visited.append((np.asarray(state.obs), np.asarray(env.clip_action(action))))
            earned.append(float(learned(parameters, state.obs, action, intention)))
            state = env_step(state, action)
            true.append(np.asarray(state.reward))
            trace.append({name: float(v) for name, v in env.trace(state).items()})
            if float(state.done):
                break
        returns = [round(float(r), 1) for r in np.sum(true, 0)]
        print(
            f"learned intention {intention}: true returns {returns}, learned reward per step "
            f"{np.mean(earned):.3f}"
        )
        for step in range(0, len(trace), args.every):
            where = ", ".join(f"{name} {value:.2f}" for name, value in trace[step].items())
            print(f"  step {step + 1}: {where}")
        print_input_box(run, parameters, learned, intention, visited)
    return 0


def print_input_box(run, parameters, learned, intention, visited) -> None:
    """Where the episode's ``visited`` (obs, executed action) pairs sit in the discriminator's
    inputs: the observation dimensions at the normalisation's clip, and what the reward pays
    for the agent's own actions there against zero actions."""
    obs = np.stack([o for o, _ in visited])
    actions = np.stack([a for _, a in visited])
    from emgail_jax.method.normalizer import normalize

    # Unclipped, to see how far beyond the clip the episode goes.
    z = np.asarray(normalize(parameters["normalizer"], obs, np.inf))
    clip = run.config.method.networks.obs_clip
    at_clip = (np.abs(z) >= clip).mean(0)
    dims = ", ".join(
        f"{d} ({at_clip[d]:.0%}, |z| {np.abs(z[:, d]).mean():.1f})"
        for d in np.flatnonzero(at_clip > 0)
    )
    demos = np.abs(np.asarray(run.demonstration_pairs.actions)).mean()
    own = np.asarray(learned(parameters, obs, actions, intention)).mean()
    still = np.asarray(learned(parameters, obs, np.zeros_like(actions), intention)).mean()
    print(f"  observation dimensions at the clip ±{clip:g}: {dims or 'none'}")
    print(f"  mean |action| {np.abs(actions).mean():.2f} (the demonstrations' {demos:.2f})")
    print(f"  learned reward per step: own actions {own:.3f}, zero actions {still:.3f}")


if __name__ == "__main__":
    raise SystemExit(main())
