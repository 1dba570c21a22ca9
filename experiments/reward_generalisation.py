"""Does a run's learned reward recognise its experts beyond the demonstrations it was trained on?

    python experiments/reward_generalisation.py RUN_DIR [--episodes N] [--refit NAME]
        [--reward-form FORM] [--along-training EVERY] [--snapshot ITER]

Per run seed, the learned reward per step of each true intention's reward (the learned
intention the run matched it to) earned by:

- the demonstrations of that intention (weighted by the run's responsibilities, as
  ``reoptimize`` reports them);
- the env's own experts on fresh episodes: new resets (the reacher's balls elsewhere), the
  shipped expert policies of the MJX envs or the driver's analytic controller, noiseless;
- the run's jointly trained policies on fresh episodes;
- uniformly random actions on fresh episodes;
- actions held at the middle of their range (no torque) on fresh episodes: an agent that
  does nothing (experiment 47).

A reward that stands for the task pays the experts' fresh episodes about what it pays the
demonstrations. One that pays them what it pays random actions has learned which episodes
were demonstrated, not what the experts did, and a fresh agent trained on it has nothing to
climb (docs/notebook/rewards-that-reoptimise.md, experiment 27).

``--along-training EVERY``: the same reward earned by the run's own policies of every EVERY-th
snapshot, beside their true returns (``metrics.csv``), with the rank correlation of the two
(docs/notebook/rewards-that-reoptimise.md, experiment 41): a reward that rises with the true return
along the run's own way from random actions to the experts has a slope a fresh agent could
follow. ``--refit NAME`` scores a refitted reward that ``python -m emgail_jax.refit`` saved,
``--reward-form`` reads the discriminator in another form, ``--snapshot ITER`` opens the run
at that snapshot (its networks and policies; a refit ``reoptimize --snapshot ITER`` saved).
"""

from __future__ import annotations

import sys

from emgail_jax.host.command_line import ArgumentParser


def learned_reward_per_step(env, act, reward, key, rows, episodes: int):
    """Mean of ``reward(obs, action, reward_rows) [P, E]`` over the live steps of ``episodes``
    fresh episodes per row of ``rows [P]`` acted by ``act(state [P, E], key) -> action``:
    ``[P]``."""
    import jax
    import jax.numpy as jnp

    import envs
    from emgail_jax.method.rollout import batch_reset

    limited = envs.EpisodeWrapper(env)
    p = rows.shape[0]
    key_reset, key_steps = jax.random.split(key)
    state = batch_reset(limited, key_reset, (p, episodes))
    step = jax.vmap(jax.vmap(limited.step))
    reward_rows = jnp.broadcast_to(rows[:, None], (p, episodes))

    def body(carry, step_key):
        state, alive, total = carry
        action = act(state, step_key)
        earned = reward(state.obs, limited.clip_action(action), reward_rows)
        total = total + jnp.where(alive > 0, earned, 0.0)
        next_state = step(state, action)
        return (next_state, alive * (1.0 - next_state.done), total), alive

    zeros = jnp.zeros((p, episodes))
    steps = jax.random.split(key_steps, limited.episode_length)
    (_, _, total), alive = jax.lax.scan(body, (state, zeros + 1.0, zeros), steps)
    return total.sum(1) / alive.sum((0, 2))


def expert_actor(env, rows):
    """The env's noiseless experts as ``act(state [P, E], key)``, row p the true intention
    ``rows[p]``; None if the env has none."""
    import jax
    import jax.numpy as jnp

    from emgail_jax import experts

    grid = lambda state: jnp.broadcast_to(rows[:, None], state.obs.shape[:2])
    if hasattr(env, "expert_action"):  # the driver's analytic controller
        analytic = jax.vmap(jax.vmap(env.expert_action))
        return lambda state, _: analytic(state, grid(state))
    policy = experts.load_expert_policy(env)
    if policy is None:
        return None
    return lambda state, _: policy(state.obs, grid(state))


def matched_reward(run, seed: int, parameters):
    """``(matching [K true], rows, learned, reward)``: the learned intention the run finally
    matched to each true intention (as ``rows``, a device array), the run's reward function,
    and it jitted on ``parameters`` as ``reward(obs, action, intention)``."""
    import jax
    import jax.numpy as jnp

    from emgail_jax.reward import check

    matching = check.run_matching(run, seed, run.snapshot or run.iteration)  # true -> learned
    learned = run.reward_function()
    reward = jax.jit(lambda obs, action, i: learned(parameters, obs, action, i))
    return matching, jnp.asarray(matching), learned, reward


def seed_columns(run, seed: int, parameters, experts, keys, episodes: int):
    """``([demonstrations, experts, joint policies, random, still] each [K true], matching)``
    for run ``seed``, scored by the reward of ``parameters``: true intention i by the learned
    intention ``matching[i]`` the run matched it to, whose policy also acts for it."""
    import numpy as np

    from emgail_jax.method.rollout import still_policy, uniform_random_policy
    from emgail_jax.reward import check

    env, k_true = run.problem.env, run.problem.true_intentions
    matching, rows, learned, reward = matched_reward(run, seed, parameters)
    policy, random, still = run.policy(seed), uniform_random_policy(env), still_policy(env)
    actors = [
        experts,
        lambda state, _: policy(state.obs, rows[:, None]),
        lambda state, key: random(state.obs, key),
        lambda state, key: still(state.obs, key),
    ]
    fresh = [
        np.asarray(learned_reward_per_step(env, act, reward, key, rows, episodes))
        if act is not None
        else np.full(k_true, np.nan)
        for act, key in zip(actors, keys, strict=True)
    ]
    demonstrations = check.demonstrations_reward(run, seed, parameters, learned)
    demonstrations = demonstrations[np.asarray(matching)]
    return [demonstrations, *fresh], [int(i) for i in matching]


def along_training(run, seed: int, parameters, every: int, episodes: int, key):
    """``[(iteration, learned reward per step [K true], true return [K true])]``: the run's own
    policies of every ``every``-th snapshot of ``seed`` on fresh episodes, scored by the reward
    of ``parameters``; true intention i by the learned intention the run finally matched to it,
    its true return the last one ``metrics.csv`` logged at or before that iteration."""
    import dataclasses

    import numpy as np

    from emgail_jax.host import checkpoints

    _, rows, _, reward = matched_reward(run, seed, parameters)
    logged = np.asarray(run.history["eval/returns"][seed])  # [iterations, K true], NaN between
    evaluated = np.flatnonzero(np.isfinite(logged).all(1)) + 1  # the iterations evaluated
    held = run.snapshot or run.iteration
    kept = checkpoints.snapshot_iterations(run.run_dir)
    iterations = [i for i in kept if i % every == 0 and i <= held]
    found = []
    for iteration in iterations:
        state = checkpoints.restore_snapshot(run.run_dir, iteration, run.state)
        policy = dataclasses.replace(run, state=state).policy(seed)
        act = lambda state, _, policy=policy: policy(state.obs, rows[:, None])
        earned = learned_reward_per_step(run.problem.env, act, reward, key, rows, episodes)
        last = evaluated[evaluated <= iteration]
        true = logged[last[-1] - 1] if len(last) else np.full(logged.shape[1], np.nan)
        found.append((iteration, np.asarray(earned), true))
    return found


def print_along_training(run, seed: int, parameters, every: int, episodes: int) -> None:
    import jax
    import numpy as np
    from scipy.stats import spearmanr

    key = jax.random.PRNGKey(2027)
    found = along_training(run, seed, parameters, every, episodes, key)
    number = run.seed_number(seed)
    print(f"seed {number}: iteration, learned reward per step / true return per true intention")
    for iteration, earned, true in found:
        cells = ", ".join(f"{e:.3f} / {t:.1f}" for e, t in zip(earned, true, strict=True))
        print(f"  {iteration:4d}  {cells}")
    earned = np.stack([f[1] for f in found])
    true = np.stack([f[2] for f in found])
    for i in range(earned.shape[1]):
        rho = spearmanr(earned[:, i], true[:, i]).statistic
        print(f"seed {number}, true intention {i}: rank correlation {rho:.2f}")


def main(argv=None) -> int:
    parser = ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("run_dir")
    parser.add_argument("--episodes", type=int, default=20, help="fresh episodes per row")
    parser.add_argument("--refit", default=None, help="a refitted reward saved in the run")
    parser.add_argument("--reward-form", default=None, help="gail, logit or log-d")
    parser.add_argument("--along-training", type=int, default=0, metavar="EVERY")
    parser.add_argument("--snapshot", type=int, default=None, metavar="ITER")
    args = parser.parse_args(argv)
    if args.episodes < 1 or args.along_training < 0:
        print("error: --episodes must be at least 1, --along-training at least 0", file=sys.stderr)
        return 2

    from emgail_jax.host import jax_setup

    jax_setup.setup(host_devices=1)
    import jax
    import jax.numpy as jnp

    from emgail_jax.host.saved_run import SavedRun
    from emgail_jax.reward.load import refitted_parameters, run_for_refit

    try:
        run = SavedRun.open(args.run_dir, snapshot=args.snapshot)
        if args.reward_form is not None:
            run = run.with_reward_form(args.reward_form)
        if args.refit:
            run = run_for_refit(run, args.refit)  # an absorbing refit reads one input more
        parameters = [
            refitted_parameters(run, args.refit, s) if args.refit else run.reward_parameters(s)
            for s in range(run.spec.seeds)
        ]
    except ValueError as error:  # the run's, its checkpoint's, env's and demonstrations' errors
        print(f"error: {error}", file=sys.stderr)
        return 2
    if args.along_training:
        for seed in range(run.spec.seeds):
            print_along_training(run, seed, parameters[seed], args.along_training, args.episodes)
        return 0
    experts = expert_actor(run.problem.env, jnp.arange(run.problem.true_intentions))
    # Experts, joint policies, random: the keys they had before the still column came.
    keys = [*jax.random.split(jax.random.PRNGKey(2026), 3), jax.random.PRNGKey(2027)]
    print(f"learned reward per step of each true intention's reward, {args.episodes} fresh")
    print(
        "episodes per row (demonstrations / experts / joint policies / random actions / "
        "actions held still):"
    )
    for seed in range(run.spec.seeds):
        columns, matching = seed_columns(run, seed, parameters[seed], experts, keys, args.episodes)
        for i, learned_intention in enumerate(matching):
            values = " / ".join(f"{column[i]:.3f}" for column in columns)
            label = f"seed {run.spec.first_seed + seed}, true intention {i}"
            print(f"{label} (learned {learned_intention}): {values}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
