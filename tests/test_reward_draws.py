"""The draw rules: several draws of fresh agents kept as one check by the learned reward alone,
the true-reward baseline's draws as one floor, and one seed's checks joined."""

import numpy as np
import pytest

from emgail_jax.host.schedule import FINAL_WINDOW
from emgail_jax.reward import check, draws


def _draw(rl_seed, earned, erd_per_intention, matching=(1, 0), run_seed=0):
    """One seed's check as :func:`check.reoptimize` writes it: 3 iterations, 2 true and
    learned intentions, true intention i acted by learned ``matching[i]``."""
    per_intention = np.tile(np.asarray(erd_per_intention, float), (3, 1))  # [iterations, K true]
    seed = {
        "run_seed": run_seed,
        "matching": list(matching),
        "returns": 100 * (1 - per_intention[-1]),
        "erd": float(per_intention.mean(-1)[-FINAL_WINDOW:].mean()),
        "erd_per_intention": per_intention[-1],
        "erd_curve": per_intention.mean(-1),
        "erd_curve_per_intention": per_intention,
        "success": [{"intention": f"path{i + 1}", "draw": rl_seed} for i in range(2)],
        "learned_reward_per_step": {"fresh_policies": earned, "demonstrations": [0.5, 0.4]},
    }
    shared = {"iteration": 4, "snapshot": None, "budget": {}, "absorbing_state": False}
    shared |= {"eval_episodes": 2, "expert_returns": [100, 100], "random_returns": [0, 0]}
    for q in seed["success"]:
        q["meets_bar"] = bool(rl_seed)
    return {
        **shared,
        "seeds": [run_seed],
        "rl_seed": rl_seed,
        **check.over_seeds([seed]),
        "compile_time_s": 1.0,
        "train_time_s": 2.0,
    }


def test_each_intention_keeps_the_draw_that_earns_the_most_learned_reward():
    """Learned intention 0 earns most in draw 0, learned 1 in draw 1; true intention 0 is acted
    by learned 1 (draw 1's agent), true 1 by learned 0 (draw 0's): the true ERDs play no part."""
    every = [_draw(0, [0.5, -1.0], [0.9, 0.2]), _draw(1, [0.1, 0.2], [0.3, 0.8])]
    chosen = draws.chosen_by_learned_reward(every)
    seed = chosen["per_seed"][0]
    assert seed["draw"] == [1, 0] and chosen["rl_seeds"] == [0, 1]
    np.testing.assert_allclose(seed["erd_per_intention"], [0.3, 0.2])
    assert np.isclose(seed["erd"], 0.25) and chosen["erd"] == [seed["erd"]]
    np.testing.assert_allclose(seed["returns"], [70, 80])
    assert [q["draw"] for q in seed["success"]] == [1, 0]
    assert chosen["meets_bar"] == [[True, False]]
    np.testing.assert_allclose(seed["learned_reward_per_step"]["fresh_policies"], [0.5, 0.2])
    np.testing.assert_allclose(seed["draws_erd"], [0.55, 0.55])
    assert chosen["draws"] == every
    assert chosen["train_time_s"] == 4.0


def test_the_nearest_rule_keeps_the_agent_nearest_what_the_demonstrations_earn():
    """The demonstrations earn 0.5 and 0.4 per step: learned intention 0's draw 0 out-earns them
    far (0.9) and is passed over for draw 1's 0.45; learned 1's draw 0 (0.3) is nearer 0.4 than
    draw 1's 0.2, and is kept by both rules."""
    every = [_draw(0, [0.9, 0.3], [0.6, 0.1]), _draw(1, [0.45, 0.2], [0.3, 0.2])]
    rows = [d["per_seed"][0] for d in every]
    assert list(draws.kept_draws(rows, "most")) == [0, 0]
    assert list(draws.kept_draws(rows, "nearest")) == [1, 0]
    chosen = draws.chosen_by_learned_reward(every, "nearest")
    seed = chosen["per_seed"][0]
    assert chosen["draw_rule"] == "nearest" and seed["draw"] == [0, 1]  # true 0 is learned 1
    np.testing.assert_allclose(seed["erd_per_intention"], [0.6, 0.2])
    np.testing.assert_allclose(seed["learned_reward_per_step"]["fresh_policies"], [0.45, 0.3])
    assert draws.chosen_by_learned_reward(every)["draw_rule"] == "most"
    with pytest.raises(ValueError, match="no draw rule 'least'"):
        draws.kept_draws(rows, "least")


def test_one_draw_chosen_is_that_draw():
    draw = _draw(0, [0.3, 0.1], [0.123456789, 0.987654321])
    chosen = draws.chosen_by_learned_reward([draw])
    assert chosen["erd"] == draw["erd"]  # bit for bit: the same sum in the same order
    curve = lambda result: result["per_seed"][0]["erd_curve"]
    np.testing.assert_array_equal(curve(chosen), curve(draw))


def test_a_draw_read_back_from_its_file_is_chosen_as_the_draw_in_memory():
    """Iterations not scored are NaN in memory and null in the draw's file; a check that goes on
    from its files chooses as one that never stopped."""
    import json

    from emgail_jax.host import records

    every = [_draw(0, [0.3, 0.1], [0.2, 0.4]), _draw(1, [0.1, 0.3], [0.3, 0.1])]
    for draw in every:  # two iterations not scored before the final window's ten
        seed = draw["per_seed"][0]
        scored = np.tile(seed["erd_curve_per_intention"][-1], (10, 1))
        seed["erd_curve_per_intention"] = np.vstack([np.full((2, 2), np.nan), scored])
    read_back = [json.loads(records.json_text(records.to_json_value(d))) for d in every]
    assert read_back[0]["per_seed"][0]["erd_curve_per_intention"][0] == [None, None]
    chosen, again = map(draws.chosen_by_learned_reward, (every, read_back))
    assert again["erd"] == chosen["erd"] and np.isfinite(chosen["erd"]).all()
    curve = lambda result: result["per_seed"][0]["erd_curve"]
    np.testing.assert_array_equal(np.asarray(curve(again), float), curve(chosen))


def test_the_best_baseline_keeps_the_highest_true_return_per_intention():
    every = [_draw(r, [0, 0], erd)["per_seed"][0] for r, erd in ((0, [0.1, 0.6]), (1, [0.4, 0.2]))]
    baselines = [{**d, "cache": f"draw{r}.json"} for r, d in enumerate(every)]
    best = draws.best_baseline(baselines)
    assert best["draw"] == [0, 1] and best["meets_bar"] == [False, True]
    np.testing.assert_allclose(best["erd_per_intention"], [0.1, 0.2])
    np.testing.assert_allclose(best["draws_erd_per_intention"], [[0.1, 0.6], [0.4, 0.2]])
    assert best["cache"] == ["draw0.json", "draw1.json"]


def test_checks_of_one_seed_each_join_into_the_check_of_both():
    """Joining seed by seed, then choosing per seed among the draws, is choosing in each
    seed's own check: the seeds' draws do not interact."""
    seed_0 = [_draw(0, [0.5, -1.0], [0.9, 0.2]), _draw(1, [0.1, 0.2], [0.3, 0.8])]
    seed_1 = [_draw(r, [0.2, 0.1], [0.1 + r, 0.4], (0, 1), run_seed=1) for r in (0, 1)]
    joined = [check.joined_seeds(list(parts)) for parts in zip(seed_0, seed_1, strict=True)]
    assert joined[0]["seeds"] == [0, 1] and joined[1]["rl_seed"] == 1
    assert joined[0]["erd"] == [*seed_0[0]["erd"], *seed_1[0]["erd"]]
    assert joined[0]["train_time_s"] == 4.0
    chosen = draws.chosen_by_learned_reward(joined)
    alone = [draws.chosen_by_learned_reward(parts) for parts in (seed_0, seed_1)]
    from emgail_jax.host.records import to_json_value

    assert to_json_value(chosen["per_seed"]) == to_json_value([a["per_seed"][0] for a in alone])
    assert np.isclose(chosen["erd_mean"], np.mean([a["erd"][0] for a in alone]))
    with pytest.raises(ValueError, match="differ in rl_seed"):
        check.joined_seeds([seed_0[0], seed_1[1]])


def test_the_hindsight_rule_keeps_per_true_intention_the_draw_of_the_lowest_erd():
    """What draw_choice compares the rules with: the true ERD read, which no user can do."""
    every = [_draw(0, [0.5, -1.0], [0.9, 0.2]), _draw(1, [0.1, 0.2], [0.3, 0.8])]
    rows = [d["per_seed"][0] for d in every]
    assert draws.kept_per_true_intention(rows, draws.BY_TRUE_ERD) == [1, 0]
    assert draws.kept_per_true_intention(rows, "most") == [1, 0]  # true 0 is learned 1
    assert draws.kept_per_true_intention(rows, "nearest") == [1, 0]


def _agents(*shares):
    return [{"episodes_meeting_bar": share} for share in shares]


def test_the_headline_is_the_mean_of_every_seed_and_draw_with_the_sample_std():
    """2 draws of 2 seeds, ERD 0.1 0.4 and 0.3 0.2: mean 0.25, deviations -0.15 0.15 0.05 -0.05,
    squares 0.05, sample variance 0.05 / 3; every agent's share of episodes meeting its bar."""
    every = [
        {"erd": [0.1, 0.4], "per_seed": [{"success": _agents(1.0)}, {"success": _agents(0.0)}]},
        {"erd": [0.3, 0.2], "per_seed": [{"success": _agents(0.5)}, {"success": _agents(0.5)}]},
    ]
    found = draws.single_draws(every)
    assert found["erd_draws_mean"] == pytest.approx(0.25) and found["erd_draws_n"] == 4
    assert found["erd_draws_std"] == pytest.approx(np.sqrt(0.05 / 3))
    assert found["success_rate"] == pytest.approx(0.5) and found["final_distance"] is None
    one = draws.single_draws([{"erd": [0.3], "per_seed": [{"success": _agents(None)}]}])
    assert one["erd_draws_std"] is None and one["success_rate"] is None  # no bar: none


def test_the_baselines_lowest_erd_draw_is_reported_beside_the_one_kept():
    """The draw kept by true return (ERD 0.8, it outruns its expert) and draw 1, the lowest."""
    baselines = [
        {"erd": 0.8, "success": _agents(1.0, 1.0)},
        {"erd": 0.1, "success": _agents(1.0, 0.5)},
        {"erd": 0.4, "success": _agents(0.0, 0.5)},
    ]
    found = draws.baseline_draws(baselines, kept=baselines[0])
    assert found["draws_erd"] == [0.8, 0.1, 0.4]
    assert (found["erd_lowest"], found["lowest_erd_draw"]) == (0.1, 1)
    assert found["success_rate"] == pytest.approx(4 / 6) and found["kept_success_rate"] == 1.0
