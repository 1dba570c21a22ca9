"""The draw rules: several RL draws of fresh agents on one reward summed up over every seed x
draw (the check's headline) and made one check by what a user without the true reward can see
(the learned reward each agent earns); the true-reward baseline's draws made one floor, with
its lowest-ERD draw beside it."""

from __future__ import annotations

import numpy as np

from emgail_jax.reward.check import (
    DRAW_SHARED,
    erd_summary,
    mean_or_none,
    over_seeds,
    sample_std,
    success_summary,
)


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


# A rule no user can follow, the true reward read: what the draws held, for comparison only.
BY_TRUE_ERD = "by true ERD"


def kept_per_true_intention(rows: list[dict], rule: str) -> list[int]:
    """Per true intention, the draw ``rule`` (one of :data:`DRAW_RULES` or
    :data:`BY_TRUE_ERD`) keeps among one seed's ``rows`` (one per draw)."""
    if rule == BY_TRUE_ERD:
        return list(np.array([r["erd_per_intention"] for r in rows], float).argmin(0))
    return list(kept_draws(rows, rule)[np.asarray(rows[0]["matching"])])


def single_draws(draws: list[dict]) -> dict:
    """A check's headline over every seed x draw of ``draws`` (:func:`reoptimize` results, one
    per RL seed): the mean ERD, its sample standard deviation and their number, and the share
    of every agent's episodes that meet the experts' bars (the final distance to the ball
    beside it, where measured). Best-of-N's kept agents are a choice among these, shown beside
    them."""
    erds = [erd for draw in draws for erd in draw["erd"]]
    rows = [row for draw in draws for row in draw.get("per_seed", ())]  # none: a bare record
    agents = [q for row in rows for q in row.get("success", ())]
    return {
        "erd_draws_mean": mean_or_none(erds),
        "erd_draws_std": sample_std(erds),
        "erd_draws_n": len(erds),
        **success_summary(agents),
    }


def baseline_draws(baselines: list[dict], kept: dict) -> dict:
    """The true-reward baseline's draws beside the one ``kept`` (:func:`best_baseline`, or the
    one draw): every draw's ERD, the lowest-ERD draw (an agent that outruns its expert has the
    most true return and a worse ERD) and the share of episodes meeting the experts' bars, over
    every draw's agents and over the kept ones."""
    erds = [b["erd"] for b in baselines]
    lowest = None if None in erds else int(np.argmin(erds))
    every = success_summary([q for b in baselines for q in b["success"]])
    return {
        "draws_erd": erds,
        "erd_lowest": None if lowest is None else erds[lowest],
        "lowest_erd_draw": lowest,
        **every,
        "kept_success_rate": success_summary(kept["success"])["success_rate"],
    }
