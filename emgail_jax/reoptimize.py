"""Is the learned reward a reward? Train fresh policies on it and measure their ERD (paper §5.2).

    python -m emgail_jax.reoptimize RUN_DIR [--seed S] [--rl-seed R] [--draws N] [--snapshot ITER]
        [--ensemble N | --across-seeds | --consolidate STEPS [--consolidate-*]]
        [--reward-form FORM] [--iterations N] [--gamma G] [--no-baseline]
        [--cache DIR] [--env-set KEY=FACTOR ...] [--out PATH]

For every run seed (or ``--seed S`` alone) and every learned intention, a new policy is trained
from scratch with TRPO on the frozen pseudo-reward R_i(s, a) of that seed (the run's final
networks, or those of the snapshot of ``--snapshot ITER``; with ``--ensemble N`` the mean of
R_i over the last N snapshots up to them; with ``--across-seeds`` the mean of every run seed's
R_i, the seeds' intentions aligned by the demonstrations they hold; with ``--consolidate`` each
seed's discriminator refitted against every snapshot's policy, saved as ``RUN_DIR/rewards/NAME``
for ``load_reward(RUN_DIR, refit=NAME)`` and reused by any later check of it), never
seeing the true reward; the seeds' and intentions' policies are vmapped in one program
(``--rl-seed R``: another draw of their initialisation and samples, to tell a reward that fails
from a search that did; ``--draws N``: N draws, keeping per intention the agent that earns the
most learned reward, as a user without the true reward would; each finished draw is kept
beside the check's file until it is written, so a check stopped part-way goes on from there).
Their deterministic episodes
(as many per iteration as training evaluates, ``num_envs``) are scored under the true
rewards; the ERD matches each true intention to the learned one the run itself matched it to
(its jointly trained policies' matching at that iteration), one matching for every number
reported. Each env's success measure (the experts' bars: velocity, upright, pitch turn, ball
reached) is reported beside it, over the experts' 10 deterministic episodes.

Every algorithm's run is checked on the reward its own policies were trained on
(:meth:`~emgail_jax.host.saved_run.SavedRun.reward_function`): EM-GAIL's R_i = -log(1 - D(s, a,
i)); Info/IntentionGAIL's -log(1 - D(s, a)) + lambda log P(i | s, a), its final posterior
included (eq. 23); GAIL's one -log(1 - D(s, a)) for the mixed demonstrations, the same for every
intention, so that its K fresh policies are K agents of that one reward, true intention i scored
by the one the run matched to i. Every fresh policy has the same budget whatever the algorithm
(iterations, gamma, ``num_envs`` episodes of ``rollout_length`` steps per iteration: one row of
the ``[K, num_envs]`` envs, although GAIL's single policy trained on all K rows), so that the
algorithms' checks compare the rewards alone. A run trained with AIRL's discriminator
(``--set discriminator_form=airl``) is checked on its state-only reward g_i(s), the one AIRL
claims transfers, not on f - log pi (its policies' training reward, which reads the policy).
A run trained with absorbing states (``--set absorbing_state=true``) is checked the same way:
a fresh policy's termination is worth the learned reward of the absorbing state for every step
left, as in the run's own B-step; the true-reward baseline has no absorbing state. So is a
reward refitted with absorbing states (``--consolidate-absorbing``), whatever the run trained.

Beside the learned reward, the **true-reward baseline**: the same TRPO, settings and budget on
the env's true rewards, the floor any learned reward is judged against (computed once per env,
K and budget, then read from ``--cache``; no algorithm enters its key, so one baseline serves
every algorithm's runs). The budget is the run's iterations and gamma unless :data:`BUDGETS` or
the flags say otherwise.

Also the learned reward per step that the fresh policies earn and that the demonstrations the
run assigned to each intention earn: fresh policies that out-earn the demonstrations yet score
far from the experts have optimised a reward that pays off the demonstrations' support. Writes
``RUN_DIR/reoptimize.json`` (``reoptimize-snapshot-ITER.json`` for a snapshot).

``--env-set`` trains and scores the fresh policies in a variant of the env (changed masses,
gravity, friction or viscosity: docs/environments.md), the test of a reward in dynamics its
demonstrations never saw. ERD there is normalised by the variant's own references: the
true-reward baseline trained in the variant with the same budget (0: per intention the best
of ``--reference-draws`` RL draws, since one draw of TRPO can miss a bar the experts meet) and
random actions in the variant (1). Beside the fresh agents, the run's own jointly trained
policies deployed unchanged in the variant, scored the same way: a reward is worth more than a
policy where its fresh agents beat them.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import hashlib
import json
import os
import shutil
import sys
import time

import numpy as np

from emgail_jax.host import jax_setup
from emgail_jax.host.schedule import FINAL_WINDOW  # the iterations averaged, as training's


@dataclasses.dataclass(frozen=True)
class Budget:
    """What the fresh policies get: TRPO iterations and the discount."""

    iterations: int
    gamma: float


# Envs whose experts needed more than an IRL run's budget (emgail_jax.experts.SPECS): the
# swimmer's gait pays off over many steps.
BUDGETS: dict[str, Budget] = {"swimmer": Budget(iterations=1500, gamma=0.9999)}

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
)
SUCCESS_EPISODES = 10  # the experts' bars are defined over 10 deterministic episodes


def drawn(key, rl_seed: int):
    """``key`` for RL seed ``rl_seed``: folded with it, RL seed 0 the key itself (the draw
    every check made before there were RL seeds)."""
    import jax

    return jax.random.fold_in(key, rl_seed) if rl_seed else key


def default_budget(run) -> Budget:
    return BUDGETS.get(
        run.spec.env, Budget(run.config.schedule.iterations, run.config.method.b_step.gamma)
    )


def budget_of(args: argparse.Namespace, run) -> Budget:
    """The env's budget with ``--iterations`` and ``--gamma`` in place of its own if given."""
    budget = default_budget(run)
    return Budget(args.iterations or budget.iterations, args.gamma or budget.gamma)


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


def train_fresh(trainer, keys, reward_data, iterations: int, label: str, progress: bool):
    """Trains ``trainer``'s policies from ``keys [S, K]`` (policy k of row s on intention k of
    the reward ``reward_data[s]``) for ``iterations``, in chunks of 10."""
    import jax
    import jax.numpy as jnp

    from emgail_jax.host.progress import ProgressBar
    from emgail_jax.host.seed_runner import chunk_length, chunks, run_chunks
    from emgail_jax.method.rl import seeds_chunk

    k = keys.shape[1]
    states = jax.jit(jax.vmap(jax.vmap(trainer.init)))(keys)
    plan = chunks(0, iterations, chunk_length(iterations, 10))
    inputs = lambda first, length: np.zeros(length, bool)
    start = time.perf_counter()
    chunk = seeds_chunk(trainer, jnp.arange(k))
    step = chunk.lower(states, inputs(*plan[0]), reward_data).compile()
    compile_s = time.perf_counter() - start
    returns, earned = [], []
    bar = ProgressBar(label, iterations, {"return": "-"}, enabled=progress)

    def after_chunk(first, length, states, metrics) -> bool:
        returns.append(np.asarray(metrics["eval/returns"]))  # [L, S, K, K env]
        earned.append(np.asarray(metrics["train/reward"]))  # [L, S, K]
        own = np.diagonal(returns[-1][-1], axis1=-2, axis2=-1).mean(0)
        bar.update(length, **{"return": " ".join(f"{r:.1f}" for r in own)})
        return True

    start = time.perf_counter()
    states = run_chunks(lambda s, x: step(s, x, reward_data), states, plan, inputs, after_chunk)
    bar.close()
    train_s = time.perf_counter() - start
    to_seed_major = lambda parts: np.swapaxes(np.concatenate(parts), 0, 1)
    return FreshAgents(states, to_seed_major(returns), to_seed_major(earned), compile_s, train_s)


def success(env, trainer, states, matching) -> list[dict]:
    """The experts' quality and bars (:func:`emgail_jax.experts.quality`) of the fresh policies
    ``states [K]``, true intention i acted by learned policy ``matching[i]``."""
    import jax
    import jax.numpy as jnp

    from emgail_jax import experts

    acting = jnp.asarray(matching)

    def policy(obs, intention):
        every = jax.vmap(lambda state: trainer.policy(state)(obs, None))(states)  # [K, ..., A]
        chosen = acting[intention]
        return jnp.take_along_axis(every, chosen[None, ..., None], axis=0)[0]

    key_quality, _ = experts.evaluation_keys()
    k_true = len(matching)
    return experts.quality(env, policy, key_quality, SUCCESS_EPISODES)[:k_true]


def _fresh_trainer(run, budget: Budget, reward_fn=None, absorbing_reward=None):
    from emgail_jax.method.rl import make_rl_train, true_reward

    # A fresh agent learns no discriminator: its rollouts need no AIRL successors.
    config = run.config.with_values(gamma=budget.gamma, discriminator_form="gail").method
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
) -> dict:
    """Trains one policy per learned intention on each of ``seeds``' frozen rewards of ``run``
    (all seeds vmapped in one program) and scores them; ``rl_seed`` picks another draw of the
    fresh policies' keys (0: the default's); ``parameters`` (one per seed) replace
    the run's :meth:`~emgail_jax.host.saved_run.SavedRun.reward_parameters`, read by
    ``reward_function`` and ``absorbing_function`` (default the run's
    :meth:`~emgail_jax.host.saved_run.SavedRun.reward_function` and
    :meth:`~emgail_jax.host.saved_run.SavedRun.absorbing_reward_function`)."""
    import jax

    from emgail_jax.host.saved_run import stacked

    learned = reward_function or run.reward_function()
    trainer = learned_reward_trainer(run, budget, learned, absorbing_function)
    per_seed_parameters = parameters or [run.reward_parameters(seed) for seed in seeds]
    parameters = stacked(per_seed_parameters)
    keys = fresh_keys(run, seeds, rl_seed)
    fresh = train_fresh(trainer, keys, parameters, budget.iterations, "re-optimising", progress)
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


def picked(draws: list[dict], pick) -> dict:
    """One :func:`scored` result (with its ``success``) whose true intention i is the agent of
    draw ``pick[i]`` of ``draws``, scores of agents trained alike under one matching."""
    pick = [int(d) for d in pick]
    column = lambda name: [np.asarray(draws[d][name])[..., i] for i, d in enumerate(pick)]
    result = {"matching": draws[0]["matching"], "returns": np.array(column("returns"))}
    known = draws[0]["erd"] is not None  # as scored: one draw picks itself alike
    result.update(erd_summary(np.stack(column("erd_curve_per_intention"), -1) if known else None))
    if "success" in draws[0]:
        result["success"] = [draws[d]["success"][i] for i, d in enumerate(pick)]
    return {**result, "draw": pick}


def chosen_by_learned_reward(draws: list[dict]) -> dict:
    """Several draws of fresh agents on the same rewards (:func:`reoptimize` results of the same
    seeds, one per RL seed) as one check: per run seed and learned intention, the agent that
    earned the most learned reward per step over the last iterations (a fall paid the absorbing
    state's reward for every step left, :func:`~emgail_jax.method.rl.reward_per_step`), the
    choice a user without the true reward can make. Each seed's ``draw`` says which draw acts
    each true intention."""
    per_seed = []
    for rows in zip(*(d["per_seed"] for d in draws), strict=True):
        earned = np.array([r["learned_reward_per_step"]["fresh_policies"] for r in rows])
        best = earned.argmax(0)  # [K learned]
        chosen = picked(rows, best[np.asarray(rows[0]["matching"])])
        chosen["learned_reward_per_step"] = {
            "fresh_policies": earned[best, np.arange(len(best))],
            "demonstrations": rows[0]["learned_reward_per_step"]["demonstrations"],
        }
        per_seed.append(
            {"run_seed": rows[0]["run_seed"], **chosen, "draws_erd": [r["erd"] for r in rows]}
        )
    shared = ("iteration", "snapshot", "budget", "absorbing_state", "eval_episodes")
    shared += ("expert_returns", "random_returns", "seeds")
    return {
        **{name: draws[0][name] for name in shared},
        "rl_seeds": [d["rl_seed"] for d in draws],
        **over_seeds(per_seed),
        "draws_erd_mean": [d["erd_mean"] for d in draws],
        "draws": draws,
        "compile_time_s": sum(d["compile_time_s"] for d in draws),
        "train_time_s": sum(d["train_time_s"] for d in draws),
    }


def best_baseline(baselines: list[dict]) -> dict:
    """Several true-reward baselines' draws (:func:`true_reward_baseline`) as one: per true
    intention the agent with the highest true return, each agent kept by the reward it trained
    on as :func:`chosen_by_learned_reward` keeps the learned reward's."""
    best = np.array([b["returns"] for b in baselines]).argmax(0)  # [K true]
    result = picked(baselines, best)
    return {
        **result,
        "meets_bar": [q["meets_bar"] for q in result["success"]],
        "draws_erd": [b["erd"] for b in baselines],
        "cache": [b["cache"] for b in baselines],
    }


def baseline_key(run, budget: Budget, rl_seed: int = 0) -> str:
    """What the true-reward baseline depends on: the env, its options and K, the budget, the
    TRPO settings and the RL seed, as a file name (another RL seed's does not begin with
    :func:`baseline_prefix`: the sweep's checks read RL seed 0's)."""
    config = run.config.to_dict()
    env = run.problem.env
    described = {
        "env": env.name,
        "options": env.options(),
        "intentions": env.num_intentions,
        "budget": dataclasses.asdict(budget),
        "config": {name: config[name] for name in RL_FIELDS if name != "gamma"},
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
        returns = np.asarray(stored["returns"])
        found = stored["success"]
    else:
        trainer = _fresh_trainer(run, budget)
        keys = jax.random.split(drawn(jax.random.PRNGKey(1000), rl_seed), run.num_intentions)[None]
        fresh = train_fresh(trainer, keys, None, budget.iterations, "true reward", progress)
        returns = fresh.returns[0]
        states = jax.tree.map(lambda x: x[0], fresh.states)
        found = records.to_json_value(success(run.problem.env, trainer, states, identity))
        if path is not None:
            os.makedirs(cache, exist_ok=True)
            records.write_json(path, {"returns": returns, "success": found})
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


def print_result(run, result: dict) -> None:
    from rich.console import Console
    from rich.table import Table

    names = run.problem.env.intention_names
    budget = result["budget"]
    table = Table(
        title=f"fresh TRPO on the learned rewards of iteration {result['iteration']}, "
        f"{budget['iterations']} iterations, gamma {budget['gamma']} (mean of the last "
        f"{FINAL_WINDOW})"
    )
    for column in ("reward", "norm. ERD", "per intention", "true returns (expert)", "bars met"):
        table.add_column(column)
    expert = result["expert_returns"]
    number = lambda x: "-" if x is None else f"{x:.3f}"
    two = lambda x: "-" if x is None else f"{x:.2f}"

    def row(label, scores):
        returns = ", ".join(
            f"{names[i]} {r:.1f}" + ("" if expert is None else f" ({expert[i]:.1f})")
            for i, r in enumerate(scores["returns"])
        )
        per = scores["erd_per_intention"]
        bars = scores["meets_bar"]
        met = "-" if None in bars else f"{sum(bars)}/{len(bars)}"
        per_text = "-" if per is None else " ".join(f"{e:.2f}" for e in per)
        table.add_row(label, number(scores["erd"]), per_text, returns, met)

    for seed_result in result["per_seed"]:
        seed_result = {**seed_result, "meets_bar": [q["meets_bar"] for q in seed_result["success"]]}
        row(f"seed {seed_result['run_seed']}", seed_result)
    if result.get("baseline"):
        row("true reward", result["baseline"])
    joint = (result.get("variant") or {}).get("joint_policies")
    for seed_result in joint["per_seed"] if joint else []:
        row(
            f"seed {seed_result['run_seed']}: its own policy",
            {**seed_result, "meets_bar": [None], "erd_per_intention": None},
        )
    console = Console(width=140)
    console.print(table)
    if result["erd_mean"] is not None:
        console.print(
            f"re-optimised ERD {result['erd_mean']:.3f} ± {result['erd_std']:.3f} over "
            f"{len(result['seeds'])} seeds"
        )
    reference = (result.get("variant") or {}).get("reference_meets_bar")
    if reference and None not in reference and not all(reference):
        # ERD is |reference - return|: past a weak reference it grows, so say it is weak.
        console.print(
            f"the variant's best true-reward agents, ERD's 0 here, meet {sum(reference)} of "
            f"{len(reference)} of the experts' bars: agents that beat them score ERD > 0 too; "
            "read the bars"
        )
    for seed_result in result["per_seed"] if "draws" in result else []:
        draws_erd = " ".join(two(e) for e in seed_result["draws_erd"])
        console.print(
            f"seed {seed_result['run_seed']}: best of {len(result['draws'])} draws by the "
            f"learned reward (each draw's ERD {draws_erd}), true intentions acted by draws "
            + " ".join(str(result["rl_seeds"][d]) for d in seed_result["draw"])
        )
    for seed_result in result["per_seed"]:
        earned = seed_result["learned_reward_per_step"]
        pairs = zip(earned["fresh_policies"], earned["demonstrations"], strict=True)
        console.print(
            f"seed {seed_result['run_seed']}: learned reward per step, fresh policies / "
            "demonstrations: " + ", ".join(f"{two(a)} / {two(b)}" for a, b in pairs)
        )


def argument_parser() -> argparse.ArgumentParser:
    from emgail_jax.method.config import REWARD_FORMS

    parser = argparse.ArgumentParser(
        prog="python -m emgail_jax.reoptimize", description=__doc__.split("\n")[0]
    )
    parser.add_argument("run_dir")
    parser.add_argument(
        "--seed",
        type=int,
        default=None,
        help="one run seed, as run --seed numbers it (default: all)",
    )
    parser.add_argument(
        "--rl-seed",
        type=int,
        default=0,
        metavar="R",
        help="another draw of the fresh policies' initialisation and samples on the same "
        "rewards (default 0)",
    )
    parser.add_argument(
        "--draws",
        type=int,
        default=1,
        metavar="N",
        help="train N draws (RL seeds R .. R + N - 1) and keep per intention the agent that "
        "earns the most learned reward; the true-reward baseline's the one that earns the "
        "most true reward (default 1); a check stopped part-way reuses the draws it finished",
    )
    parser.add_argument(
        "--snapshot", type=int, default=None, metavar="ITER", help="the rewards of this snapshot"
    )
    parser.add_argument("--iterations", type=int, default=None, help="default: the env's budget")
    parser.add_argument("--gamma", type=float, default=None, help="default: the env's budget")
    parser.add_argument(
        "--no-baseline", dest="baseline", action="store_false", help="skip the true reward"
    )
    parser.add_argument(
        "--cache", default=None, help=f"true-reward baselines (default {default_cache()})"
    )
    parser.add_argument(
        "--refit",
        action="store_true",
        help="the refit that re-optimises best where it was measured: --consolidate "
        f"{REFIT['consolidate']} --consolidate-fresh --consolidate-penalty "
        f"{REFIT['consolidate_penalty']:g} --consolidate-noise {REFIT['consolidate_noise']:g} "
        f"--consolidate-batch {REFIT['consolidate_batch']}, read as log D unless the env's "
        "episodes end early (without --consolidate-absorbing); on hopper also "
        f"{refit_extras('hopper')}, on halfcheetah {refit_extras('halfcheetah')}; a "
        "--consolidate-*, --reward-form or --iterations given with it replaces that one",
    )
    parser.add_argument(
        "--consolidate",
        type=int,
        default=None,
        metavar="STEPS",
        help="first refit each discriminator STEPS steps against every snapshot's policy "
        "(emgail_jax.host.consolidation; default 0: the run's reward as it is)",
    )
    parser.add_argument(
        "--consolidate-penalty",
        type=float,
        default=None,
        metavar="WEIGHT",
        help="with --consolidate: the refit's gradient penalty (default 0: none)",
    )
    parser.add_argument(
        "--consolidate-fresh",
        action="store_true",
        help="with --consolidate: refit from new discriminator weights, not the run's final ones",
    )
    parser.add_argument(
        "--consolidate-noise",
        type=float,
        default=None,
        metavar="S",
        help="with --consolidate: a copy of every policy sample moved by noise of standard "
        "deviation S is a further negative (default 0: none)",
    )
    parser.add_argument(
        "--consolidate-batch",
        type=int,
        default=None,
        metavar="M",
        help="with --consolidate: every step sees M samples per intention drawn anew from the "
        "snapshots' (default 0: all of them)",
    )
    parser.add_argument(
        "--consolidate-ranking",
        type=float,
        default=None,
        metavar="WEIGHT",
        help="with --consolidate: rank the snapshots' policies by iteration and the "
        "demonstrations above them, with this weight (emgail_jax.method.ranking; default 0: none)",
    )
    parser.add_argument(
        "--consolidate-ranking-random",
        action="store_true",
        help="with --consolidate-ranking: uniformly random actions rank below the oldest snapshot",
    )
    parser.add_argument(
        "--consolidate-ranking-still",
        action="store_true",
        help="with --consolidate-ranking: actions held at the middle of their range rank below "
        "the oldest snapshot (above random actions with --consolidate-ranking-random)",
    )
    parser.add_argument(
        "--consolidate-agents",
        type=int,
        default=0,
        metavar="ROUNDS",
        help="with --consolidate-batch: refit ROUNDS times more, each against fresh agents "
        "trained on the last refit too, as many negatives per step as the snapshots' "
        "(default 0: none)",
    )
    parser.add_argument(
        "--consolidate-state-only",
        action="store_true",
        help="with --consolidate: refit D(s, i) of the observation alone, every action read as "
        "zeros, and pay the fresh agents that",
    )
    parser.add_argument(
        "--consolidate-absorbing",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="with --consolidate: termination as an absorbing state (DAC) in the refit, learnt "
        "fake from the snapshots' falls; a fresh agent's fall is paid its reward for every "
        "step left, so --refit reads log D on any env whose recipe names no reward form "
        "(from new weights unless the run trained with absorbing states; on hopper --refit "
        "has it, --no-consolidate-absorbing drops it)",
    )
    parser.add_argument(
        "--ensemble",
        type=int,
        default=0,
        metavar="N",
        help="the reward is the mean of R_i over the last N snapshots up to the networks "
        "re-optimised (default 0: those networks' alone)",
    )
    parser.add_argument(
        "--across-seeds",
        action="store_true",
        help="each seed's fresh agents train on the mean of every run seed's reward, the seeds' "
        "intentions aligned by the demonstrations they hold (SavedRun.aligned_intentions)",
    )
    parser.add_argument(
        "--reward-form",
        default=None,
        choices=REWARD_FORMS,
        help="the reward the discriminator defines (default: the run's)",
    )
    parser.add_argument(
        "--env-set",
        nargs="+",
        default=[],
        metavar="KEY=FACTOR",
        help="train and score in a variant of the env: mass.BODY, gravity, friction, viscosity "
        "(factors on the model's values; ERD against the variant's own true-reward baseline)",
    )
    parser.add_argument(
        "--reference-draws",
        type=int,
        default=3,
        metavar="N",
        help="with --env-set: ERD's 0 is per intention the best of N true-reward draws in the "
        "variant (default 3)",
    )
    parser.add_argument("--out", default=None, help="default: RUN_DIR/reoptimize[-...].json")
    parser.add_argument("--quiet", action="store_true")
    return parser


def parse_args(argv=None, env: str | None = None) -> argparse.Namespace:
    """The command line with ``--refit``'s recipe for ``env`` filled in
    (:func:`with_refit_recipe`)."""
    return with_refit_recipe(argument_parser().parse_args(argv), env)


# `--refit`: experiment 35's refit of docs/rewards-that-reoptimise.md, from new weights against
# every snapshot's policy and noisy copies of its samples (reacher-2 0.070 over 8 seeds).
REFIT = {
    "consolidate": 4000,
    "consolidate_penalty": 10.0,
    "consolidate_noise": 1.0,
    "consolidate_batch": 5000,
}

# What `--refit` adds on the locomotion envs where the plain refit's agents stay near random
# actions: the snapshots ranked by iteration, read as the logit, and hopper's falls priced by an
# absorbing state (experiments 43, 61, 63 and 64); halfcheetah's agents are still closing on the
# experts' speed at 400 TRPO iterations and reach them by 1000 (experiment 64).
REFIT_BY_ENV: dict[str, dict] = {
    "hopper": {"consolidate_ranking": 10.0, "consolidate_absorbing": True, "reward_form": "logit"},
    "halfcheetah": {"consolidate_ranking": 30.0, "reward_form": "logit", "iterations": 1000},
}
# The refit's options that are off unless given or in the env's recipe.
OFF_UNLESS_GIVEN = {"consolidate_ranking": 0.0, "consolidate_absorbing": False}


def refit_extras(env: str) -> str:
    """``--refit``'s options on ``env`` beyond :data:`REFIT`, spelled as on the command line."""
    words = []
    for option, value in REFIT_BY_ENV.get(env, {}).items():
        words.append("--" + option.replace("_", "-"))
        if value is not True:
            words.append(f"{value:g}" if isinstance(value, float) else str(value))
    return " ".join(words)


def with_refit_recipe(args: argparse.Namespace, env: str | None = None) -> argparse.Namespace:
    """``args`` with every refit option it left unset at the :data:`REFIT` recipe's value (and
    ``env``'s :data:`REFIT_BY_ENV`) if ``--refit`` was given, and at none otherwise. The reward
    form, where neither the recipe nor the command line names one, is
    :func:`refit_reward_form`'s; the TRPO iterations the env's budget's."""
    args = argparse.Namespace(**vars(args))
    recipe = {**REFIT, **REFIT_BY_ENV.get(env, {})} if args.refit else {}
    unset = {**{option: type(value)(0) for option, value in REFIT.items()}, **OFF_UNLESS_GIVEN}
    for option, off in unset.items():
        if getattr(args, option) is None:
            setattr(args, option, recipe.get(option, off))
    for option in ("reward_form", "iterations"):
        if getattr(args, option) is None:
            setattr(args, option, recipe.get(option))
    args.consolidate_fresh = args.consolidate_fresh or args.refit
    return args


def refit_reward_form(args: argparse.Namespace, terminates: bool) -> str | None:
    """The reward form the fresh agents read: ``--reward-form`` if given; with ``--refit``,
    log D (below 0 wherever D < 1, so nothing off the demonstrations is paid) unless episodes
    end early without an absorbing state, where log D pays for falling and the run's own form
    stays (experiment 11); otherwise None, the run's."""
    from emgail_jax.method.config import RewardForm

    pays_falling = terminates and not args.consolidate_absorbing
    if args.reward_form is not None or not args.refit or pays_falling:
        return args.reward_form
    return RewardForm.LOG_D.value


def _check_options(args: argparse.Namespace) -> None:
    from emgail_jax.host.run_spec import RunError

    if args.rl_seed < 0:
        raise RunError("--rl-seed must be 0 or more")
    if args.draws < 1:
        raise RunError("--draws must be at least 1")
    if args.iterations is not None and args.iterations < 1:
        raise RunError("--iterations must be at least 1")
    if args.gamma is not None and not 0 < args.gamma <= 1:
        raise RunError("--gamma must be in (0, 1]")
    if args.consolidate < 0:
        raise RunError("--consolidate must be 0 (none) or more steps")
    if args.consolidate_penalty < 0 or (args.consolidate_penalty and not args.consolidate):
        raise RunError("--consolidate-penalty is a weight >= 0 and goes with --consolidate")
    if args.consolidate_noise < 0 or (args.consolidate_noise and not args.consolidate):
        raise RunError(
            "--consolidate-noise is a standard deviation >= 0 and goes with --consolidate"
        )
    if args.consolidate_batch < 0 or (args.consolidate_batch and not args.consolidate):
        raise RunError(
            "--consolidate-batch is a number of samples >= 0 and goes with --consolidate"
        )
    if args.consolidate_ranking < 0 or (args.consolidate_ranking and not args.consolidate):
        raise RunError("--consolidate-ranking is a weight >= 0 and goes with --consolidate")
    for level in ("random", "still"):
        if getattr(args, f"consolidate_ranking_{level}") and not args.consolidate_ranking:
            raise RunError(f"--consolidate-ranking-{level} goes with --consolidate-ranking WEIGHT")
    if args.consolidate_agents < 0 or (args.consolidate_agents and not args.consolidate_batch):
        raise RunError(
            "--consolidate-agents is a number of rounds >= 0 and goes with --consolidate-batch M"
        )
    if args.consolidate_fresh and not args.consolidate:
        raise RunError("--consolidate-fresh goes with --consolidate STEPS")
    if args.consolidate_state_only and not args.consolidate:
        raise RunError("--consolidate-state-only goes with --consolidate STEPS")
    if args.consolidate_absorbing and not args.consolidate:
        raise RunError("--consolidate-absorbing goes with --consolidate STEPS")
    if args.ensemble < 0 or (args.ensemble and args.consolidate):
        raise RunError("--ensemble is a number of snapshots >= 0, and not with --consolidate")
    if args.across_seeds and (args.ensemble or args.consolidate):
        raise RunError(
            "--across-seeds averages the run's own rewards: not with --ensemble or --consolidate"
        )
    if args.reference_draws < 1:
        raise RunError("--reference-draws must be at least 1")
    if args.env_set and not args.baseline:
        raise RunError(
            "--env-set scores against the variant's true-reward baseline: drop --no-baseline"
        )


@dataclasses.dataclass
class Chosen:
    """The reward the command line asks for: ``parameters`` (one per seed; None: the run's),
    read by ``function`` and ``absorbing`` (None: the run's reward and absorbing reward), and
    what was done to get them (``result`` keys)."""

    parameters: list | None = None
    function: object = None
    absorbing: object = None
    details: dict = dataclasses.field(default_factory=dict)


def _opened(args: argparse.Namespace):
    """``(args, run, seeds, Chosen)`` of the command line: ``args`` with the reward form
    resolved for the run's env (:func:`refit_reward_form`), the saved run with that form, and
    its consolidated or ensemble rewards if asked."""
    import envs
    from emgail_jax.host.run_spec import RunError
    from emgail_jax.host.saved_run import SavedRun, across_seeds_reward

    _check_options(args)
    run = SavedRun.open(args.run_dir, snapshot=args.snapshot)
    if args.env_set:
        run.problem = variant_problem(run, args.env_set)
    seeds = list(range(run.spec.seeds)) if args.seed is None else [run.seed_index(args.seed)]
    if run.config.method.m_step.form.airl and (args.reward_form or args.consolidate):
        # Its reward is g_i(s), no reading of a GAIL discriminator's logit, nor refitted as one.
        raise RunError(
            "an AIRL run's reward is g_i(s): --reward-form, --consolidate and --refit do not apply"
        )
    form = refit_reward_form(args, envs.env_class(run.spec.env).terminates)
    args = argparse.Namespace(**{**vars(args), "reward_form": form})
    if args.reward_form is not None:
        run = run.with_reward_form(args.reward_form)
    chosen = Chosen(details={"consolidation": None, "ensemble": None, "across_seeds": None})
    if args.consolidate:
        name, refit = "-".join(refit_parts(args)), refit_of(args)
        if refit.absorbing:
            if not (refit.fresh or run.trained_with_absorbing_states):
                raise RunError(
                    "--consolidate-absorbing needs --consolidate-fresh: the run's "
                    "discriminator was trained without absorbing states"
                )
            run = run.with_absorbing_states()
        chosen.parameters, chosen.details["consolidation"] = consolidated(
            run, seeds, refit, name, budget_of(args, run), progress=not args.quiet
        )
        chosen.details["saved_reward"] = name
        if refit.state_only:
            chosen.function = run.reward_function(state_only=True)
    if args.ensemble:
        chosen.parameters, iterations = ensemble_parameters(run, seeds, args.ensemble)
        chosen.function = ensemble_reward(run.reward_function())
        if run.absorbing_reward_function() is not None:
            chosen.absorbing = ensemble_reward(run.absorbing_reward_function())
        chosen.details["ensemble"] = iterations
    if args.across_seeds:
        if run.spec.seeds < 2:
            raise RunError("--across-seeds needs a run of 2 or more seeds")
        chosen.parameters = [run.across_seeds_parameters(seed) for seed in seeds]
        chosen.function = across_seeds_reward(run.reward_function())
        if run.absorbing_reward_function() is not None:
            chosen.absorbing = across_seeds_reward(run.absorbing_reward_function())
        # [seed][t][i]: seed t's intention averaged into intention i of each checked seed
        chosen.details["across_seeds"] = [p["intentions"] for p in chosen.parameters]
    return args, run, seeds, chosen


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


def main(argv=None) -> int:
    given = argument_parser().parse_args(argv)
    jax_setup.setup(host_devices=1)

    import envs
    from emgail_jax.host import run_lock
    from emgail_jax.host.checkpoints import CheckpointError
    from emgail_jax.host.demonstration_files import DemonstrationError
    from emgail_jax.host.run_spec import RunError, read_summary

    with contextlib.ExitStack() as held:
        try:
            held.enter_context(run_lock.reading(given.run_dir))  # no live run writes it
            env = read_summary(given.run_dir).get("env")
            opened = _opened(with_refit_recipe(given, env))
        except (RunError, CheckpointError, envs.EnvError, DemonstrationError) as error:
            print(f"error: {error}", file=sys.stderr)
            return 2
        return _reoptimized(*opened)


def _reoptimized(args: argparse.Namespace, run, seeds: list[int], chosen: Chosen) -> int:
    """The rest of :func:`main`: the fresh agents trained, scored and written."""
    from emgail_jax.host import records

    budget = budget_of(args, run)
    cache = args.cache or default_cache()
    variant = None
    if args.env_set:  # the variant's own expert, its best true-reward agents, first
        reference = variant_reference(run, budget, cache, args.reference_draws, not args.quiet)
        variant = {
            "dynamics": args.env_set,
            "reference_draws": args.reference_draws,
            "reference_draw": reference["draw"],
            "reference_returns": reference["draws_returns"],
            "original_experts_erd": reference["original_experts_erd"],
            "reference_meets_bar": reference["meets_bar"],
        }
        run.problem = with_expert_returns(run.problem, reference["returns"])
    rl_seeds = range(args.rl_seed, args.rl_seed + args.draws)
    path = args.out or os.path.join(args.run_dir, default_name(args))
    finished = FinishedDraws(path, check_identity(args, run)) if args.draws > 1 else None
    draws = []
    for rl_seed in rl_seeds:
        draw = finished.read(rl_seed, not args.quiet) if finished else None
        if draw is None:
            draw = reoptimize(
                run,
                seeds,
                budget,
                progress=not args.quiet,
                parameters=chosen.parameters,
                reward_function=chosen.function,
                absorbing_function=chosen.absorbing,
                rl_seed=rl_seed,
            )
            if finished:
                finished.write(rl_seed, draw)
        draws.append(draw)
    result = draws[0] if args.draws == 1 else chosen_by_learned_reward(draws)
    # What the fresh agents were paid: an AIRL run's policies trained on f - log pi, its
    # fresh agents on g_i(s).
    airl = run.config.method.m_step.form.airl
    result["reward_form"] = "airl-g" if airl else run.algorithm.reward_form
    result.update(chosen.details)
    if variant is not None:
        variant["joint_policies"] = joint_policies(run, seeds, result["iteration"])
    result["variant"] = variant
    result["baseline"] = None
    if args.baseline:
        # The baseline's own draws: how far the search varies on the true reward.
        baselines = [
            true_reward_baseline(run, budget, cache, not args.quiet, rl_seed=rl_seed)
            for rl_seed in rl_seeds
        ]
        result["baseline"] = baselines[0] if args.draws == 1 else best_baseline(baselines)
    records.write_json(path, result)
    if finished:
        finished.remove()
    print_result(run, records.to_json_value(result))
    print(f"wrote {path}")
    return 0


def check_identity(args: argparse.Namespace, run) -> dict:
    """What a check's draws depend on: its options (not how many draws, nor where and how it
    reports) and the iteration of the networks checked."""
    unrelated = ("draws", "quiet", "out", "baseline", "cache")
    options = {k: v for k, v in sorted(vars(args).items()) if k not in unrelated}
    return {"options": options, "iteration": run.snapshot or run.iteration}


@dataclasses.dataclass(frozen=True)
class FinishedDraws:
    """The draws of a check of several (``--draws``) finished so far, kept beside its file
    (``NAME.draws/rl-R.json``) until the check is written, so that a check stopped part-way
    goes on from its last finished draw. A draw kept for other options or networks is done
    again."""

    check_path: str
    identity: dict

    @property
    def directory(self) -> str:
        return os.path.splitext(self.check_path)[0] + ".draws"

    def _path(self, rl_seed: int) -> str:
        return os.path.join(self.directory, f"rl-{rl_seed}.json")

    def read(self, rl_seed: int, progress: bool) -> dict | None:
        from emgail_jax.host import records

        try:
            with open(self._path(rl_seed)) as f:
                kept = json.load(f)
        except (OSError, ValueError):
            return None
        if kept.get("check") != records.to_json_value(self.identity):
            return None
        if progress:
            print(f"RL draw {rl_seed}: finished before, reused")
        return kept["draw"]

    def write(self, rl_seed: int, draw: dict) -> None:
        from emgail_jax.host import records

        os.makedirs(self.directory, exist_ok=True)
        records.write_json(self._path(rl_seed), {"check": self.identity, "draw": draw})

    def remove(self) -> None:
        shutil.rmtree(self.directory, ignore_errors=True)


def default_name(args) -> str:
    """``reoptimize[-seed-S][-rl-R][-draws-N][-it-N][-gamma-G][-snapshot-ITER][-consolidated-STEPS
    [-penalty-W][-fresh][-noise-S][-batch-M]][-ensemble-N][-across-seeds][-FORM][-env-...].json``: a
    check of one seed, or at another budget, does not overwrite the check of every seed at the
    env's budget."""
    parts = ["reoptimize"]
    if args.seed is not None:
        parts.append(f"seed-{args.seed}")
    if args.rl_seed:
        parts.append(f"rl-{args.rl_seed}")
    if args.draws > 1:
        parts.append(f"draws-{args.draws}")
    if args.iterations is not None:
        parts.append(f"it-{args.iterations}")
    if args.gamma is not None:
        parts.append(f"gamma-{args.gamma:g}")
    parts += reward_parts(args)
    if args.env_set:
        parts.append("env-" + "-".join(args.env_set))
    return "-".join(parts) + ".json"


def reward_parts(args) -> list[str]:
    """The parts of :func:`default_name` that say which reward was checked: the snapshot, the
    refit or ensemble, the reward form."""
    parts = refit_parts(args)
    if args.ensemble:
        parts.append(f"ensemble-{args.ensemble}")
    if args.across_seeds:
        parts.append("across-seeds")
    if args.reward_form:
        parts.append(args.reward_form)
    return parts


def refit_parts(args) -> list[str]:
    """The snapshot and the refit's options: with ``--consolidate``, the name of the refitted
    discriminator it saves (``RUN/rewards/NAME``), whatever reward form reads it."""
    parts = []
    if args.snapshot is not None:
        parts.append(f"snapshot-{args.snapshot}")
    if args.consolidate:
        parts.append(f"consolidated-{args.consolidate}")
    if args.consolidate_penalty:
        parts.append(f"penalty-{args.consolidate_penalty:g}")
    if args.consolidate_fresh:
        parts.append("fresh")
    if args.consolidate_noise:
        parts.append(f"noise-{args.consolidate_noise:g}")
    if args.consolidate_batch:
        parts.append(f"batch-{args.consolidate_batch}")
    if args.consolidate_ranking:
        parts.append(f"ranking-{args.consolidate_ranking:g}")
    if args.consolidate_ranking_random:
        parts.append("random")
    if args.consolidate_ranking_still:
        parts.append("still")
    if args.consolidate_agents:
        parts.append(f"agents-{args.consolidate_agents}")
    if args.consolidate_state_only:
        parts.append("state-only")
    if args.consolidate_absorbing:
        parts.append("absorbing")
    return parts


def refit_of(args):
    """The :class:`~emgail_jax.host.consolidation.Refit` the ``--consolidate*`` options ask for."""
    from emgail_jax.host.consolidation import Refit

    return Refit(
        steps=args.consolidate,
        gradient_penalty=args.consolidate_penalty,
        fresh=args.consolidate_fresh,
        support_noise=args.consolidate_noise,
        batch=args.consolidate_batch,
        ranking=args.consolidate_ranking,
        ranking_random=args.consolidate_ranking_random,
        ranking_still=args.consolidate_ranking_still,
        agent_rounds=args.consolidate_agents,
        state_only=args.consolidate_state_only,
        absorbing=args.consolidate_absorbing,
    )


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
            key = jax.random.PRNGKey(number + 2000)
            samples = consolidation.snapshot_policy_samples(run, seed, key)
            found, losses = consolidation.consolidated_parameters(
                run, seed, refit, key, samples=samples
            )
            if refit.agent_rounds:
                found, losses = refitted_against_agents(
                    run, seed, refit, key, budget, found, samples, progress
                )
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


if __name__ == "__main__":
    sys.exit(main())
