"""python -m emgail_jax.reoptimize on a tiny run: every seed, the true-reward baseline (cached),
one matching, the success measures, snapshots, --refit's recipe and the --set settings."""

import dataclasses
import json

import numpy as np
import pytest

from emgail_jax import reoptimize
from emgail_jax.method.metrics import reward_difference
from emgail_jax.reward import check, draws, recipe
from emgail_jax.reward import saved as store
from emgail_jax.reward.refit import Refit

pytestmark = pytest.mark.heavy


@pytest.fixture(scope="module")
def reoptimized(tiny_run, tmp_path_factory):
    cache = tmp_path_factory.mktemp("baselines")
    assert reoptimize.main([str(tiny_run), "--iterations", "2", "--cache", str(cache)]) == 0
    return json.loads((tiny_run / "reoptimize-it-2.json").read_text()), cache


@pytest.fixture(scope="module")
def saved(tiny_run):
    from emgail_jax.host.saved_run import SavedRun

    return SavedRun.open(str(tiny_run))


def test_every_seed_is_reoptimised_beside_the_true_reward(reoptimized, capsys):
    result, cache = reoptimized
    assert result["seeds"] == [0, 1] and len(result["erd"]) == 2
    assert result["budget"] == {
        "iterations": 2,
        "gamma": 0.995,
        "gae_lambda": 0.97,
        "value_target_scaling": False,
    }
    assert result["eval_episodes"] == 2  # the tiny run's num_envs, as training evaluates
    assert result["absorbing_state"] is False  # an episode's end is worth 0
    assert result["reward"] == {"source": "paper"}  # the run saved no reward: its own
    assert np.isclose(result["erd_mean"], np.mean(result["erd"]))
    for seed, per_seed in enumerate(result["per_seed"]):
        assert per_seed["run_seed"] == seed and per_seed["erd"] == result["erd"][seed]
        assert len(per_seed["erd_curve"]) == 2 and len(per_seed["success"]) == 2
        assert [q["intention"] for q in per_seed["success"]] == ["path1", "path2"]
        earned = per_seed["learned_reward_per_step"]
        assert np.all(np.isfinite(earned["fresh_policies"]))
    baseline = result["baseline"]
    assert baseline["matching"] == [0, 1] and len(baseline["erd_curve"]) == 2
    assert baseline["cache"].startswith(str(cache)) and baseline["cache"].endswith(".json")


def test_the_headline_is_every_seed_x_draw_with_the_baseline_and_doing_nothing_beside(
    reoptimized,
):
    """One draw of 2 seeds: the mean and sample sd of their ERDs first; the baseline's one draw
    is its lowest; the driver has no bars (no success share) and a centred action box (one
    do-nothing row, zero actions)."""
    result, _ = reoptimized
    assert result["erd_draws_n"] == 2
    assert result["erd_draws_mean"] == pytest.approx(np.mean(result["erd"]))
    assert result["erd_draws_std"] == pytest.approx(np.std(result["erd"], ddof=1))
    assert result["success_rate"] is None and result["final_distance"] is None
    baseline = result["baseline"]
    assert baseline["draws_erd"] == [baseline["erd"]] and baseline["lowest_erd_draw"] == 0
    assert [row["actions"] for row in result["do_nothing"]] == ["zero"]
    assert result["do_nothing"][0]["erd"] > 0
    lines = reoptimize._headline_lines(result)
    assert lines[0].startswith("re-optimised ERD, mean of every seed x draw: ")
    assert "(sample sd, n = 2)" in lines[0] and lines[-1].startswith("doing nothing (zero")


def test_one_matching_scores_every_number(reoptimized, saved):
    result, _ = reoptimized
    expert, random = np.asarray(result["expert_returns"]), np.asarray(result["random_returns"])
    for seed, per_seed in enumerate(result["per_seed"]):
        matching = per_seed["matching"]
        np.testing.assert_array_equal(matching, saved.history["eval/matching"][seed, -1])
        e = reward_difference(np.asarray(per_seed["returns"]), expert, random)
        # The final ERD averages the last iterations' ERDs under that matching (here both).
        assert np.isclose(np.mean(per_seed["erd_curve"]), per_seed["erd"])
        assert np.allclose(np.asarray(per_seed["erd_per_intention"]), e, rtol=1e-5)


def test_the_baseline_is_read_from_the_cache_the_second_time(tiny_run, reoptimized):
    """A second reoptimize reads the true-reward baseline the first stored: with its bars
    flipped in the cache file, the flipped bars come back (the same baseline trained again,
    from the same keys, would give the first run's)."""
    first, cache = reoptimized
    path = first["baseline"]["cache"]
    with open(path) as f:
        stored = json.load(f)
    marked = {
        **stored,
        "success": [{**q, "meets_bar": not q["meets_bar"]} for q in stored["success"]],
    }
    with open(path, "w") as f:
        json.dump(marked, f)
    out = tiny_run / "again.json"
    args = [str(tiny_run), "--iterations", "2", "--cache", str(cache), "--out", str(out)]
    try:
        assert reoptimize.main([*args, "--quiet"]) == 0
    finally:
        with open(path, "w") as f:
            json.dump(stored, f)
    again = json.loads(out.read_text())
    flipped = [not met for met in first["baseline"]["meets_bar"]]
    assert again["baseline"]["meets_bar"] == flipped
    assert again["baseline"]["erd_curve"] == first["baseline"]["erd_curve"]
    assert again["erd"] == first["erd"]  # the same keys: the same fresh policies


@pytest.mark.slow  # end to end (make test-slow); cheaper tests cover its parts
def test_checks_of_one_seed_each_merge_into_the_check_of_every_seed(
    tiny_run, reoptimized, tmp_path, capsys
):
    """One seed per process (on other cores or machines), then --merge: the check of both
    seeds, as the check trained together gives it, with the cached baseline beside it."""
    whole, cache = reoptimized
    options = ["--iterations", "2", "--draws", "2", "--quiet"]
    parts = [str(tmp_path / f"seed-{seed}.json") for seed in (1, 0)]
    for seed, part in zip((1, 0), parts, strict=True):
        args = [str(tiny_run), *options, "--seed", str(seed), "--no-baseline", "--out", part]
        assert reoptimize.main(args) == 0
    out = tmp_path / "merged.json"
    merge = [str(tiny_run), *options, "--cache", str(cache), "--out", str(out), "--merge"]
    assert reoptimize.main([*merge, *parts]) == 0
    merged = json.loads(out.read_text())
    assert merged["seeds"] == [0, 1] and merged["rl_seeds"] == [0, 1]
    first = merged["draws"][0]  # draw 0 is the plain check of both seeds
    assert first["seeds"] == [0, 1]
    np.testing.assert_allclose(first["erd"], whole["erd"], rtol=1e-4)
    from emgail_jax.host.records import to_json_value

    again = to_json_value(draws.chosen_by_learned_reward(merged["draws"]))
    assert {name: merged[name] for name in again} == again
    # The rule that keeps a draw trains nothing: the same parts merge under the other rule.
    nearest = tmp_path / "nearest.json"
    merge_nearest = [*merge[:-2], str(nearest), "--keep-draw", "nearest", "--merge", *parts]
    assert reoptimize.main(merge_nearest) == 0
    kept = json.loads(nearest.read_text())
    again = to_json_value(draws.chosen_by_learned_reward(merged["draws"], "nearest"))
    assert kept["draw_rule"] == "nearest" and {name: kept[name] for name in again} == again
    assert merged["baseline"]["cache"] and merged["check"]["options"]["seed"] is None
    # The same seed twice, a part checked with other options, or of every seed, is refused.
    refused = [
        ([*merge, parts[0], parts[0]], "seed 1 is checked twice"),
        ([*merge[:-1], "--iterations", "3", "--merge", *parts], "otherwise (--iterations)"),
        ([*merge[:-1], "--draws", "1", "--merge", *parts], "give the --draws and --rl-seed"),
        ([*merge, str(out)], "is no check of one seed"),
    ]
    capsys.readouterr()
    for args, message in refused:
        assert reoptimize.main(args) == 2
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1


@pytest.mark.slow  # a tiny GAIL run and its re-optimisation: two compiles
def test_gails_one_reward_is_reoptimised_like_emgails(tmp_path):
    """GAIL's run is checked on its one reward: every learned intention earns the same on the
    demonstrations, and the baseline is the one an EM-GAIL run of the env and K would read."""
    from emgail_jax import run

    out, cache = tmp_path / "gail", tmp_path / "cache"
    tiny = ["--seeds", "2", "--iterations", "4", "--num-envs", "2", "--rollout-length", "20"]
    args = ["--env", "driver", "--algo", "gail", *tiny, "--chunk-size", "2", "--quiet"]
    assert run.main([*args, "--out", str(out)]) == 0
    assert reoptimize.main([str(out), "--iterations", "2", "--cache", str(cache), "--quiet"]) == 0
    result = json.loads((out / "reoptimize-it-2.json").read_text())
    assert result["seeds"] == [0, 1] and len(result["erd"]) == 2
    for per_seed in result["per_seed"]:
        earned = per_seed["learned_reward_per_step"]["demonstrations"]
        assert len(earned) == 2 and earned[0] == pytest.approx(earned[1])
    assert result["baseline"]["cache"].split("/")[-1].startswith("driver-k2-2it-g0.995-")


@pytest.mark.slow  # a tiny run with absorbing states and two re-optimisations: three compiles
def test_a_run_with_absorbing_states_is_reoptimised_with_them(tmp_path):
    """The fresh agents are paid the learned reward of the absorbing state the run's own
    B-step was (the one its last iteration logged)."""
    from emgail_jax import run
    from emgail_jax.host.saved_run import SavedRun

    out = tmp_path / "absorbing"
    tiny = ["--seeds", "2", "--iterations", "4", "--num-envs", "2", "--rollout-length", "20"]
    args = ["--env", "driver", *tiny, "--chunk-size", "2", "--snapshot-every", "2", "--quiet"]
    assert run.main([*args, "--set", "absorbing_state=true", "--out", str(out)]) == 0
    saved = SavedRun.open(str(out))
    absorbing = saved.absorbing_reward_function()
    for seed in (0, 1):
        every = [absorbing(saved.reward_parameters(seed), i) for i in range(2)]
        logged = saved.history["train/absorbing_reward"][seed, -1]
        assert float(np.mean(every)) == pytest.approx(float(logged), rel=1e-5)
    again = [str(out), "--iterations", "2", "--no-baseline", "--quiet"]
    assert reoptimize.main([*again, "--out", str(tmp_path / "r.json")]) == 0
    result = json.loads((tmp_path / "r.json").read_text())
    assert result["absorbing_state"] is True and len(result["erd"]) == 2


def test_a_snapshot_is_reoptimised_on_its_own_networks(tiny_run, reoptimized):
    first, _ = reoptimized
    args = [str(tiny_run), "--iterations", "2", "--snapshot", "2", "--no-baseline", "--quiet"]
    assert reoptimize.main(args) == 0
    result = json.loads((tiny_run / "reoptimize-it-2-snapshot-2.json").read_text())
    assert result["snapshot"] == 2 and result["iteration"] == 2 and result["baseline"] is None
    earned = [r["learned_reward_per_step"]["demonstrations"] for r in result["per_seed"]]
    final = [r["learned_reward_per_step"]["demonstrations"] for r in first["per_seed"]]
    assert earned != final  # another discriminator


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--snapshot", "3"], "no snapshot of iteration 3"),
        (["--seed", "5"], "the run has seeds 0..1"),
        (["--iterations", "0"], "--iterations must be at least 1"),
        (["--rl-seed", "-1"], "--rl-seed must be 0 or more"),
        (["--set", "consolidate_fresh=true"], "--set consolidate_fresh goes with a refit"),
        (["--set", "consolidate_noise=1"], "--set consolidate_noise goes with a refit"),
        (["--set", "consolidate_batch=100"], "--set consolidate_batch goes with a refit"),
        (
            ["--set", "consolidate=5", "--set", "consolidate_ranking_random=true"],
            "consolidate_ranking_random goes with consolidate_ranking=WEIGHT",
        ),
        (
            ["--set", "consolidate=5", "--set", "consolidate_ranking_still=true"],
            "consolidate_ranking_still goes with consolidate_ranking=WEIGHT",
        ),
        (["--set", "consolidate_absorbing=true"], "--set consolidate_absorbing goes with a refit"),
        (
            ["--set", "consolidate=5", "--set", "consolidate_absorbing=true"],
            "consolidate_absorbing needs consolidate_fresh=true",
        ),
        (
            ["--set", "across_seeds=true", "--set", "consolidate=5"],
            "across_seeds averages the run's own rewards: not with a refit",
        ),
        (["--env-set", "gravity=2"], "--env-set: env 'driver' has no option 'dynamics'"),
        (["--env-set", "gravity=2", "--no-baseline"], "drop --no-baseline"),
        (["--draws", "0"], "--draws must be at least 1"),
        (["--keep-draw", "nearest"], "--keep-draw chooses among draws: give --draws N"),
        (["--merge", "a.json", "--seed", "0"], "--merge joins checks of one seed each: drop"),
        (["--merge", "missing.json"], "--merge: cannot read 'missing.json'"),
        (["--set", "reward=saved"], "has no refitted reward: python -m emgail_jax.refit"),
        (["--refit", "--set", "reward=paper"], "--set reward=paper checks a reward made before"),
        (["--set", "absorbing_reward=random"], "absorbing_reward prices an absorbing state, and"),
        (
            ["--set", "absorbing_reward=random", "--set", "across_seeds=true"],
            "absorbing_reward=random prices one seed's reward: not with across_seeds",
        ),
    ],
)
def test_bad_input_gives_one_line_and_exit_code_2(tiny_run, capsys, extra, message):
    assert reoptimize.main([str(tiny_run), *extra]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and message in err and err.count("\n") == 1


def test_a_directory_without_a_run(tmp_path, capsys):
    assert reoptimize.main([str(tmp_path)]) == 2
    assert "no summary.json" in capsys.readouterr().err


@pytest.mark.slow  # a second re-optimisation (the plain one runs always)
def test_another_rl_seed_trains_other_fresh_agents_on_the_same_rewards(tiny_run, reoptimized):
    first, _ = reoptimized
    args = [str(tiny_run), "--iterations", "2", "--rl-seed", "1", "--no-baseline", "--quiet"]
    assert reoptimize.main(args) == 0
    result = json.loads((tiny_run / "reoptimize-rl-1-it-2.json").read_text())
    assert result["rl_seed"] == 1 and first["rl_seed"] == 0
    earned = lambda r: [s["learned_reward_per_step"] for s in r["per_seed"]]
    # The same rewards on the same demonstrations; other agents earn other amounts.
    for mine, theirs in zip(earned(result), earned(first), strict=True):
        assert mine["demonstrations"] == theirs["demonstrations"]
        assert mine["fresh_policies"] != theirs["fresh_policies"]


@pytest.mark.slow  # a re-optimisation across seeds (the plain one runs always)
def test_a_reward_across_seeds_is_reoptimised(tiny_run, reoptimized, saved):
    first, _ = reoptimized
    args = [str(tiny_run), "--iterations", "2", "--set", "across_seeds=true", "--no-baseline"]
    args.append("--quiet")
    assert reoptimize.main(args) == 0
    result = json.loads((tiny_run / "reoptimize-it-2-across-seeds.json").read_text())
    assert result["across_seeds"] == [saved.aligned_intentions(s).tolist() for s in (0, 1)]
    earned = [r["learned_reward_per_step"]["demonstrations"] for r in result["per_seed"]]
    assert earned != [r["learned_reward_per_step"]["demonstrations"] for r in first["per_seed"]]


@pytest.mark.slow  # consolidation, then a fresh re-optimisation (the plain one runs always)
def test_a_consolidated_reward_in_the_logit_form(tiny_run, reoptimized):
    first, _ = reoptimized
    args = [str(tiny_run), "--iterations", "2", "--set", "consolidate=5"]
    args += ["--set", "reward_form=logit"]
    assert reoptimize.main([*args, "--no-baseline", "--quiet"]) == 0
    result = json.loads((tiny_run / "reoptimize-it-2-consolidated-5-logit.json").read_text())
    assert result["reward_form"] == "logit" and first["reward_form"] == "gail"
    assert [c["run_seed"] for c in result["consolidation"]] == [0, 1]
    assert all(c["steps"] == 5 for c in result["consolidation"])
    assert all(c["seconds"] > 0 for c in result["consolidation"])  # the sweep's estimate
    earned = result["per_seed"][0]["learned_reward_per_step"]["demonstrations"]
    assert earned != first["per_seed"][0]["learned_reward_per_step"]["demonstrations"]
    assert result["saved_reward"] == "consolidated-5"  # whatever form reads it
    saved = sorted(p.name for p in (tiny_run / "rewards" / "consolidated-5").iterdir())
    seeds = ["seed-0.json", "seed-0.msgpack", "seed-1.json", "seed-1.msgpack"]
    assert saved == ["reward.json", *seeds]


@pytest.mark.slow  # a tiny swimmer run and its re-optimisation in a variant: two compiles
def test_a_variant_is_scored_against_its_own_true_reward_agent(tmp_path):
    from emgail_jax import run

    out, cache = tmp_path / "swimmer", tmp_path / "cache"
    tiny = ["--seeds", "1", "--iterations", "2", "--num-envs", "2", "--rollout-length", "20"]
    options = [*tiny, "--eval-every", "1", "--random-episodes", "2", "--quiet"]
    assert run.main(["--env", "swimmer", "--intentions", "2", *options, "--out", str(out)]) == 0
    args = [str(out), "--iterations", "2", "--cache", str(cache), "--quiet"]
    variant = ["--env-set", "viscosity=2", "mass.mid=1.5", "--set", "reference_draws=2"]
    assert reoptimize.main([*args, *variant]) == 0
    result = json.loads((out / "reoptimize-it-2-env-viscosity=2-mass.mid=1.5.json").read_text())
    assert result["variant"]["dynamics"] == ["viscosity=2", "mass.mid=1.5"]
    baseline = result["baseline"]
    # The variant's expert is, per intention, the best of its two true-reward draws (RL seeds
    # 0 and 1), the returns ERD is measured from; the baseline beside it is draw 0.
    draws = np.asarray(result["variant"]["reference_returns"])
    assert draws.shape == (2, 2) and draws[0] == pytest.approx(baseline["returns"])
    assert result["expert_returns"] == pytest.approx(draws.max(0))
    assert result["variant"]["reference_draw"] == list(draws.argmax(0))
    assert len(result["variant"]["original_experts_erd"]) == 2
    assert baseline["cache"].endswith(".json") and "swimmer-k2-2it" in baseline["cache"]
    assert len(list(cache.glob("*.json"))) == 2  # both draws cached
    assert len(result["variant"]["reference_meets_bar"]) == 2
    # Beside it, the run's own policies deployed unchanged in the variant.
    joint = result["variant"]["joint_policies"]
    assert [r["run_seed"] for r in joint["per_seed"]] == [0] and np.isfinite(joint["erd"][0])
    assert joint["erd_mean"] == pytest.approx(joint["erd"][0])
    assert reoptimize.main(args) == 0  # the env as trained: another baseline, other references
    plain = json.loads((out / "reoptimize-it-2.json").read_text())
    assert plain["variant"] is None and plain["baseline"]["cache"] != baseline["cache"]
    assert plain["random_returns"] != pytest.approx(result["random_returns"])


def test_the_default_file_names_what_was_checked():
    args = reoptimize.parse_args(["RUN"])
    assert reoptimize.default_name(args) == "reoptimize.json"
    args = reoptimize.parse_args(
        ["RUN", "--seed", "1", "--set", "reward_form=log-d", "--snapshot", "20"]
    )
    assert reoptimize.default_name(args) == "reoptimize-seed-1-snapshot-20-log-d.json"
    args = reoptimize.parse_args(["RUN", "--rl-seed", "2"])
    assert reoptimize.default_name(args) == "reoptimize-rl-2.json"
    args = reoptimize.parse_args(["RUN", "--rl-seed", "2", "--draws", "3"])
    assert reoptimize.default_name(args) == "reoptimize-rl-2-draws-3.json"
    args = reoptimize.parse_args(["RUN", "--draws", "3", "--keep-draw", "nearest"])
    assert reoptimize.default_name(args) == "reoptimize-draws-3-keep-nearest.json"
    args = reoptimize.parse_args(["RUN", "--iterations", "1000", "--set", "gamma=0.999"])
    assert reoptimize.default_name(args) == "reoptimize-it-1000-gamma-0.999.json"
    args = reoptimize.parse_args(["RUN", "--set", "gae_lambda=0.995"])
    assert reoptimize.default_name(args) == "reoptimize-lambda-0.995.json"
    args = reoptimize.parse_args(["RUN", "--set", "value_target_scaling=true"])
    assert reoptimize.default_name(args) == "reoptimize-scaled-values.json"
    args = reoptimize.parse_args(["RUN", "--set", "value_target_scaling=false"])
    assert reoptimize.default_name(args) == "reoptimize-no-scaled-values.json"
    args = reoptimize.parse_args(["RUN", "--set", "across_seeds=true", "--rl-seed", "1"])
    assert reoptimize.default_name(args) == "reoptimize-rl-1-across-seeds.json"
    refit = [
        "--set",
        "consolidate=4000",
        "--set",
        "consolidate_penalty=10",
        "--set",
        "consolidate_fresh=true",
    ]
    args = reoptimize.parse_args(["RUN", *refit, "--set", "consolidate_noise=1"])
    assert reoptimize.default_name(args) == (
        "reoptimize-consolidated-4000-penalty-10-fresh-noise-1.json"
    )
    assert recipe.refit_of(args) == Refit(4000, gradient_penalty=10, fresh=True, support_noise=1)
    args = reoptimize.parse_args(["RUN", *refit, "--set", "consolidate_batch=2500"])
    name = "reoptimize-consolidated-4000-penalty-10-fresh-batch-2500.json"
    assert reoptimize.default_name(args) == name and recipe.refit_of(args).batch == 2500
    ranked = ["--set", "consolidate_ranking=10", "--set", "consolidate_ranking_random=true"]
    args = reoptimize.parse_args(["RUN", *refit, *ranked])
    name = "reoptimize-consolidated-4000-penalty-10-fresh-ranking-10-random.json"
    assert reoptimize.default_name(args) == name
    assert recipe.refit_of(args) == Refit(
        4000, gradient_penalty=10, fresh=True, ranking=10, ranking_random=True
    )
    args = reoptimize.parse_args(
        ["RUN", *refit, *ranked, "--set", "consolidate_ranking_still=true"]
    )
    name = "reoptimize-consolidated-4000-penalty-10-fresh-ranking-10-random-still.json"
    assert reoptimize.default_name(args) == name
    assert recipe.refit_of(args) == Refit(
        4000, gradient_penalty=10, fresh=True, ranking=10, ranking_random=True, ranking_still=True
    )
    # The saved refit is named by the refit alone: any reward form reads the same one.
    args = reoptimize.parse_args(["RUN", *refit, "--set", "reward_form=log-d", "--snapshot", "20"])
    assert recipe.refit_parts(args) == [
        "snapshot-20",
        *("consolidated-4000", "penalty-10", "fresh"),
    ]


def test_refit_is_the_measured_recipe_and_any_option_given_replaces_its_own():
    written = ["--set", "consolidate=4000", "--set", "consolidate_fresh=true"]
    written += ["--set", "consolidate_penalty=10", "--set", "consolidate_noise=1"]
    written += ["--set", "consolidate_batch=5000"]
    spelled, preset = (
        reoptimize.parse_args(["RUN", *written]),
        reoptimize.parse_args(["RUN", "--refit"]),
    )
    assert recipe.refit_of(preset) == recipe.refit_of(spelled)
    # So it reads (and saves) the same refit as the spelled-out command.
    assert recipe.refit_parts(preset) == recipe.refit_parts(spelled)
    changed = reoptimize.parse_args(["RUN", "--refit", "--set", "consolidate_penalty=3"])
    assert recipe.refit_of(changed) == dataclasses.replace(
        recipe.refit_of(spelled), gradient_penalty=3
    )
    # Without it nothing is refitted, as before the option.
    assert recipe.refit_of(reoptimize.parse_args(["RUN"])) == Refit(0)


def test_refit_adds_the_envs_own_recipe_and_any_option_given_replaces_its_part():
    driver = reoptimize.parse_args(["RUN", "--refit"], env="driver")
    assert driver == reoptimize.parse_args(["RUN", "--refit"])  # the common recipe alone
    hopper = reoptimize.parse_args(["RUN", "--refit"], env="hopper")
    assert recipe.refit_of(hopper) == dataclasses.replace(
        recipe.refit_of(driver), ranking=10, absorbing=True
    )
    assert hopper.reward_form == "logit" and hopper.absorbing_reward == "random"
    # Named as the spelled-out command, so the refit it saves is the one that command reads.
    spelled = [
        "--set",
        "consolidate_ranking=10",
        "--set",
        "consolidate_absorbing=true",
        "--set",
        "reward_form=logit",
    ]
    spelled += ["--set", "absorbing_reward=random"]
    assert reoptimize.default_name(hopper) == reoptimize.default_name(
        reoptimize.parse_args(["RUN", "--refit", *spelled])
    )
    cheetah = reoptimize.parse_args(["RUN", "--refit"], env="halfcheetah")
    assert (cheetah.consolidate_ranking, cheetah.consolidate_absorbing) == (30, False)
    # The budget is the env's declaration, not the recipe's: the refit leaves it unset.
    assert cheetah.reward_form == "logit" and cheetah.iterations is None
    assert cheetah.value_target_scaling is None
    shorter = reoptimize.parse_args(["RUN", "--refit", "--iterations", "400"], env="halfcheetah")
    assert shorter.iterations == 400 and shorter.consolidate_ranking == 30
    raw = ["RUN", "--refit", "--set", "value_target_scaling=false"]
    assert reoptimize.parse_args(raw, env="halfcheetah").value_target_scaling is False
    # Each part of the env's recipe can be replaced or turned off alone.
    options = [
        "--set",
        "consolidate_ranking=0",
        "--set",
        "consolidate_absorbing=false",
        "--set",
        "reward_form=log-d",
    ]
    plain = reoptimize.parse_args(["RUN", "--refit", *options], env="hopper")
    assert recipe.refit_of(plain) == recipe.refit_of(driver)
    assert plain.reward_form == "log-d" and plain.absorbing_reward is None
    learned = reoptimize.parse_args(
        ["RUN", "--refit", "--set", "absorbing_reward=learned"], "hopper"
    )
    assert learned.absorbing_reward == "learned" and "absorbing-random" not in (
        reoptimize.reward_parts(learned)
    )
    assert recipe.refit_of(learned) == recipe.refit_of(hopper)
    # Without --refit the env adds nothing.
    assert recipe.refit_of(reoptimize.parse_args(["RUN"], env="hopper")) == Refit(0)
    assert reoptimize.parse_args(["RUN"], env="hopper").reward_form is None
    assert reoptimize.parse_args(["RUN"], env="hopper").absorbing_reward is None
    assert recipe.refit_extras("hopper") == (
        "consolidate_ranking=10 consolidate_absorbing=true reward_form=logit "
        "absorbing_reward=random"
    )
    assert recipe.refit_extras("halfcheetah") == ("consolidate_ranking=30 reward_form=logit")
    assert recipe.refit_extras("reacher") == ""


def test_refit_reads_log_d_unless_episodes_end_early():
    form = recipe.refit_reward_form
    assert form(reoptimize.parse_args(["RUN", "--refit"]), terminates=False) == "log-d"
    assert form(reoptimize.parse_args(["RUN", "--refit"]), terminates=True) is None
    given = reoptimize.parse_args(["RUN", "--refit", "--set", "reward_form=logit"])
    assert form(given, terminates=False) == "logit"
    # With an absorbing state a fall is priced, so log D no longer pays for it.
    absorbing = reoptimize.parse_args(["RUN", "--refit", "--set", "consolidate_absorbing=true"])
    assert form(absorbing, terminates=True) == "log-d"
    assert form(reoptimize.parse_args(["RUN"]), terminates=False) is None


def test_refit_names_its_check_as_the_spelled_out_command(tiny_run, monkeypatch):
    """The driver's episodes never end early: ``--refit`` is read as log D, and its check is
    written under the same name as the options spelled out."""
    captured = {}
    monkeypatch.setattr(
        reoptimize, "_reoptimized", lambda args, *opened: captured.update(args=args) or 0
    )
    monkeypatch.setattr(store, "saved_or_refitted", lambda *a, **k: (None, []))
    assert reoptimize.main([str(tiny_run), "--refit"]) == 0
    name = "reoptimize-consolidated-4000-penalty-10-fresh-noise-1-batch-5000-log-d.json"
    assert reoptimize.default_name(captured["args"]) == name


def test_refit_takes_the_recipe_of_the_runs_env(tiny_run, tmp_path, monkeypatch):
    """``main`` reads the env from the run's summary before it fills in ``--refit``."""
    import shutil

    copy = tmp_path / "run"
    shutil.copytree(tiny_run, copy)
    summary = json.loads((copy / "summary.json").read_text())
    seen = []

    class Opened(Exception):
        """Stops ``main`` once it has resolved its options."""

    def opened(args):
        seen.append(args)
        raise Opened

    monkeypatch.setattr(reoptimize, "_opened", opened)
    for env in ("hopper", "driver"):
        (copy / "summary.json").write_text(json.dumps({**summary, "env": env}))
        with pytest.raises(Opened):
            reoptimize.main([str(copy), "--refit"])
    assert [args.consolidate_ranking for args in seen] == [10, 0]
    assert [args.reward_form for args in seen] == ["logit", None]


@pytest.mark.slow  # end to end (make test-slow); cheaper tests cover its parts
def test_an_absorbing_refit_is_named_so_and_prices_the_fresh_agents_falls(tiny_run, tmp_path):
    import shutil

    copy = tmp_path / "run"
    shutil.copytree(tiny_run, copy, ignore=shutil.ignore_patterns("rewards"))
    options = ["--set", "consolidate=3", "--set", "consolidate_fresh=true"]
    options += ["--set", "consolidate_absorbing=true"]
    args = reoptimize.parse_args([str(copy), *options])
    assert recipe.refit_parts(args) == ["consolidated-3", "fresh", "absorbing"]
    assert recipe.refit_of(args) == Refit(steps=3, fresh=True, absorbing=True)
    _, run, _, chosen = reoptimize._opened(args)
    # The fresh agents read the refit's network, and their falls its absorbing state's reward.
    assert run.networks.discriminator.absorbing
    absorbing = run.absorbing_reward_function()
    assert np.isfinite(float(absorbing(chosen.parameters[0], 0)))
    pairs = run.demonstration_pairs
    assert run.reward_function()(
        chosen.parameters[0], pairs.observations[:5], pairs.actions[:5], 0
    ).shape == (5,)
    plain = reoptimize.parse_args(
        [str(copy), "--set", "consolidate=3", "--set", "consolidate_fresh=true"]
    )
    assert reoptimize._opened(plain)[1].absorbing_reward_function() is None


@pytest.mark.slow  # end to end (make test-slow); cheaper tests cover its parts
def test_absorbing_reward_random_pays_a_fall_what_random_actions_earn(tiny_run, tmp_path):
    import shutil

    import jax
    import jax.numpy as jnp

    from emgail_jax.reward.refit import random_actions_reward

    copy = tmp_path / "run"
    shutil.copytree(tiny_run, copy, ignore=shutil.ignore_patterns("rewards"))
    refit = ["--set", "consolidate=3", "--set", "consolidate_fresh=true"]
    refit += ["--set", "consolidate_absorbing=true"]
    args = reoptimize.parse_args([str(copy), *refit, "--set", "absorbing_reward=random"])
    assert reoptimize.reward_parts(args)[-1] == "absorbing-random"
    _, run, seeds, chosen = reoptimize._opened(args)
    _, _, _, learned = reoptimize._opened(reoptimize.parse_args([str(copy), *refit]))
    reward = run.reward_function()
    for seed in seeds:
        priced, own = chosen.parameters[seed], learned.parameters[seed]
        # The same refit (read back from disk), its absorbing state priced anew.
        equal = jax.tree.map(np.array_equal, priced["discriminator"], own["discriminator"])
        assert all(jax.tree.leaves(equal))
        expected = random_actions_reward(run, own, reward)
        np.testing.assert_array_equal(priced["absorbing_price"], expected)
        for intention in range(2):
            assert float(chosen.absorbing(priced, jnp.int32(intention))) == expected[intention]
        details = chosen.details["absorbing_price"][seed]
        np.testing.assert_array_equal(details["random_actions"], expected)
        learned_value = run.absorbing_reward_function()(own, jnp.arange(2))
        np.testing.assert_allclose(details["learned"], learned_value)
        assert not np.allclose(expected, learned_value)


@pytest.mark.slow  # a re-optimisation with a refit
def test_a_check_at_random_actions_price_records_both_prices(tiny_run, tmp_path, capsys):
    import shutil

    copy = tmp_path / "run"
    shutil.copytree(tiny_run, copy, ignore=shutil.ignore_patterns("rewards"))
    refit = ["--set", "consolidate=3", "--set", "consolidate_fresh=true"]
    refit += ["--set", "consolidate_absorbing=true"]
    command = [str(copy), *refit, "--set", "absorbing_reward=random", "--iterations", "2"]
    assert reoptimize.main([*command, "--seed", "1", "--no-baseline"]) == 0
    name = "reoptimize-seed-1-it-2-consolidated-3-fresh-absorbing-absorbing-random.json"
    result = json.loads((copy / name).read_text())
    price = result["absorbing_price"][0]
    assert len(price["random_actions"]) == len(price["learned"]) == 2
    assert (
        np.all(np.isfinite(price["random_actions"])) and price["random_actions"] != price["learned"]
    )
    assert "seed 1: a fall paid per step left" in capsys.readouterr().out


@pytest.mark.slow  # three re-optimisations (the plain one runs always)
def test_draws_are_trained_and_the_learned_reward_keeps_one_per_intention(tiny_run, reoptimized):
    _, cache = reoptimized
    args = [str(tiny_run), "--iterations", "2", "--draws", "2", "--cache", str(cache)]
    assert reoptimize.main([*args, "--quiet"]) == 0
    result = json.loads((tiny_run / "reoptimize-draws-2-it-2.json").read_text())
    assert result["rl_seeds"] == [0, 1] and [d["rl_seed"] for d in result["draws"]] == [0, 1]
    assert result["draws"][0]["erd"] == reoptimized[0]["erd"]  # draw 0 is the plain check
    again = draws.chosen_by_learned_reward(result["draws"])
    assert again["erd"] == result["erd"]
    assert len(result["baseline"]["draw"]) == 2 and len(result["baseline"]["cache"]) == 2


def test_a_check_of_several_draws_goes_on_from_its_last_finished_draw(
    tiny_run, reoptimized, tmp_path, monkeypatch
):
    """Each finished draw is kept beside the check's file: a check stopped part-way trains
    only the draws it had not finished, and one with other options trains them all."""
    one_draw, _ = reoptimized
    trained, stops = [], [2]

    class Stopped(Exception):
        pass

    def draw(run, seeds, budget, rl_seed=0, partial=None, **_):
        assert partial.path.endswith(f".draws/rl-{rl_seed}.partial.npz")
        partial.write(1, {"policy": np.zeros(2)}, np.zeros(1), np.zeros(1), 0.0)
        if rl_seed in stops:
            stops.remove(rl_seed)
            raise Stopped  # while training draw 2
        trained.append(rl_seed)
        return {**one_draw, "rl_seed": rl_seed, "train_time_s": float(rl_seed)}

    monkeypatch.setattr(check, "reoptimize", draw)
    out = tmp_path / "check.json"
    args = [str(tiny_run), "--iterations", "2", "--draws", "3", "--no-baseline", "--quiet"]
    with pytest.raises(Stopped):
        reoptimize.main([*args, "--out", str(out)])
    kept = tmp_path / "check.draws"
    expected = ["rl-0.json", "rl-1.json", "rl-2.partial.npz"]  # a finished draw's save goes
    assert sorted(p.name for p in kept.iterdir()) == expected
    assert not out.exists()
    trained.clear()
    assert reoptimize.main([*args, "--out", str(out)]) == 0
    assert trained == [2]  # draws 0 and 1 read back
    result = json.loads(out.read_text())
    assert [d["train_time_s"] for d in result["draws"]] == [0.0, 1.0, 2.0]
    assert result["rl_seeds"] == [0, 1, 2] and not kept.exists()
    # Read back or trained, a draw gives the same check.
    from emgail_jax.host.records import to_json_value

    again = to_json_value(draws.chosen_by_learned_reward(result["draws"]))
    assert {name: result[name] for name in again} == again
    # Draws kept for other options are trained again.
    kept.mkdir()
    (kept / "rl-0.json").write_text((tiny_run / "reoptimize-it-2.json").read_text())
    trained.clear()
    assert reoptimize.main([*args, "--iterations", "3", "--out", str(out)]) == 0
    assert trained == [0, 1, 2]


def test_a_check_not_given_scaling_keeps_the_identity_it_had_before_the_option():
    import types

    from emgail_jax import reoptimize

    run = types.SimpleNamespace(snapshot=None, iteration=4)
    identity = reoptimize.check_identity(reoptimize.parse_args(["RUN"]), run)
    assert "value_target_scaling" not in identity["options"]
    given = reoptimize.parse_args(["RUN", "--set", "value_target_scaling=false"])
    assert reoptimize.check_identity(given, run)["options"]["value_target_scaling"] is False


def test_a_check_records_the_options_it_depends_on_as_before():
    """Every option and setting a check's draws depend on, and the deleted ones at the one value
    they still have: a check stopped part-way before, or a part to merge, reads as before."""
    import types

    run = types.SimpleNamespace(snapshot=None, iteration=4)
    options = reoptimize.check_identity(reoptimize.parse_args(["RUN", "--refit"]), run)["options"]
    assert set(options) == {
        *reoptimize.IDENTITY_FLAGS,
        *recipe.CHECK_SETTINGS,
        "ensemble",
        "consolidate_agents",
        "consolidate_state_only",
    } - {"value_target_scaling", "reward"}  # a refit made here: no saved reward to name
    assert options["consolidate"] == 4000 and options["ensemble"] == 0


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--set", "colour=red"], "--set: unknown key 'colour'; the keys: consolidate, "),
        (["--set", "gamma"], "--set takes KEY=VALUE, e.g. gamma=...; got 'gamma'"),
        (["--set", "gamma=0"], "--set gamma=0: gamma takes a number in (0, 1]"),
        (["--set", "gae_lambda=1.5"], "gae_lambda takes a number in [0, 1]"),
        (["--set", "consolidate=-1"], "consolidate takes a number of steps >= 0"),
        (["--set", "consolidate_batch=2.5"], "consolidate_batch takes a number of samples >= 0"),
        (["--set", "consolidate_fresh=yes"], "consolidate_fresh takes true or false"),
        (["--set", "reward_form=sqrt"], "reward_form takes one of gail, "),
        (["--set", "reference_draws=0"], "reference_draws takes a number >= 1"),
        (["--set", "reward=mine"], "--set reward=mine: reward takes saved or paper"),
        (["--ensemble", "2"], "unrecognized arguments: --ensemble"),
        (["--consolidate-agents", "1"], "unrecognized arguments: --consolidate-agents"),
        (["--consolidate-state-only"], "unrecognized arguments: --consolidate-state-only"),
    ],
)
def test_a_setting_or_option_it_does_not_take_is_one_line_and_exit_code_2(
    tmp_path, capsys, extra, message
):
    """Refused before the run is read, as the parser refuses any other option."""
    with pytest.raises(SystemExit) as exited:
        reoptimize.main([str(tmp_path), *extra])
    assert exited.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and message in err and err.count("\n") == 1


def test_the_settings_are_typed_and_the_last_given_wins():
    args = reoptimize.parse_args(["RUN", "--set", "gamma=0.9", "--set", "gamma=0.99"])
    assert args.gamma == 0.99 and isinstance(args.gamma, float)
    args = reoptimize.parse_args(["RUN", "--set", "consolidate=5", "--set", "across_seeds=True"])
    assert args.consolidate == 5 and args.across_seeds is True


def test_help_lists_at_most_15_options(capsys):
    with pytest.raises(SystemExit):
        reoptimize.main(["--help"])
    options = [line for line in capsys.readouterr().out.split("\n") if line.startswith("  -")]
    assert len(options) <= 15
