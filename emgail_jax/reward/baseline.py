"""The true-reward baseline of a reward check: the same TRPO, settings and budget on the env's
true rewards, the floor a learned reward is judged against, computed once per env, K and
budget and cached (no algorithm enters its key, so one baseline serves every algorithm's runs);
and in a variant of the env's dynamics, ERD's references there."""

from __future__ import annotations

import hashlib
import json
import os

import numpy as np

from emgail_jax.reward.check import (
    Budget,
    drawn,
    fresh_trainer,
    scored,
    success,
    train_fresh,
)
from emgail_jax.reward.draws import best_baseline
from emgail_jax.reward.progress import PartialTraining

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


def default_cache() -> str:
    root = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(root, "emgail-jax", "true-reward-baselines")


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
        trainer = fresh_trainer(run, budget)
        keys = jax.random.split(drawn(jax.random.PRNGKey(1000), rl_seed), run.num_intentions)[None]
        # Its key names everything it depends on; saved part-way only where it is cached.
        partial = None if path is None else PartialTraining(path + ".partial.npz", {"key": key})
        fresh = train_fresh(
            trainer,
            keys,
            None,
            budget.iterations,
            label="true reward",
            progress=progress,
            partial=partial,
        )
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
