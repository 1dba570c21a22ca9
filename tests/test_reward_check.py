"""The reward check on a tiny run: the run's matching, the true-reward baseline shared by every
algorithm and cached, the demonstrations' reward, ensembles, a saved refit, the draws."""

import dataclasses
import types

import jax
import numpy as np
import pytest

from emgail_jax.host import check_progress, reward_check
from emgail_jax.host.consolidation import Refit

pytestmark = pytest.mark.heavy


@pytest.fixture(scope="module")
def saved(tiny_run):
    from emgail_jax.host.saved_run import SavedRun

    return SavedRun.open(str(tiny_run))


def test_the_run_matching_is_the_last_evaluation_at_or_before_the_iteration(saved):
    history = saved.history["eval/matching"]
    for iteration in (1, 2, 4):
        np.testing.assert_array_equal(
            reward_check.run_matching(saved, 1, iteration), history[1, iteration - 1]
        )


def test_one_true_reward_baseline_serves_every_algorithm(saved):
    """The baseline's cache key holds the env, K, budget and TRPO settings, not the algorithm
    whose reward is checked: the sweep's EM-GAIL, Info/IntentionGAIL and GAIL cells of an env
    and K share one baseline."""
    budget = reward_check.Budget(iterations=400, gamma=0.995, gae_lambda=0.97)
    key = reward_check.baseline_key(saved, budget)
    assert key.startswith("driver-k2-400it-g0.995-")
    for algo in ("gail", "infogail"):
        other = dataclasses.replace(saved, config=saved.config.with_values(algo=algo))
        assert other.config.method.algo == algo
        assert reward_check.baseline_key(other, budget) == key
    wider = dataclasses.replace(saved, config=saved.config.with_values(num_envs=3))
    assert reward_check.baseline_key(wider, budget) != key
    # The true reward has no absorbing state, whatever the run learned.
    absorbing = dataclasses.replace(saved, config=saved.config.with_values(absorbing_state=True))
    assert reward_check.baseline_key(absorbing, budget) == key


def test_demonstrations_reward_weights_pairs_by_their_responsibilities(saved):
    expert = saved.demonstration_pairs
    gamma = np.asarray(saved.responsibilities(0).gamma)
    reward = saved.reward(0)
    earned = reward_check.demonstrations_reward(saved, 0)
    for i in range(2):
        if gamma[:, i].sum() == 0:  # no demonstration assigned: nothing to earn on
            assert np.isnan(earned[i])
            continue
        per_pair = np.asarray(reward(expert.observations, expert.actions, i))
        expected = (gamma[:, i] * per_pair).sum() / gamma[:, i].sum()
        np.testing.assert_allclose(earned[i], expected, rtol=1e-5)


def test_an_ensemble_reward_is_the_mean_of_the_snapshots_rewards(tiny_run, saved):
    from emgail_jax.host.saved_run import SavedRun

    parameters, iterations = reward_check.ensemble_parameters(saved, [1], 2)
    assert iterations == [2, 4]
    ensemble = reward_check.ensemble_reward(saved.reward_function())
    pairs = saved.demonstration_pairs
    earlier = SavedRun.open(str(tiny_run), snapshot=2)
    for i in range(2):
        every = [r.reward(1)(pairs.observations, pairs.actions, i) for r in (earlier, saved)]
        assert not np.allclose(every[0], every[1])  # two discriminators
        mean = ensemble(parameters[0], pairs.observations, pairs.actions, i)
        np.testing.assert_allclose(mean, np.mean(every, 0), rtol=1e-5)
    _, last = reward_check.ensemble_parameters(saved, [1], 1)
    assert last == [4]


def test_a_stopped_training_goes_on_from_its_save_as_if_never_stopped(saved, tmp_path):
    """Fresh agents stopped after a save and started again with it end bit-identical to agents
    trained at once."""
    from emgail_jax.host.saved_run import stacked

    budget = reward_check.Budget(iterations=20, gamma=0.99, gae_lambda=0.97)
    trainer = reward_check.learned_reward_trainer(saved, budget, saved.reward_function())
    keys = reward_check.fresh_keys(saved, [1], rl_seed=0)
    data = stacked([saved.reward_parameters(1)])

    def train(partial=None):
        return reward_check.train_fresh(trainer, keys, data, 20, "", False, partial)

    whole = train()

    class Stopped(Exception):
        pass

    class StoppedAfterItsFirstSave(check_progress.PartialTraining):
        def write(self, *args):
            super().write(*args)
            raise Stopped

    path = str(tmp_path / "rl-0.partial.npz")
    with pytest.raises(Stopped):
        train(StoppedAfterItsFirstSave(path, {"check": 1}, every_s=0.0))
    partial = check_progress.PartialTraining(path, {"check": 1})
    done, *_ = partial.read(whole.states, 10, 20)
    assert done == 10  # the first of two chunks
    resumed = train(partial)
    np.testing.assert_array_equal(resumed.returns, whole.returns)
    np.testing.assert_array_equal(resumed.earned, whole.earned)
    for a, b in zip(jax.tree.leaves(resumed.states), jax.tree.leaves(whole.states), strict=True):
        np.testing.assert_array_equal(a, b)
    assert resumed.returns.shape == (1, 20, 2, 2)


def test_fresh_agents_scored_on_the_schedule_train_as_if_scored_every_iteration(saved):
    """Evaluation episodes every 10th iteration and each of the last 10 only: the agents, the
    reward they earn and the returns where scored are those of agents scored every iteration;
    the other iterations' returns are NaN."""
    from emgail_jax.host.saved_run import stacked

    budget = reward_check.Budget(iterations=30, gamma=0.99, gae_lambda=0.97)
    trainer = reward_check.learned_reward_trainer(saved, budget, saved.reward_function())
    keys = reward_check.fresh_keys(saved, [0, 1], rl_seed=0)
    data = stacked([saved.reward_parameters(seed) for seed in (0, 1)])
    train = lambda **every: reward_check.train_fresh(trainer, keys, data, 30, "", False, **every)
    scheduled, every = train(), train(curve_every=1)
    for a, b in zip(jax.tree.leaves(scheduled.states), jax.tree.leaves(every.states), strict=True):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(scheduled.earned, every.earned)
    scored = np.zeros(30, bool)
    scored[[9, *range(19, 30)]] = True  # iterations 10 and 20 to 30
    np.testing.assert_array_equal(scheduled.returns[:, scored], every.returns[:, scored])
    assert np.isnan(scheduled.returns[:, ~scored]).all()
    assert np.isfinite(every.returns).all()


def test_a_refit_is_saved_once_and_reused(tiny_run, tmp_path, capsys):
    import shutil

    from emgail_jax.host.run_spec import RunError
    from emgail_jax.host.saved_run import SavedRun

    copy = tmp_path / "run"
    shutil.copytree(tiny_run, copy, ignore=shutil.ignore_patterns("rewards"))
    run = SavedRun.open(str(copy))
    first, first_losses = reward_check.consolidated(run, [1], Refit(steps=3), "consolidated-3")
    assert "reused" not in capsys.readouterr().out
    again, again_losses = reward_check.consolidated(run, [1], Refit(steps=3), "consolidated-3")
    assert "seed 1: the refitted reward 'consolidated-3' saved before, reused" in (
        capsys.readouterr().out
    )
    for a, b in zip(jax.tree.leaves(first), jax.tree.leaves(again), strict=True):
        np.testing.assert_array_equal(a, b)
    loss = lambda losses: losses[0]["after"]["discriminator/loss"]
    assert loss(again_losses) == pytest.approx(float(loss(first_losses)))
    with pytest.raises(RunError, match=r"'consolidated-3' .* was refitted otherwise"):
        reward_check.consolidated(run, [1], Refit(steps=4), "consolidated-3")


@pytest.mark.slow  # fresh agents trained twice inside the refit
def test_a_refit_against_fresh_agents_trains_them_and_records_each_round(tiny_run, tmp_path):
    import shutil

    from emgail_jax.host import consolidation
    from emgail_jax.host.run_spec import RunError
    from emgail_jax.host.saved_run import SavedRun

    copy = tmp_path / "run"
    shutil.copytree(tiny_run, copy, ignore=shutil.ignore_patterns("rewards"))
    run = SavedRun.open(str(copy))
    budget = reward_check.Budget(iterations=2, gamma=0.99, gae_lambda=0.97)
    plain = Refit(steps=5, fresh=True, batch=20)
    (before,), _ = reward_check.consolidated(run, [1], plain, "plain", budget, progress=False)
    against = dataclasses.replace(plain, agent_rounds=2)
    (after,), (losses,) = reward_check.consolidated(run, [1], against, "agents", budget, False)
    rounds = losses["agent_rounds"]
    assert len(rounds) == 2
    for one in rounds:
        assert one["erd"] >= 0 and len(one["returns"]) == 2
        assert np.asarray(one["learned_reward_per_step"]).shape == (2,)
    leaves = zip(jax.tree.leaves(before), jax.tree.leaves(after), strict=True)
    assert not all(np.array_equal(a, b) for a, b in leaves)
    description = consolidation.read_description(str(copy), "agents")
    assert description["agents"] == {"reward_form": "gail", "budget": dataclasses.asdict(budget)}
    with pytest.raises(RunError, match="refitted otherwise"):
        other = reward_check.Budget(iterations=3, gamma=0.99, gae_lambda=0.97)
        reward_check.consolidated(run, [1], against, "agents", other, False)


def test_another_rl_seeds_baseline_is_kept_apart_from_the_sweeps(saved):
    budget = reward_check.default_budget(saved)
    first = reward_check.baseline_key(saved, budget)
    assert first.startswith(reward_check.baseline_prefix("driver", 2, budget.iterations))
    assert reward_check.baseline_key(saved, budget, rl_seed=1) == "rl1-" + first


def test_the_budgets_lambda_is_the_runs_unless_given_and_names_its_baseline(saved, monkeypatch):
    from emgail_jax import reoptimize
    from emgail_jax.method import rl

    budget = reward_check.default_budget(saved)
    assert budget.gae_lambda == saved.config.method.b_step.gae_lambda
    args = reoptimize.parse_args(["RUN", "--gae-lambda", "0.995"])
    given = reoptimize.budget_of(args, saved)
    assert given == dataclasses.replace(budget, gae_lambda=0.995)
    assert reward_check.baseline_key(saved, given) != reward_check.baseline_key(saved, budget)
    monkeypatch.setattr(rl, "make_rl_train", lambda config, *rest: config)
    assert reward_check._fresh_trainer(saved, given).b_step.gae_lambda == 0.995


def test_value_target_scaling_is_the_runs_unless_given_and_names_its_baseline(saved, monkeypatch):
    """Off (the run's), the baseline keeps the key it had before scaling was a setting: the
    key of a config without it."""
    from emgail_jax import reoptimize
    from emgail_jax.method import rl

    budget = reward_check.default_budget(saved)
    assert budget.value_target_scaling is False
    args = reoptimize.parse_args(["RUN", "--value-target-scaling"])
    scaled = reoptimize.budget_of(args, saved)
    assert scaled == dataclasses.replace(budget, value_target_scaling=True)
    assert reward_check.baseline_key(saved, scaled) != reward_check.baseline_key(saved, budget)
    fields = tuple(f for f in reward_check.RL_FIELDS if f != "value_target_scaling")
    monkeypatch.setattr(reward_check, "RL_FIELDS", fields)
    without_the_setting = reward_check.baseline_key(saved, budget)
    monkeypatch.undo()
    assert reward_check.baseline_key(saved, budget) == without_the_setting
    monkeypatch.setattr(rl, "make_rl_train", lambda config, *rest: config)
    assert reward_check._fresh_trainer(saved, scaled).b_step.value_target_scaling is True
    assert reward_check._fresh_trainer(saved, budget).b_step.value_target_scaling is False


def test_a_check_not_given_scaling_keeps_the_identity_it_had_before_the_option():
    from emgail_jax import reoptimize

    run = types.SimpleNamespace(snapshot=None, iteration=4)
    identity = reoptimize.check_identity(reoptimize.parse_args(["RUN"]), run)
    assert "value_target_scaling" not in identity["options"]
    given = reoptimize.parse_args(["RUN", "--no-value-target-scaling"])
    assert reoptimize.check_identity(given, run)["options"]["value_target_scaling"] is False


def _draw(rl_seed, earned, erd_per_intention, matching=(1, 0), run_seed=0):
    """One seed's check as :func:`reward_check.reoptimize` writes it: 3 iterations, 2 true and
    learned intentions, true intention i acted by learned ``matching[i]``."""
    per_intention = np.tile(np.asarray(erd_per_intention, float), (3, 1))  # [iterations, K true]
    seed = {
        "run_seed": run_seed,
        "matching": list(matching),
        "returns": 100 * (1 - per_intention[-1]),
        "erd": float(per_intention.mean(-1)[-reward_check.FINAL_WINDOW :].mean()),
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
        **reward_check.over_seeds([seed]),
        "compile_time_s": 1.0,
        "train_time_s": 2.0,
    }


def test_each_intention_keeps_the_draw_that_earns_the_most_learned_reward():
    """Learned intention 0 earns most in draw 0, learned 1 in draw 1; true intention 0 is acted
    by learned 1 (draw 1's agent), true 1 by learned 0 (draw 0's): the true ERDs play no part."""
    draws = [_draw(0, [0.5, -1.0], [0.9, 0.2]), _draw(1, [0.1, 0.2], [0.3, 0.8])]
    chosen = reward_check.chosen_by_learned_reward(draws)
    seed = chosen["per_seed"][0]
    assert seed["draw"] == [1, 0] and chosen["rl_seeds"] == [0, 1]
    np.testing.assert_allclose(seed["erd_per_intention"], [0.3, 0.2])
    assert np.isclose(seed["erd"], 0.25) and chosen["erd"] == [seed["erd"]]
    np.testing.assert_allclose(seed["returns"], [70, 80])
    assert [q["draw"] for q in seed["success"]] == [1, 0]
    assert chosen["meets_bar"] == [[True, False]]
    np.testing.assert_allclose(seed["learned_reward_per_step"]["fresh_policies"], [0.5, 0.2])
    np.testing.assert_allclose(seed["draws_erd"], [0.55, 0.55])
    assert chosen["draws"] == draws
    assert chosen["train_time_s"] == 4.0


def test_the_nearest_rule_keeps_the_agent_nearest_what_the_demonstrations_earn():
    """The demonstrations earn 0.5 and 0.4 per step: learned intention 0's draw 0 out-earns them
    far (0.9) and is passed over for draw 1's 0.45; learned 1's draw 0 (0.3) is nearer 0.4 than
    draw 1's 0.2, and is kept by both rules."""
    draws = [_draw(0, [0.9, 0.3], [0.6, 0.1]), _draw(1, [0.45, 0.2], [0.3, 0.2])]
    rows = [d["per_seed"][0] for d in draws]
    assert list(reward_check.kept_draws(rows, "most")) == [0, 0]
    assert list(reward_check.kept_draws(rows, "nearest")) == [1, 0]
    chosen = reward_check.chosen_by_learned_reward(draws, "nearest")
    seed = chosen["per_seed"][0]
    assert chosen["draw_rule"] == "nearest" and seed["draw"] == [0, 1]  # true 0 is learned 1
    np.testing.assert_allclose(seed["erd_per_intention"], [0.6, 0.2])
    np.testing.assert_allclose(seed["learned_reward_per_step"]["fresh_policies"], [0.45, 0.3])
    assert reward_check.chosen_by_learned_reward(draws)["draw_rule"] == "most"
    with pytest.raises(ValueError, match="no draw rule 'least'"):
        reward_check.kept_draws(rows, "least")


def test_one_draw_chosen_is_that_draw():
    draw = _draw(0, [0.3, 0.1], [0.123456789, 0.987654321])
    chosen = reward_check.chosen_by_learned_reward([draw])
    assert chosen["erd"] == draw["erd"]  # bit for bit: the same sum in the same order
    curve = lambda result: result["per_seed"][0]["erd_curve"]
    np.testing.assert_array_equal(curve(chosen), curve(draw))


def test_a_draw_read_back_from_its_file_is_chosen_as_the_draw_in_memory():
    """Iterations not scored are NaN in memory and null in the draw's file; a check that goes on
    from its files chooses as one that never stopped."""
    import json

    from emgail_jax.host import records

    draws = [_draw(0, [0.3, 0.1], [0.2, 0.4]), _draw(1, [0.1, 0.3], [0.3, 0.1])]
    for draw in draws:  # two iterations not scored before the final window's ten
        seed = draw["per_seed"][0]
        scored = np.tile(seed["erd_curve_per_intention"][-1], (10, 1))
        seed["erd_curve_per_intention"] = np.vstack([np.full((2, 2), np.nan), scored])
    read_back = [json.loads(records.json_text(records.to_json_value(d))) for d in draws]
    assert read_back[0]["per_seed"][0]["erd_curve_per_intention"][0] == [None, None]
    chosen, again = map(reward_check.chosen_by_learned_reward, (draws, read_back))
    assert again["erd"] == chosen["erd"] and np.isfinite(chosen["erd"]).all()
    curve = lambda result: result["per_seed"][0]["erd_curve"]
    np.testing.assert_array_equal(np.asarray(curve(again), float), curve(chosen))


def test_the_best_baseline_keeps_the_highest_true_return_per_intention():
    draws = [_draw(r, [0, 0], erd)["per_seed"][0] for r, erd in ((0, [0.1, 0.6]), (1, [0.4, 0.2]))]
    baselines = [{**d, "cache": f"draw{r}.json"} for r, d in enumerate(draws)]
    best = reward_check.best_baseline(baselines)
    assert best["draw"] == [0, 1] and best["meets_bar"] == [False, True]
    np.testing.assert_allclose(best["erd_per_intention"], [0.1, 0.2])
    np.testing.assert_allclose(best["draws_erd_per_intention"], [[0.1, 0.6], [0.4, 0.2]])
    assert best["cache"] == ["draw0.json", "draw1.json"]


def test_checks_of_one_seed_each_join_into_the_check_of_both():
    """Joining seed by seed, then choosing per seed among the draws, is choosing in each
    seed's own check: the seeds' draws do not interact."""
    seed_0 = [_draw(0, [0.5, -1.0], [0.9, 0.2]), _draw(1, [0.1, 0.2], [0.3, 0.8])]
    seed_1 = [_draw(r, [0.2, 0.1], [0.1 + r, 0.4], (0, 1), run_seed=1) for r in (0, 1)]
    joined = [reward_check.joined_seeds(list(parts)) for parts in zip(seed_0, seed_1, strict=True)]
    assert joined[0]["seeds"] == [0, 1] and joined[1]["rl_seed"] == 1
    assert joined[0]["erd"] == [*seed_0[0]["erd"], *seed_1[0]["erd"]]
    assert joined[0]["train_time_s"] == 4.0
    chosen = reward_check.chosen_by_learned_reward(joined)
    alone = [reward_check.chosen_by_learned_reward(draws) for draws in (seed_0, seed_1)]
    from emgail_jax.host.records import to_json_value

    assert to_json_value(chosen["per_seed"]) == to_json_value([a["per_seed"][0] for a in alone])
    assert np.isclose(chosen["erd_mean"], np.mean([a["erd"][0] for a in alone]))
    with pytest.raises(ValueError, match="differ in rl_seed"):
        reward_check.joined_seeds([seed_0[0], seed_1[1]])
