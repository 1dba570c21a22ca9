"""Smoke runs of the experiment scripts under experiments/ on tiny settings: they are not part
of the package, so nothing else would notice when one of them no longer runs."""

import importlib.util
import json
import pathlib
import re
import shutil
import sys

import numpy as np
import pytest

pytestmark = pytest.mark.heavy

EXPERIMENTS = pathlib.Path(__file__).resolve().parents[1] / "experiments"


def _load(name):
    spec = importlib.util.spec_from_file_location(name, EXPERIMENTS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look their module up while it executes
    spec.loader.exec_module(module)
    return module


@pytest.mark.slow  # a child process with a cold compilation cache: 60-100 s
def test_bench_measures_the_driver(capsys):
    """The benchmark's child process on the driver with few seeds and chunks: every number it
    reports is there and positive."""
    bench = _load("bench")
    assert bench.main(["--envs", "driver:2", "--seeds", "2", "--chunks", "1"]) == 0
    out = capsys.readouterr().out
    for line in ("== driver-2", "2 seed(s):", "E-step", "M-step", "B-step", "evaluation",
                 "compile (2 seeds", "warm cache", "init alone",
                 "peak resident memory"):  # fmt: skip
        assert line in out, line


@pytest.mark.slow  # two TRPO programs compiled: about 60 s
def test_the_reward_check_benchmark_times_both_ways_on_the_driver(capsys):
    """Both ways are timed and their ratio printed; 12 iterations score 10 and 12 in one."""
    bench = _load("bench_reward_check")
    assert bench.main(["--env", "driver", "--rows", "2", "--iterations", "12"]) == 0
    out = capsys.readouterr().out
    scored = [int(n) for n in re.findall(r"(\d+) iterations scored", out)]
    timed = [float(seconds) for seconds in re.findall(r"([\d.]+) s per row-iteration", out)]
    assert scored == [10, 12] and len(timed) == 2 and min(timed) > 0
    assert float(out.split("ratio every iteration / as shipped:")[1]) > 0


@pytest.mark.slow  # four processes compile a TRPO program: about 60 s
def test_the_check_processes_benchmark_times_both_ways_on_the_driver(capsys):
    bench = _load("bench_check_processes")
    assert bench.main(["--env", "driver", "--rows", "2", "--iterations", "10"]) == 0
    out = capsys.readouterr().out
    rates = [float(rate) for rate in re.findall(r"([\d.]+) row-iterations per s", out)]
    assert len(rates) == 2 and min(rates) > 0
    assert float(out.split("ratio 2 processes / one process:")[1]) > 0


def test_the_check_processes_benchmark_refuses_one_row(capsys):
    with pytest.raises(SystemExit) as stopped:
        _load("bench_check_processes").main(["--rows", "1"])
    assert stopped.value.code == 2
    assert "needs 2 or more rows" in capsys.readouterr().err


def test_draw_choice_gives_each_rules_erd_from_the_checks_file(tmp_path, capsys):
    """Learned intention 0's draw 1 out-earns the demonstrations far and misses its expert: the
    check's rule keeps it, the nearest rule and the true ERD keep draw 0."""
    draw_choice = _load("draw_choice")

    def draw(earned, erd):  # one seed, 2 intentions, a constant curve of 12 scored iterations
        earned = {"fresh_policies": earned, "demonstrations": [1.0, 1.0]}
        row = {"run_seed": 0, "matching": [0, 1], "returns": [1.0, 1.0], "erd": float(np.mean(erd)),
               "erd_per_intention": erd, "erd_curve_per_intention": [erd] * 12,
               "learned_reward_per_step": earned}  # fmt: skip
        return {"per_seed": [row]}

    check = tmp_path / "check.json"
    check.write_text(
        json.dumps({"draws": [draw([1.0, 0.9], [0.1, 0.2]), draw([1.8, 1.0], [0.9, 0.1])]})
    )
    assert draw_choice.rule_erds(json.loads(check.read_text())) == {
        0: {
            "most": pytest.approx(0.5),
            "nearest": pytest.approx(0.1),
            "by true ERD": pytest.approx(0.1),
        }
    }
    assert draw_choice.main([str(check)]) == 0
    assert capsys.readouterr().out.splitlines()[-1].split() == ["mean", "0.500", "0.100", "0.100"]
    # The baseline kept by true return (0.4), and the lowest ERD of its draws per intention.
    baseline = {"erd": 0.4, "draws_erd": [0.4, 0.25],
                "draws_erd_per_intention": [[0.6, 0.2], [0.1, 0.4]]}  # fmt: skip
    check.write_text(json.dumps({**json.loads(check.read_text()), "baseline": baseline}))
    assert draw_choice.main([str(check)]) == 0
    last = capsys.readouterr().out.splitlines()[-1]
    assert last == "  true-reward baseline: 0.400 (most true return), 0.150 (lowest ERD)"
    del baseline["draws_erd_per_intention"]  # a check written before: whole draws
    check.write_text(json.dumps({**json.loads(check.read_text()), "baseline": baseline}))
    assert draw_choice.main([str(check)]) == 0
    assert capsys.readouterr().out.splitlines()[-1].endswith("0.250 (its draw of the lowest ERD)")
    one = tmp_path / "one.json"
    one.write_text(json.dumps({"draws": [draw([1.0, 0.9], [0.1, 0.2])]}))
    assert draw_choice.main([str(one)]) == 2
    assert "no check of several draws" in capsys.readouterr().err


def test_the_reward_check_benchmark_refuses_no_iterations(capsys):
    with pytest.raises(SystemExit) as stopped:
        _load("bench_reward_check").main(["--iterations", "0"])
    assert stopped.value.code == 2
    assert "give positive numbers" in capsys.readouterr().err


@pytest.mark.slow  # end to end (make test-slow); cheaper tests cover its parts
def test_driver_separability_writes_its_table(tmp_path, capsys):
    module = _load("driver_separability")
    assert module.main(["--radii", "4", "20", "--out", str(tmp_path)]) == 0
    rows = (tmp_path / "separability.csv").read_text().splitlines()
    assert rows[0].startswith("radius,destination_gap,separability")
    radii = [float(row.split(",")[0]) for row in rows[1:]]
    assert radii == pytest.approx([4.0, 20.0])
    # More overlap at the smaller radius.
    separabilities = [float(row.split(",")[2]) for row in rows[1:]]
    assert separabilities[0] < separabilities[1]


@pytest.mark.slow  # its own compile of the RL update: 30-90 s
def test_rl_floor_trains_on_the_true_reward(capsys):
    rl_floor = _load("rl_floor")
    args = ["--env", "driver", "--intentions", "2", "--iterations", "10"]
    assert rl_floor.main([*args, "--set", "num_envs=2", "--set", "hidden=8,"]) == 0
    (line,) = capsys.readouterr().out.splitlines()
    assert line.startswith("iteration 10: returns ") and "ERD" in line and "entropy" in line


def test_unequal_shares_writes_the_asked_episodes(tmp_path, capsys):
    from emgail_jax.host import demonstration_files

    module = _load("unequal_shares")
    out = tmp_path / "driver-41.npz"
    assert module.main(["--env", "driver", "--episodes", "4", "1", "--out", str(out)]) == 0
    assert "shares 0.800, 0.200" in capsys.readouterr().out
    demos = demonstration_files.load(str(out))
    assert np.bincount(demos.intentions).tolist() == [400, 100]
    bare = tmp_path / "bare.npz"
    assert (
        module.main(
            ["--env", "driver", "--episodes", "1", "1", "--out", str(bare), "--drop-labels"]
        )
        == 0
    )
    assert demonstration_files.load(str(bare)).intentions is None
    assert np.load(f"{bare}.labels.npy").tolist() == [0] * 100 + [1] * 100
    assert module.main(["--env", "driver", "--episodes", "9", "1", "--out", str(out)]) == 2
    assert "has 5 episodes, not 9" in capsys.readouterr().err


@pytest.mark.slow  # a supervised classifier trained per step of the reacher's demonstrations
def test_posterior_ceiling_scores_the_demonstrations_by_step(capsys):
    """The supervised posterior on a few fresh reacher episodes: an accuracy for the whole set
    and for each shown step, all of them fractions."""
    module = _load("posterior_ceiling")
    assert module.main(["--env", "reacher", "--intentions", "2", "--episodes", "3"]) == 0
    out = capsys.readouterr().out
    overall = float(out.split("posterior scores ")[1].split()[0])
    assert 0.5 <= overall <= 1.0  # two intentions: better than chance on shipped demos
    per_step = out.split("accuracy by step:")[1].splitlines()[0].split()
    steps, values = per_step[0::2], [float(v) for v in per_step[1::2]]
    assert steps == [f"{s}:" for s in module.STEPS_SHOWN if s < 50]  # reacher: 50 steps
    assert all(0.0 <= v <= 1.0 for v in values)


@pytest.mark.slow  # end to end (make test-slow); cheaper tests cover its parts
def test_intention_signals_describe_every_demonstration_of_every_seed(tiny_run, capsys):
    module = _load("intention_signals")
    from emgail_jax.host.saved_run import SavedRun

    run = SavedRun.open(str(tiny_run), snapshot=2)
    found = module.signals(run, seed=1)
    episodes, k = run.demonstration_pairs.episodes, run.num_intentions
    assert found["holder"].shape == found["true"].shape == found["agree"].shape == (episodes,)
    assert found["logit"].shape == found["log_pi"].shape == (episodes, k)
    assert np.all((found["agree"] >= 0) & (found["agree"] <= 1))
    held = np.bincount(found["holder"], minlength=k)
    np.testing.assert_array_equal(held, run.demonstrations_held(1))
    assert module.main([str(tiny_run), "--snapshot", "2"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [line for line in lines if line.startswith("seed")] == [
        "seed 0, iteration 2:",
        "seed 1, iteration 2:",
    ]
    assert module.main([str(tiny_run / "missing")]) == 2
    assert capsys.readouterr().err.startswith("error: ")


def test_posterior_ceiling_of_the_driver_at_a_radius(capsys):
    """The supervised posterior on a few fresh noisy driver episodes at radius 20 (paths far
    apart) labels the generated demonstrations well, with and without the step; the driver's
    options and the other envs' are refused in one line."""
    from emgail_jax.host.problem import make_problem

    module = _load("posterior_ceiling")
    problem = make_problem("driver", 2, env_options={"radius": 20.0})
    env, demos = problem.env, problem.demos
    right = module.supervised_ceiling("driver", env, demos, env.expert_policy, 10, with_step=True)
    assert sorted(right) == ["pair", "pair and step"]
    for seen in right.values():
        assert seen.shape == (1000,) and seen.dtype == bool  # 2 x 5 demonstrations x 100 steps
        assert seen.mean() > 0.9
        assert seen[demos.step_in_episode >= 50].all()  # by mid-episode the paths are apart
    out = capsys.readouterr().out
    assert "2000 fresh expert pairs; on the 1000 demonstration pairs" in out
    tenths = out.split("by tenth of the episode:")[1].splitlines()[0].split()
    assert tenths[0::2] == [f"{a}-{a + 9}:" for a in range(0, 100, 10)]
    refused = {
        ("--env", "reacher", "--radius", "4"): "--radius applies to the driver env only",
        ("--env", "driver", "--radius", "0.1"): "tighter than the car can turn",
        ("--env", "driver", "--episodes", "0"): "--episodes must be at least 1; got 0",
    }
    for argv, message in refused.items():
        assert module.main([*argv, "--intentions", "2"]) == 2
        assert message in capsys.readouterr().err


def test_posterior_ceiling_actions_apart_is_the_mean_over_pairs_of_intentions():
    module = _load("posterior_ceiling")
    still, one, two = np.zeros((3, 2)), np.ones((3, 2)), np.full((3, 2), 2.0)
    np.testing.assert_allclose(module.mean_pairwise_distance([still, one]), np.sqrt(2))
    # pairs (0, 1), (0, 2), (1, 2): sqrt 2, 2 sqrt 2, sqrt 2
    apart = module.mean_pairwise_distance([still, one, two])
    np.testing.assert_allclose(apart, np.full(3, 4 * np.sqrt(2) / 3))


def test_posterior_ceiling_scores_a_driver_runs_own_posterior_by_tenth(tiny_run, capsys):
    """A driver run's posterior, matched by its trajectory labels, by step and by tenth of the
    episode for every seed; in place of the expert's actions (it acts on whole states), each
    intention's mean demonstrated action and how far apart the policies' mean actions are."""
    from emgail_jax.host.problem import make_problem

    module = _load("posterior_ceiling")
    module.compare_run(str(tiny_run), make_problem("driver", 2).demos)
    lines = capsys.readouterr().out.splitlines()
    assert [line.split(":")[0].strip() for line in lines if "run seed" in line] == [
        "run seed 0",
        "run seed 1",
    ]
    tenths = [line.split("by tenth:")[1].split() for line in lines if "by tenth:" in line]
    assert len(tenths) == 2 and all(len(t) == 20 for t in tenths)
    assert all(0.0 <= float(v) <= 1.0 for t in tenths for v in t[1::2])
    demonstrated = [line.split("(mean):")[1].split() for line in lines if "demonstrated" in line]
    assert len(demonstrated) == 2 and all(len(t) == 20 for t in demonstrated)
    apart = [line.split("apart:")[1].split() for line in lines if "mean actions apart" in line]
    assert len(apart) == 2 and all(float(v) >= 0.0 for t in apart for v in t[1::2])
    noise = [float(line.split(":")[1]) for line in lines if "action noise" in line]
    assert len(noise) == 2 and all(0.0 < v < 10.0 for v in noise)
    assert not any("|policy" in line or "experts' actions apart" in line for line in lines)


@pytest.mark.slow  # a fresh agent's TRPO compiled and trained (the run's 4 iterations)
def test_fresh_agent_drive_traces_each_learned_intentions_episode(tiny_run, capsys):
    module = _load("fresh_agent_drive")
    assert module.main([str(tiny_run), "--seed", "1", "--every", "50"]) == 0
    out = capsys.readouterr().out
    for intention in (0, 1):
        assert f"learned intention {intention}: true returns [" in out
    # the driver's episodes are 100 steps: its x, y at steps 1 and 51 of each
    assert out.count("  step 1: x ") == 2 and out.count("  step 51: x ") == 2
    assert out.count("  observation dimensions at the clip ±5: ") == 2
    assert out.count("  learned reward per step: own actions ") == 2


@pytest.mark.slow  # end to end (make test-slow); cheaper tests cover its parts
def test_reward_generalisation_scores_every_seed_and_true_intention(tiny_run, capsys):
    module = _load("reward_generalisation")
    assert module.main([str(tiny_run), "--episodes", "2"]) == 0
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("seed ")]
    assert len(lines) == 4  # 2 seeds x 2 true intentions
    for line in lines:
        values = [float(v) for v in line.split(": ")[1].split(" / ")]
        # The driver has its experts; a tiny run's intention may hold no demonstration (nan).
        assert len(values) == 5 and all(np.isfinite(values[1:]))


def test_reward_generalisation_scores_the_runs_snapshots_along_training(tiny_run, capsys):
    module = _load("reward_generalisation")
    assert module.main([str(tiny_run), "--episodes", "2", "--along-training", "2"]) == 0
    out = capsys.readouterr().out
    rows = [line.split() for line in out.splitlines() if line.startswith("  ")]
    assert [int(r[0]) for r in rows] == [2, 4, 2, 4]  # the snapshots, per seed
    for row in rows:
        earned = [float(v) for v in row[1::3]]
        assert len(earned) == 2 and all(np.isfinite(earned))
    assert out.count("rank correlation") == 4  # 2 seeds x 2 true intentions
    # Opened at a snapshot: its own policies and reward, and no later snapshot's.
    assert (
        module.main([str(tiny_run), "--episodes", "2", "--along-training", "2", "--snapshot", "2"])
        == 0
    )
    rows = [line.split() for line in capsys.readouterr().out.splitlines() if line.startswith("  ")]
    assert [int(r[0]) for r in rows] == [2, 2]

    import jax

    from emgail_jax.host.saved_run import SavedRun

    run = SavedRun.open(str(tiny_run))
    found = module.along_training(run, 1, run.reward_parameters(1), 4, 2, jax.random.PRNGKey(0))
    logged = np.asarray(run.history["eval/returns"][1])
    last = max(i for i in range(4) if np.isfinite(logged[i]).all())
    assert [f[0] for f in found] == [4]
    np.testing.assert_array_equal(found[0][2], logged[last])


def test_reward_generalisation_matches_intentions_where_the_run_was_opened(tiny_run, monkeypatch):
    from emgail_jax.host.saved_run import SavedRun
    from emgail_jax.reward import check

    module = _load("reward_generalisation")
    asked = []
    matching = check.run_matching
    monkeypatch.setattr(
        check, "run_matching", lambda run, seed, i: asked.append(i) or matching(run, seed, i)
    )
    for snapshot, iteration in ((2, 2), (None, 4)):
        run = SavedRun.open(str(tiny_run), snapshot=snapshot)
        module.matched_reward(run, 0, run.reward_parameters(0))
        assert asked[-1] == iteration


@pytest.mark.slow  # end to end (make test-slow); cheaper tests cover its parts
def test_reward_generalisation_scores_a_refit_with_absorbing_states(tiny_run, tmp_path, capsys):

    import jax

    from emgail_jax.host.saved_run import SavedRun
    from emgail_jax.reward import refit as refitting
    from emgail_jax.reward import saved as store

    copy = tmp_path / "run"
    shutil.copytree(tiny_run, copy, ignore=shutil.ignore_patterns("rewards"))
    run = SavedRun.open(str(copy)).with_absorbing_states()
    refit = refitting.Refit(steps=3, fresh=True, absorbing=True)
    for seed in range(2):
        parameters, losses = refitting.consolidated_parameters(
            run, seed, refit, jax.random.PRNGKey(seed)
        )
        description = store.refit_description(refit, None, run.iteration)
        store.save_refitted(
            str(copy), "falls", seed, parameters["discriminator"], description, losses
        )
    module = _load("reward_generalisation")
    assert module.main([str(copy), "--episodes", "2", "--refit", "falls"]) == 0
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("seed ")]
    assert len(lines) == 4
    for line in lines:
        values = [float(v) for v in line.split(": ")[1].split(" / ")]
        assert len(values) == 5 and all(np.isfinite(values[1:]))


def test_reward_generalisation_refuses_bad_input_in_one_line(tiny_run, tmp_path, capsys):
    module = _load("reward_generalisation")
    assert module.main([str(tiny_run), "--episodes", "0"]) == 2
    assert "--episodes must be at least 1" in capsys.readouterr().err
    for wrong in ([str(tmp_path / "no-run")], [str(tiny_run), "--snapshot", "3"]):
        assert module.main(wrong) == 2
        err = capsys.readouterr().err
        assert err.startswith("error: ") and err.count("\n") == 1


def test_learned_reward_per_step_is_the_mean_over_each_rows_steps():
    """Row p's reward is p + 1 on every step: its mean per step is p + 1, whatever the
    actions."""
    import jax
    import jax.numpy as jnp

    import envs

    module = _load("reward_generalisation")
    env = envs.make("driver", intentions=2)
    act = lambda state, key: jax.random.uniform(key, (*state.obs.shape[:-1], env.action_size))
    reward = lambda obs, action, rows: rows + 1.0 + 0.0 * action[..., 0]
    per_step = module.learned_reward_per_step(
        env, act, reward, jax.random.PRNGKey(0), jnp.arange(2), 3
    )
    np.testing.assert_allclose(np.asarray(per_step), [1.0, 2.0])
