"""The reward check: is a learned reward a reward? (paper §5.2, eq. 28)

Fresh TRPO policies trained from scratch on a run's frozen learned reward, one per learned
intention and run seed in one vmapped program, scored under the env's true rewards: ERD with
the run's own matching of intentions and the experts' success bars. Beside them the
true-reward baseline, the same TRPO and budget on the true rewards; several RL draws kept by
the learned reward alone; the rewards a check may read instead of the run's own (a refit,
the mean over snapshots); the references of a variant of the env's dynamics.
``python -m emgail_jax.reoptimize`` (:mod:`emgail_jax.reoptimize`) is its command line.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import time

import numpy as np

from emgail_jax.host.check_progress import PartialTraining
from emgail_jax.host.schedule import FINAL_WINDOW, evaluation_plan

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


# What envs whose experts needed more than an IRL run's budget get in place of the run's
# (emgail_jax.experts.SPECS): the swimmer's gait pays off over many steps, and TRPO on its
# true reward finds the fast gait on most draws only when GAE's lambda carries the credit that
# far (docs/rewards-that-reoptimise.md, experiment 73).
BUDGETS: dict[str, dict] = {"swimmer": {"iterations": 1500, "gamma": 0.9999, "gae_lambda": 0.995}}


# The fields of a run's config that shape TRPO on a given reward (the baseline's cache key).
RL_FIELDS = (
    "num_envs",
    "rollout_length",
    "hidden",
    "init_log_std",
    "obs_clip",
    "gamma",
    "gae_lambda",
    "trpo",
    "value_learning_rate",
    "value_epochs",
    "value_minibatches",
    "value_target_scaling",
)


SUCCESS_EPISODES = 10  # the experts' bars are defined over 10 deterministic episodes


def drawn(key, rl_seed: int):
    """``key`` for RL seed ``rl_seed``: folded with it, RL seed 0 the key itself (the draw
    every check made before there were RL seeds)."""
    import jax

    return jax.random.fold_in(key, rl_seed) if rl_seed else key


def env_budget(
    env: str, iterations: int, gamma: float, gae_lambda: float, value_target_scaling: bool = False
) -> Budget:
    """A run's own TRPO iterations, gamma, lambda and value target scaling, with the env's
    :data:`BUDGETS` in place."""
    own = Budget(iterations, gamma, gae_lambda, value_target_scaling)
    return dataclasses.replace(own, **BUDGETS.get(env, {}))


def default_budget(run) -> Budget:
    b_step = run.config.method.b_step
    return env_budget(
        run.spec.env,
        run.config.schedule.iterations,
        b_step.gamma,
        b_step.gae_lambda,
        b_step.value_target_scaling,
    )


def default_cache() -> str:
    root = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(root, "emgail-jax", "true-reward-baselines")


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
    label: str,
    progress: bool,
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


def _fresh_trainer(run, budget: Budget, reward_fn=None, absorbing_reward=None):
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
    return _fresh_trainer(run, budget, reward_fn, absorbing_fn)


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
    import jax

    from emgail_jax.host.saved_run import stacked

    learned = reward_function or run.reward_function()
    trainer = learned_reward_trainer(run, budget, learned, absorbing_function)
    per_seed_parameters = parameters or [run.reward_parameters(seed) for seed in seeds]
    parameters = stacked(per_seed_parameters)
    keys = fresh_keys(run, seeds, rl_seed)
    label = "re-optimising"
    fresh = train_fresh(trainer, keys, parameters, budget.iterations, label, progress, partial)
    iteration = run.snapshot or run.iteration
    per_seed = []
    for row, seed in enumerate(seeds):
        matching = run_matching(run, seed, iteration)
        scores = scored(fresh.returns[row], matching, run, seed)
        result = {"run_seed": run.seed_number(seed), **scores}
        states = jax.tree.map(lambda x, r=row: x[r], fresh.states)
        result["success"] = success(run.problem.env, trainer, states, matching)
        result["learned_reward_per_step"] = {  # learned intentions' order
            "fresh_policies": fresh.earned[row, -FINAL_WINDOW:].mean(0),
            "demonstrations": demonstrations_reward(run, seed, per_seed_parameters[row], learned),
        }
        per_seed.append(result)
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


def picked(draws: list[dict], pick) -> dict:
    """One :func:`scored` result (with its ``success``) whose true intention i is the agent of
    draw ``pick[i]`` of ``draws``, scores of agents trained alike under one matching."""
    pick = [int(d) for d in pick]
    # float64: a draw read back from its file has null where its agents were not scored.
    column = lambda name: [
        np.asarray(draws[d][name], np.float64)[..., i] for i, d in enumerate(pick)
    ]
    result = {"matching": draws[0]["matching"], "returns": np.array(column("returns"))}
    known = draws[0]["erd"] is not None  # as scored: one draw picks itself alike
    result.update(erd_summary(np.stack(column("erd_curve_per_intention"), -1) if known else None))
    if "success" in draws[0]:
        result["success"] = [draws[d]["success"][i] for i, d in enumerate(pick)]
    return {**result, "draw": pick}


DRAW_RULES = ("most", "nearest")


def kept_draws(rows: list[dict], rule: str = "most") -> np.ndarray:
    """Per learned intention, the draw ``rule`` keeps among one seed's ``rows`` (one per draw),
    by the learned reward per step each agent earned over the last iterations: ``most``, the
    agent that earned the most; ``nearest``, the one nearest what the demonstrations earn (one
    that out-earns them far may have found what the reward overpays off their support)."""
    earned = np.array([r["learned_reward_per_step"]["fresh_policies"] for r in rows], float)
    if rule == "most":
        return earned.argmax(0)
    if rule == "nearest":
        demonstrations = np.asarray(rows[0]["learned_reward_per_step"]["demonstrations"], float)
        return np.abs(earned - demonstrations).argmin(0)
    raise ValueError(f"no draw rule {rule!r}: one of {', '.join(DRAW_RULES)}")


def chosen_by_learned_reward(draws: list[dict], rule: str = "most") -> dict:
    """Several draws of fresh agents on the same rewards (:func:`reoptimize` results of the same
    seeds, one per RL seed) as one check: per run seed and learned intention, the agent
    :func:`kept_draws` keeps by ``rule`` (a fall paid the absorbing state's reward for every
    step left, :func:`~emgail_jax.method.rl.reward_per_step`), a choice a user without the true
    reward can make. Each seed's ``draw`` says which draw acts each true intention."""
    per_seed = []
    for rows in zip(*(d["per_seed"] for d in draws), strict=True):
        earned = np.array([r["learned_reward_per_step"]["fresh_policies"] for r in rows])
        best = kept_draws(rows, rule)  # [K learned]
        chosen = picked(rows, best[np.asarray(rows[0]["matching"])])
        chosen["learned_reward_per_step"] = {
            "fresh_policies": earned[best, np.arange(len(best))],
            "demonstrations": rows[0]["learned_reward_per_step"]["demonstrations"],
        }
        per_seed.append(
            {"run_seed": rows[0]["run_seed"], **chosen, "draws_erd": [r["erd"] for r in rows]}
        )
    shared = (*DRAW_SHARED[:-1], "seeds")
    return {
        **{name: draws[0][name] for name in shared},
        "rl_seeds": [d["rl_seed"] for d in draws],
        "draw_rule": rule,
        **over_seeds(per_seed),
        "draws_erd_mean": [d["erd_mean"] for d in draws],
        "draws": draws,
        "compile_time_s": sum(d["compile_time_s"] for d in draws),
        "train_time_s": sum(d["train_time_s"] for d in draws),
    }


def best_baseline(baselines: list[dict]) -> dict:
    """Several true-reward baselines' draws (:func:`true_reward_baseline`) as one: per true
    intention the agent with the highest true return, each agent kept by the reward it trained
    on as :func:`chosen_by_learned_reward` keeps the learned reward's. Each draw's ERD per
    intention is kept beside it: an agent that outruns its expert has the most true return and
    a worse ERD than a draw nearer the expert, which a reader may prefer as the floor."""
    best = np.array([b["returns"] for b in baselines]).argmax(0)  # [K true]
    result = picked(baselines, best)
    return {
        **result,
        "meets_bar": [q["meets_bar"] for q in result["success"]],
        "draws_erd": [b["erd"] for b in baselines],
        "draws_erd_per_intention": [b["erd_per_intention"] for b in baselines],
        "cache": [b["cache"] for b in baselines],
    }


def baseline_key(run, budget: Budget, rl_seed: int = 0) -> str:
    """What the true-reward baseline depends on: the env, its options and K, the budget, the
    TRPO settings and the RL seed, as a file name (another RL seed's does not begin with
    :func:`baseline_prefix`: the sweep's checks read RL seed 0's)."""
    # Lambda and scaling enter as the TRPO settings they override, so a budget that keeps the
    # run's names the baseline it named before they were part of the budget; scaling off is
    # left out of the key as it was before the setting existed.
    config = run.config.with_values(
        gae_lambda=budget.gae_lambda, value_target_scaling=budget.value_target_scaling
    ).to_dict()
    if not config["value_target_scaling"]:
        del config["value_target_scaling"]
    env = run.problem.env
    described = {
        "env": env.name,
        "options": env.options(),
        "intentions": env.num_intentions,
        "budget": {"iterations": budget.iterations, "gamma": budget.gamma},
        "config": {name: config[name] for name in RL_FIELDS if name in config and name != "gamma"},
    }
    text = json.dumps(described, sort_keys=True, default=str)
    digest = hashlib.sha256(text.encode()).hexdigest()[:12]
    prefix = baseline_prefix(env.name, env.num_intentions, budget.iterations)
    return (f"rl{rl_seed}-" if rl_seed else "") + f"{prefix}g{budget.gamma}-{digest}"


def baseline_prefix(env_name: str, intentions: int, iterations: int) -> str:
    """How the :func:`baseline_key` of every baseline of an env, K and budget iterations
    begins, whatever its gamma and settings (the sweep looks for one it need not compute)."""
    return f"{env_name}-k{intentions}-{iterations}it-"


def true_reward_baseline(
    run, budget: Budget, cache: str | None, progress: bool = True, rl_seed: int = 0
) -> dict:
    """TRPO on the env's true rewards with the fresh policies' settings and budget, policy i on
    intention i (one RL seed, ``rl_seed``'s draw), scored like them; read from ``cache`` when
    computed before."""
    import jax

    from emgail_jax.host import records

    key = baseline_key(run, budget, rl_seed)
    path = None if cache is None else os.path.join(cache, key + ".json")
    k_true = run.problem.true_intentions
    identity = np.arange(k_true)
    if path is not None and os.path.exists(path):
        with open(path) as f:
            stored = json.load(f)
        returns = np.asarray(stored["returns"], np.float64)  # null where not scored
        found = stored["success"]
    else:
        trainer = _fresh_trainer(run, budget)
        keys = jax.random.split(drawn(jax.random.PRNGKey(1000), rl_seed), run.num_intentions)[None]
        # Its key names everything it depends on; saved part-way only where it is cached.
        partial = None if path is None else PartialTraining(path + ".partial.npz", {"key": key})
        label = "true reward"
        fresh = train_fresh(trainer, keys, None, budget.iterations, label, progress, partial)
        returns = fresh.returns[0]
        states = jax.tree.map(lambda x: x[0], fresh.states)
        found = records.to_json_value(success(run.problem.env, trainer, states, identity))
        if path is not None:
            os.makedirs(cache, exist_ok=True)
            records.write_json(path, {"returns": returns, "success": found})
            partial.remove()
    result = scored(returns, identity, run, None)
    return {**result, "success": found, "meets_bar": [q["meets_bar"] for q in found], "cache": path}


def variant_reference(run, budget: Budget, cache: str | None, draws: int, progress: bool) -> dict:
    """ERD's 0 in a variant: per true intention the highest true return of ``draws`` true-reward
    baselines (RL seeds 0 .. draws - 1, each cached), and what each draw scored against the
    original experts."""
    found = [true_reward_baseline(run, budget, cache, progress, r) for r in range(draws)]
    best = best_baseline(found)
    return {
        "returns": best["returns"],
        "draw": best["draw"],
        "draws_returns": np.array([b["returns"] for b in found], np.float64),  # [draws, K true]
        "original_experts_erd": best["draws_erd"],
        "meets_bar": best["meets_bar"],
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


def ensemble_parameters(run, seeds: list[int], size: int) -> tuple[list, list[int]]:
    """Each seed's reward parameters of the last ``size`` snapshots up to the networks ``run``
    holds, stacked ``[size, ...]``, and those snapshots' iterations."""
    from emgail_jax.host import checkpoints
    from emgail_jax.host.saved_run import stacked

    last = run.snapshot or run.iteration
    kept = [i for i in checkpoints.snapshot_iterations(run.run_dir) if i <= last]
    if len(kept) < size:
        raise checkpoints.CheckpointError(
            f"--ensemble {size} needs {size} snapshots up to iteration {last}; "
            f"'{run.run_dir}' kept {len(kept)} (run --snapshot-every)"
        )
    iterations = kept[-size:]
    runs = [
        dataclasses.replace(run, state=checkpoints.restore_snapshot(run.run_dir, i, run.state))
        for i in iterations
    ]
    return [stacked([r.reward_parameters(seed) for r in runs]) for seed in seeds], iterations


def ensemble_reward(reward_function):
    """``reward_function(parameters, *inputs)`` (a reward, or the absorbing state's)
    averaged over ``parameters`` stacked ``[N, ...]`` (:func:`ensemble_parameters`)."""
    import jax

    def mean_reward(parameters, *inputs):
        every = jax.vmap(lambda one: reward_function(one, *inputs))(parameters)
        return every.mean(0)

    return mean_reward


def consolidated(
    run, seeds: list[int], refit, name: str, budget: Budget | None = None, progress: bool = True
):
    """Every seed's consolidated reward parameters and the refit's losses; each seed's refit is
    read from the run's saved reward ``name`` when it was made before, and saved there when
    not (:mod:`~emgail_jax.host.consolidation`). A refit against fresh agents trains them with
    ``budget`` (default the env's) on the run's reward form, which its saved description
    records."""
    import jax

    from emgail_jax.host import consolidation
    from emgail_jax.host.run_spec import RunError

    description = consolidation.refit_description(
        refit, run.snapshot, run.snapshot or run.iteration
    )
    budget = budget or default_budget(run)
    if refit.agent_rounds:
        agents = {"reward_form": run.algorithm.reward_form, "budget": dataclasses.asdict(budget)}
        description["agents"] = agents
    saved_before = name in consolidation.saved_refits(run.run_dir)
    if saved_before:
        consolidation.check_refitted_from(run, name)
    if saved_before and consolidation.read_description(run.run_dir, name) != description:
        raise RunError(
            f"the saved reward '{name}' of '{run.run_dir}' was refitted otherwise: "
            "delete its directory under rewards/ to refit it"
        )
    parameters, metrics = [], []
    for seed in seeds:
        number = run.seed_number(seed)
        found = consolidation.saved_parameters(run, name, seed)
        if found is not None:
            losses = consolidation.read_losses(run.run_dir, name, number)
            if progress:
                print(f"seed {number}: the refitted reward '{name}' saved before, reused")
        else:
            started = time.monotonic()
            key = jax.random.PRNGKey(number + 2000)
            samples = consolidation.snapshot_policy_samples(run, seed, key)
            found, losses = consolidation.consolidated_parameters(
                run, seed, refit, key, samples=samples
            )
            if refit.agent_rounds:
                found, losses = refitted_against_agents(
                    run, seed, refit, key, budget, found, samples, progress
                )
            # What this seed's refit cost, compiles included: the sweep's estimate reads it.
            losses = {**losses, "seconds": time.monotonic() - started}
            consolidation.save_refitted(
                run.run_dir, name, number, found["discriminator"], description, losses
            )
        parameters.append(found)
        metrics.append({"run_seed": number, **dataclasses.asdict(refit), **losses})
    return parameters, metrics


# The fresh agents a refit is fitted against are RL draws from this one on (round r's is
# AGENT_DRAWS + r), never one that ``--rl-seed`` checks the refit with.
AGENT_DRAWS = 1000


def refitted_against_agents(
    run, seed: int, refit, key, budget: Budget, first, samples, progress: bool
):
    """``(reward parameters, losses)``: ``refit.agent_rounds`` rounds, each training fresh
    agents on the last refit ``first`` onwards with ``budget``, one training rollout of them
    (with exploration) added to every earlier round's, and the refit made again from the same
    start against those rollouts too (and the snapshots' ``samples`` the first refit saw,
    not collected again); the losses are the last refit's, with each round's
    agents' ERD, true returns and learned reward per step (``agent_rounds``)."""
    import jax

    from emgail_jax.host import consolidation
    from emgail_jax.host.saved_run import stacked

    trainer = learned_reward_trainer(run, budget, run.reward_function(refit.state_only))
    acting = lambda state: trainer.policy(state, deterministic=False)
    matching = run_matching(run, seed, run.snapshot or run.iteration)
    found, rollouts, rounds = first, [], []
    for number in range(1, refit.agent_rounds + 1):
        keys = fresh_keys(run, [seed], AGENT_DRAWS + number)
        label = f"refit's agents, round {number}"
        fresh = train_fresh(trainer, keys, stacked([found]), budget.iterations, label, progress)
        states = jax.tree.map(lambda x: x[0], fresh.states)
        policy = consolidation.agents_policy(acting, states)
        rollout_key = jax.random.fold_in(key, AGENT_DRAWS + number)
        rollouts.append(consolidation.fixed_policy_samples(run, policy, rollout_key))
        agents = tuple(np.concatenate(parts, 1) for parts in zip(*rollouts, strict=True))
        scores = scored(fresh.returns[0], matching, run, seed)
        rounds.append(
            {
                "erd": scores["erd"],
                "returns": scores["returns"],
                "learned_reward_per_step": fresh.earned[0, -FINAL_WINDOW:].mean(0),
            }
        )
        found, losses = consolidation.consolidated_parameters(
            run, seed, refit, key, agents, samples
        )
    return found, {**losses, "agent_rounds": rounds}
