"""The reward check: is a learned reward a reward? (paper §5.2, eq. 28)

Fresh TRPO policies trained from scratch on a run's frozen learned reward, one per learned
intention and run seed in one vmapped program, scored under the env's true rewards: ERD with
the run's own matching of intentions and the experts' success bars, and the run's own policies
deployed in a variant of the env's dynamics. Beside them the true-reward baseline
(:mod:`~emgail_jax.reward.baseline`); several RL draws kept by the learned reward alone
(:mod:`~emgail_jax.reward.draws`). ``python -m emgail_jax.reoptimize``
(:mod:`emgail_jax.reoptimize`) is its command line.
"""

from __future__ import annotations

import dataclasses
import functools
import time

import numpy as np

from emgail_jax.host.schedule import FINAL_WINDOW, evaluation_plan
from emgail_jax.reward.progress import PartialTraining

# The fresh agents are scored on evaluation episodes every CURVE_EVERY-th iteration and each of
# the last FINAL_WINDOW (their final numbers), as training scores its policies.
CURVE_EVERY = 10


@dataclasses.dataclass(frozen=True)
class Budget:
    """What the fresh policies get: TRPO iterations, the discount, GAE's lambda and whether
    their value baselines fit scaled targets (:class:`~emgail_jax.method.value.ValueLearner`)."""

    iterations: int
    gamma: float
    gae_lambda: float
    value_target_scaling: bool = False


SUCCESS_EPISODES = 10  # the experts' bars are defined over 10 deterministic episodes


def drawn(key, rl_seed: int):
    """``key`` for RL seed ``rl_seed``: folded with it, RL seed 0 the key itself (the draw
    every check made before there were RL seeds)."""
    import jax

    return jax.random.fold_in(key, rl_seed) if rl_seed else key


def env_budget(
    declared: dict, iterations: int, gamma: float, gae_lambda: float, value_target_scaling=False
) -> Budget:
    """A run's own TRPO iterations, gamma, lambda and value target scaling, with what its env
    declares in their place (``declared``: :attr:`envs.Env.rl_budget`)."""
    own = Budget(iterations, gamma, gae_lambda, value_target_scaling)
    return dataclasses.replace(own, **declared)


def default_budget(run) -> Budget:
    """The fresh agents' budget of ``run``: its own, with its env's declared budget in place."""
    import envs

    b_step = run.config.method.b_step
    return env_budget(
        envs.env_class(run.spec.env).rl_budget,
        run.config.schedule.iterations,
        b_step.gamma,
        b_step.gae_lambda,
        b_step.value_target_scaling,
    )


@dataclasses.dataclass
class FreshAgents:
    """What training fresh policies on a reward left: per reward row ``S`` and policy ``K``."""

    states: object  # RLState [S, K]
    returns: np.ndarray  # [S, iterations, K, K env] deterministic true returns
    earned: np.ndarray  # [S, iterations, K] the reward trained on, per step
    compile_s: float
    train_s: float


def train_fresh(
    trainer,
    keys,
    reward_data,
    iterations: int,
    *,
    label: str,
    progress: bool = True,
    partial: PartialTraining | None = None,
    curve_every: int = CURVE_EVERY,
):
    """Trains ``trainer``'s policies from ``keys [S, K]`` (policy k of row s on intention k of
    the reward ``reward_data[s]``) for ``iterations``, in chunks of 10; with ``partial``, from
    where its save left off, saving as it goes. Scores them every ``curve_every``-th iteration
    and each of the last :data:`FINAL_WINDOW`; the returns of the others are NaN."""
    import jax
    import jax.numpy as jnp

    from emgail_jax.host.progress import ProgressBar
    from emgail_jax.host.seed_runner import chunk_length, chunks, run_chunks
    from emgail_jax.method.rl import seeds_chunk

    k = keys.shape[1]
    states = jax.jit(jax.vmap(jax.vmap(trainer.init)))(keys)
    length = chunk_length(iterations, 10)
    done, returns, earned, train_before = 0, [], [], 0.0
    resumed = partial.read(states, length, iterations) if partial else None
    if resumed is not None:
        done, states, returns_so_far, earned_so_far, train_before = resumed
        returns, earned = [returns_so_far], [earned_so_far]
    plan = chunks(done, iterations, length)
    evaluating = lambda first, length: evaluation_plan(first, length, iterations, curve_every)
    start = time.perf_counter()
    chunk = seeds_chunk(trainer, jnp.arange(k))
    step = chunk.lower(states, evaluating(0, length), reward_data).compile()
    compile_s = time.perf_counter() - start
    bar = ProgressBar(label, iterations, {"return": "-"}, completed=done, enabled=progress)
    start = saved_at = time.perf_counter()

    def after_chunk(first, length, states, metrics) -> bool:
        nonlocal saved_at
        returns.append(np.asarray(metrics["eval/returns"]))  # [L, S, K, K env]
        earned.append(np.asarray(metrics["train/reward"]))  # [L, S, K]
        evaluated = np.flatnonzero(evaluating(first, length))
        texts = {}
        if len(evaluated):  # the chunk's last scored iteration, mean over the rows
            own = np.diagonal(returns[-1][evaluated[-1]], axis1=-2, axis2=-1).mean(0)
            texts["return"] = " ".join(f"{r:.1f}" for r in own)
        bar.update(length, **texts)
        now = time.perf_counter()
        if partial and now - saved_at >= partial.every_s and first + length < iterations:
            train_s = train_before + now - start
            partial.write(first + length, states, *map(np.concatenate, (returns, earned)), train_s)
            saved_at = now
        return True

    run = lambda s, flags: step(s, flags, reward_data)
    states = run_chunks(run, states, plan, evaluating, after_chunk)
    bar.close()
    train_s = train_before + time.perf_counter() - start
    to_seed_major = lambda parts: np.swapaxes(np.concatenate(parts), 0, 1)
    return FreshAgents(states, to_seed_major(returns), to_seed_major(earned), compile_s, train_s)


def success(env, trainer, states, matching) -> list[dict]:
    """The experts' quality and bars (:func:`~emgail_jax.host.expert_bars.quality`) of the
    fresh policies ``states [K]``, true intention i acted by learned policy ``matching[i]``."""
    import jax
    import jax.numpy as jnp

    from emgail_jax.host import expert_bars

    acting = jnp.asarray(matching)

    def policy(obs, intention):
        every = jax.vmap(lambda state: trainer.policy(state)(obs, None))(states)  # [K, ..., A]
        chosen = acting[intention]
        return jnp.take_along_axis(every, chosen[None, ..., None], axis=0)[0]

    key_quality, _ = expert_bars.evaluation_keys()
    k_true = len(matching)
    return expert_bars.quality(env, policy, key_quality, SUCCESS_EPISODES)[:k_true]


def episode_share(q: dict) -> float | None:
    """The share of an agent's episodes that meet its experts' bar each alone, of its
    :func:`success` entry ``q``; of an entry recorded before that share was, its reached share
    where it has one (a bar that holds each episode to reaching its ball); None otherwise."""
    return q.get("episodes_meeting_bar", q.get("reached"))


def mean_or_none(values: list) -> float | None:
    """The mean of ``values``; None where there are none or one is unknown."""
    return None if not values or None in values else float(np.mean(values))


def sample_std(values: list) -> float | None:
    """The sample standard deviation of ``values`` (ddof 1); None for fewer than 2 or one
    unknown."""
    return None if len(values) < 2 or None in values else float(np.std(values, ddof=1))


def success_summary(agents: list[dict]) -> dict:
    """Over ``agents`` (:func:`success` entries): the share of their episodes that meet the
    experts' bars and, where the env measures one, their mean final distance to their ball."""
    distances = [q.get("final_distance") for q in agents]
    return {
        "success_rate": mean_or_none([episode_share(q) for q in agents]),
        "final_distance": mean_or_none(distances),
    }


def do_nothing(problem) -> list[dict]:
    """The reference rows of a policy that does nothing, no training needed: zero actions, and
    the middle of the action box where it is not centred, scored like the random reference
    (its episodes and key), acting every true intention alike."""
    import jax
    import jax.numpy as jnp

    import envs
    from emgail_jax.method.metrics import reward_difference
    from emgail_jax.method.rollout import episode_returns, still_policy

    env = problem.env
    zero = lambda obs, key: jnp.zeros((*obs.shape[:-1], env.action_size), obs.dtype)
    policies = {"zero": zero}
    if np.any(np.asarray(env.action_low) + np.asarray(env.action_high) != 0):
        policies["mid-range"] = still_policy(env)
    k_true, rows = problem.true_intentions, []
    for actions, policy in policies.items():
        returns = jax.jit(
            lambda key, policy=policy: episode_returns(
                envs.EpisodeWrapper(env), policy, key, 1, problem.random_episodes
            )
        )(jax.random.PRNGKey(problem.random_seed))
        matched = np.asarray(returns[0, :k_true], np.float64)[None]  # [1, K true]
        per_intention = None
        if problem.demos.expert_returns is not None:
            expert = np.asarray(problem.demos.expert_returns, np.float64)
            random = np.asarray(problem.random_returns, np.float64)
            per_intention = reward_difference(matched, expert, random)
        summary = erd_summary(per_intention)
        rows.append(
            {
                "actions": actions,
                "returns": matched[0],
                "erd": summary["erd"],
                "erd_per_intention": summary["erd_per_intention"],
            }
        )
    return rows


def fresh_trainer(run, budget: Budget, reward_fn=None, absorbing_reward=None):
    from emgail_jax.method.rl import make_rl_train, true_reward

    # A fresh agent learns no discriminator: its rollouts need no AIRL successors.
    config = run.config.with_values(
        gamma=budget.gamma,
        gae_lambda=budget.gae_lambda,
        value_target_scaling=budget.value_target_scaling,
        discriminator_form="gail",
    ).method
    env = run.problem.env
    episodes = config.rollout.num_envs
    return make_rl_train(config, env, reward_fn or true_reward, episodes, absorbing_reward)


def learned_reward_trainer(run, budget: Budget, learned, absorbing_function=None):
    """The fresh agents' trainer on ``learned(parameters, obs, action, intention)`` (the reward
    data each row trains on is its ``parameters``), a termination paid
    ``absorbing_function(parameters, intention)`` per step left (default the run's absorbing
    reward, None without absorbing states)."""
    reward_fn = lambda obs, action, true, intention, parameters: learned(
        parameters, obs, action, intention
    )
    absorbing = absorbing_function or run.absorbing_reward_function()
    absorbing_fn = None
    if absorbing is not None:
        absorbing_fn = lambda intention, parameters: absorbing(parameters, intention)
    return fresh_trainer(run, budget, reward_fn, absorbing_fn)


def fresh_keys(run, seeds: list[int], rl_seed: int = 0) -> np.ndarray:
    """``[S, K]`` keys of the fresh agents: each run seed's from that seed, one per learned
    intention, drawn for ``rl_seed`` (:func:`drawn`)."""
    import jax

    seed_key = lambda s: drawn(jax.random.PRNGKey(run.spec.first_seed + s + 1000), rl_seed)
    return np.stack([jax.random.split(seed_key(s), run.num_intentions) for s in seeds])


def scored(returns, matching, run, seed: int | None) -> dict:
    """ERD per iteration and final (mean of the last 10) of ``returns [iterations, K, K env]``
    with ``matching [K true]`` held fixed; a true intention matched to a learned one the run
    does not keep scores 1, as random actions."""
    from emgail_jax.method.metrics import reward_difference

    problem = run.problem
    # In float64: a baseline read back from its cache scores exactly as when computed.
    expert = np.asarray(problem.demos.expert_returns, np.float64)
    k_true = len(matching)
    matched = np.asarray(returns, np.float64)[:, matching, np.arange(k_true)]  # [iter, K true]
    result = {
        "returns": matched[-FINAL_WINDOW:].mean(0),  # [K true] of the matched policies
        "learned_returns": returns[-FINAL_WINDOW:].mean(0),  # [K learned, K env] unmatched
        "matching": np.asarray(matching),
    }
    if problem.demos.expert_returns is None:
        return {**result, **erd_summary(None)}
    random = np.asarray(problem.random_returns, np.float64)
    per_intention = reward_difference(matched, expert, random)
    in_use = None if seed is None else run.intentions_in_use(seed)
    if in_use is not None:
        per_intention = np.where(np.asarray(in_use)[matching], per_intention, 1.0)
    return {**result, **erd_summary(per_intention)}


def erd_summary(per_intention: np.ndarray | None) -> dict:
    """ERD's entries of a check from ``per_intention [iterations, K true]`` (None where the
    experts' returns are unknown): the curve and the final value, the mean of the last 10."""
    if per_intention is None:
        return dict.fromkeys(("erd", "erd_per_intention", "erd_curve", "erd_curve_per_intention"))
    curve = per_intention.mean(-1)
    return {
        "erd": float(curve[-FINAL_WINDOW:].mean()),
        "erd_per_intention": per_intention[-FINAL_WINDOW:].mean(0),
        "erd_curve": curve,
        "erd_curve_per_intention": per_intention,
    }


def run_matching(run, seed: int, iteration: int) -> np.ndarray:
    """``[K true]`` the learned intention the run matched each true intention to when it last
    evaluated its policies at or before ``iteration`` (the first evaluation after it if none
    before); the identity when the run never evaluated (no expert returns)."""
    matchings = np.asarray(run.history["eval/matching"][seed])  # [iterations, K true]
    evaluated = np.flatnonzero(matchings[:, 0] >= 0) + 1  # iteration numbers
    if not len(evaluated):
        return np.arange(run.problem.true_intentions)
    before = evaluated[evaluated <= iteration]
    chosen = before[-1] if len(before) else evaluated[0]
    return matchings[chosen - 1]


def demonstrations_reward(run, seed: int, parameters=None, reward_function=None) -> np.ndarray:
    """``[K]``: learned intention i's reward per step on the demonstration pairs, weighted by
    the run's responsibilities gamma_i (every pair alike without a posterior); NaN for an
    intention the run assigned no demonstration to. ``parameters`` replace the seed's reward
    parameters (a consolidated reward), read by ``reward_function`` (default the run's)."""
    pairs = run.demonstration_pairs
    k = run.num_intentions
    if run.algorithm.learns_posterior:
        gamma = np.asarray(run.responsibilities(seed).gamma)  # [N, K]
    else:
        gamma = np.ones((pairs.observations.shape[0], k))
    parameters = parameters or run.reward_parameters(seed)
    learned = reward_function or run.reward_function()
    reward = lambda obs, action, i: learned(parameters, obs, action, i)
    per_pair = np.stack(
        [np.asarray(reward(pairs.observations, pairs.actions, i)) for i in range(k)], -1
    )  # [N, K]
    weight = gamma.sum(0)
    total = (gamma * per_pair).sum(0)
    return np.divide(total, weight, out=np.full(k, np.nan), where=weight > 0)


def reoptimize(
    run,
    seeds: list[int],
    budget: Budget,
    *,
    progress: bool = True,
    parameters=None,
    reward_function=None,
    absorbing_function=None,
    rl_seed: int = 0,
    partial: PartialTraining | None = None,
) -> dict:
    """Trains one policy per learned intention on each of ``seeds``' frozen rewards of ``run``
    (all seeds vmapped in one program) and scores them; ``rl_seed`` picks another draw of the
    fresh policies' keys (0: the default's); ``parameters`` (one per seed) replace
    the run's :meth:`~emgail_jax.host.saved_run.SavedRun.reward_parameters`, read by
    ``reward_function`` and ``absorbing_function`` (default the run's
    :meth:`~emgail_jax.host.saved_run.SavedRun.reward_function` and
    :meth:`~emgail_jax.host.saved_run.SavedRun.absorbing_reward_function`); with ``partial``
    the training goes on from its save and is saved as it goes."""
    from emgail_jax.host.saved_run import stacked

    learned = reward_function or run.reward_function()
    trainer = learned_reward_trainer(run, budget, learned, absorbing_function)
    per_seed_parameters = parameters or [run.reward_parameters(seed) for seed in seeds]
    parameters = stacked(per_seed_parameters)
    keys = fresh_keys(run, seeds, rl_seed)
    fresh = train_fresh(
        trainer,
        keys,
        parameters,
        budget.iterations,
        label="re-optimising",
        progress=progress,
        partial=partial,
    )
    iteration = run.snapshot or run.iteration
    score = functools.partial(_seed_scores, run, fresh=fresh, trainer=trainer, learned=learned)
    per_seed = [
        score(seed, row, parameters=per_seed_parameters[row]) for row, seed in enumerate(seeds)
    ]
    return {
        "iteration": iteration,
        "snapshot": run.snapshot,
        "budget": dataclasses.asdict(budget),
        "absorbing_state": (absorbing_function or run.absorbing_reward_function()) is not None,
        "eval_episodes": run.config.method.rollout.num_envs,
        "expert_returns": run.problem.demos.expert_returns,
        "random_returns": run.problem.random_returns,
        "seeds": [run.seed_number(seed) for seed in seeds],
        "rl_seed": rl_seed,
        **over_seeds(per_seed),
        "compile_time_s": fresh.compile_s,
        "train_time_s": fresh.train_s,
    }


def _seed_scores(run, seed: int, row: int, *, fresh: FreshAgents, trainer, learned, parameters):
    """Run seed ``seed``'s fresh agents (row ``row`` of ``fresh``) scored: ERD under the run's
    matching, the experts' bars, and the learned reward they and the demonstrations earn."""
    import jax

    matching = run_matching(run, seed, run.snapshot or run.iteration)
    scores = scored(fresh.returns[row], matching, run, seed)
    result = {"run_seed": run.seed_number(seed), **scores}
    states = jax.tree.map(lambda x: x[row], fresh.states)
    result["success"] = success(run.problem.env, trainer, states, matching)
    result["learned_reward_per_step"] = {  # learned intentions' order
        "fresh_policies": fresh.earned[row, -FINAL_WINDOW:].mean(0),
        "demonstrations": demonstrations_reward(run, seed, parameters, learned),
    }
    return result


def over_seeds(per_seed: list[dict]) -> dict:
    """What a check reports of its seeds' results: each seed's ERD, their mean and spread, and
    which of the experts' bars each seed's agents meet."""
    erds = [r["erd"] for r in per_seed]
    return {
        "erd": erds,
        "erd_mean": None if None in erds else float(np.mean(erds)),
        "erd_std": None if None in erds else float(np.std(erds)),
        "meets_bar": [[q["meets_bar"] for q in r["success"]] for r in per_seed],
        "per_seed": per_seed,
    }


# What every seed of one draw of a check shares (:func:`reoptimize`'s result).
DRAW_SHARED = (
    "iteration",
    "snapshot",
    "budget",
    "absorbing_state",
    "eval_episodes",
    "expert_returns",
    "random_returns",
    "rl_seed",
)


def joined_seeds(parts: list[dict]) -> dict:
    """One draw of a check over the run seeds of ``parts`` (:func:`reoptimize` results of the
    same draw on other seeds, in the order given), as if their seeds had trained together:
    each seed's agents depend on its own keys alone (:func:`fresh_keys`)."""
    for name in DRAW_SHARED:
        if any(part[name] != parts[0][name] for part in parts):
            raise ValueError(f"the checks joined differ in {name}")
    per_seed = [row for part in parts for row in part["per_seed"]]
    return {
        **{name: parts[0][name] for name in DRAW_SHARED},
        "seeds": [row["run_seed"] for row in per_seed],
        **over_seeds(per_seed),
        "compile_time_s": sum(part["compile_time_s"] for part in parts),
        "train_time_s": sum(part["train_time_s"] for part in parts),
    }


def joint_policies(run, seeds: list[int], iteration: int) -> dict:
    """The run's own jointly trained policies, unchanged, in ``run.problem``'s env (a variant):
    ``num_envs`` deterministic episodes per learned intention, scored like the fresh policies
    (the run's matching at ``iteration``). What a reward re-optimised in the variant is
    compared with: the policy a user would otherwise deploy there."""
    import jax

    count = run.config.method.rollout.num_envs
    key = jax.random.PRNGKey(run.spec.first_seed + 3000)
    per_seed = []
    for seed in seeds:
        returns, _, _ = run.episodes(seed, count, key)
        mean = np.asarray(returns, np.float64).mean(1)[None]  # [1, K learned, K env]
        scores = scored(mean, run_matching(run, seed, iteration), run, seed)
        per_seed.append(
            {"run_seed": run.seed_number(seed), **{n: scores[n] for n in ("erd", "returns")}}
        )
    erds = [r["erd"] for r in per_seed]
    return {
        "erd": erds,
        "erd_mean": None if None in erds else float(np.mean(erds)),
        "per_seed": per_seed,
    }


def variant_problem(run, settings: list[str]):
    """The run's problem in a variant of its env (``settings``: ``KEY=FACTOR``); ERD's
    references then follow the variant (random actions in it; the expert: see
    :func:`with_expert_returns`)."""
    import envs
    from emgail_jax.host.run_spec import RunError

    problem = run.problem
    options = {**run.spec.env_options, "dynamics": settings}
    try:
        env = envs.make(run.spec.env, intentions=problem.env.num_intentions, **options)
    except envs.EnvError as error:
        raise RunError(f"--env-set: {error}") from None
    return dataclasses.replace(problem, env=env)


def with_expert_returns(problem, returns):
    """``problem`` with ``returns [K true]`` as ERD's expert reference (0)."""
    demos = dataclasses.replace(problem.demos, expert_returns=np.asarray(returns, np.float64))
    return dataclasses.replace(problem, demos=demos)
