"""The true-reward baseline's cache key: one baseline for every algorithm of an env, K and
budget, kept apart by RL seed, lambda and value target scaling."""

import dataclasses

import pytest

from emgail_jax.reward import baseline, check


@pytest.fixture(scope="module")
def saved(tiny_run):
    from emgail_jax.host.saved_run import SavedRun

    return SavedRun.open(str(tiny_run))


def test_one_true_reward_baseline_serves_every_algorithm(saved):
    """The baseline's cache key holds the env, K, budget and TRPO settings, not the algorithm
    whose reward is checked: the sweep's EM-GAIL, Info/IntentionGAIL and GAIL cells of an env
    and K share one baseline."""
    budget = check.Budget(iterations=400, gamma=0.995, gae_lambda=0.97)
    key = baseline.baseline_key(saved, budget)
    assert key.startswith("driver-k2-400it-g0.995-")
    for algo in ("gail", "infogail"):
        other = dataclasses.replace(saved, config=saved.config.with_values(algo=algo))
        assert other.config.method.algo == algo
        assert baseline.baseline_key(other, budget) == key
    wider = dataclasses.replace(saved, config=saved.config.with_values(num_envs=3))
    assert baseline.baseline_key(wider, budget) != key
    # The true reward has no absorbing state, whatever the run learned.
    absorbing = dataclasses.replace(saved, config=saved.config.with_values(absorbing_state=True))
    assert baseline.baseline_key(absorbing, budget) == key


def test_another_rl_seeds_baseline_is_kept_apart_from_the_sweeps(saved):
    budget = check.default_budget(saved)
    first = baseline.baseline_key(saved, budget)
    assert first.startswith(baseline.baseline_prefix("driver", 2, budget.iterations))
    assert baseline.baseline_key(saved, budget, rl_seed=1) == "rl1-" + first


def test_the_budgets_lambda_is_the_runs_unless_given_and_names_its_baseline(saved, monkeypatch):
    from emgail_jax import reoptimize
    from emgail_jax.method import rl

    budget = check.default_budget(saved)
    assert budget.gae_lambda == saved.config.method.b_step.gae_lambda
    args = reoptimize.parse_args(["RUN", "--set", "gae_lambda=0.995"])
    given = reoptimize.budget_of(args, saved)
    assert given == dataclasses.replace(budget, gae_lambda=0.995)
    assert baseline.baseline_key(saved, given) != baseline.baseline_key(saved, budget)
    monkeypatch.setattr(rl, "make_rl_train", lambda config, *rest: config)
    assert check.fresh_trainer(saved, given).b_step.gae_lambda == 0.995


def test_value_target_scaling_is_the_runs_unless_given_and_names_its_baseline(saved, monkeypatch):
    """Off (the run's), the baseline keeps the key it had before scaling was a setting: the
    key of a config without it."""
    from emgail_jax import reoptimize
    from emgail_jax.method import rl

    budget = check.default_budget(saved)
    assert budget.value_target_scaling is False
    args = reoptimize.parse_args(["RUN", "--set", "value_target_scaling=true"])
    scaled = reoptimize.budget_of(args, saved)
    assert scaled == dataclasses.replace(budget, value_target_scaling=True)
    assert baseline.baseline_key(saved, scaled) != baseline.baseline_key(saved, budget)
    fields = tuple(f for f in baseline.RL_FIELDS if f != "value_target_scaling")
    monkeypatch.setattr(baseline, "RL_FIELDS", fields)
    without_the_setting = baseline.baseline_key(saved, budget)
    monkeypatch.undo()
    assert baseline.baseline_key(saved, budget) == without_the_setting
    monkeypatch.setattr(rl, "make_rl_train", lambda config, *rest: config)
    assert check.fresh_trainer(saved, scaled).b_step.value_target_scaling is True
    assert check.fresh_trainer(saved, budget).b_step.value_target_scaling is False
