"""End-to-end smoke runs of the command line on tiny configs, and its bad-input handling."""

import csv
import json

import numpy as np
import pytest

from emgail_jax import run
from emgail_jax.method.config import AlgorithmName, Prior, RunConfig

pytestmark = pytest.mark.heavy

SEEDS, ITERATIONS = 2, 2
TINY = [
    "--env", "driver",
    "--seeds", str(SEEDS),
    "--iterations", str(ITERATIONS),
    "--num-envs", "2",
    "--rollout-length", "20",
    "--quiet",
]  # fmt: skip


def _run(tmp_path, name, *extra):
    out = tmp_path / name
    code = run.main([*TINY, "--out", str(out), *extra])
    return code, out


class _Runs(dict):
    """``runs[name]``: the tiny run of the algorithm ``name`` ("emgail-again": a second
    EM-GAIL run with the same seed), made when a test first asks for it."""

    def __init__(self, tmp):
        super().__init__()
        self.tmp = tmp

    def __missing__(self, name):
        code, self[name] = _run(self.tmp, name, "--algo", name.removesuffix("-again"))
        assert code == 0
        return self[name]


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    return _Runs(tmp_path_factory.mktemp("runs"))


# Info/IntentionGAIL's run is a whole program of its own (make test-slow): EM-GAIL's and GAIL's
# runs cover the run, test_algorithms and test_discriminator its reward and discriminator.
ALGOS = ["emgail", pytest.param("infogail", marks=pytest.mark.slow), "gail"]


@pytest.mark.parametrize("algo", ALGOS)
def test_summary_follows_the_run_contract(runs, algo):
    summary = json.loads((runs[algo] / "summary.json").read_text())
    assert summary["status"] == "completed"
    assert (summary["env"], summary["algo"], summary["intentions"]) == ("driver", algo, 2)
    assert (summary["seeds"], summary["iterations"]) == (SEEDS, ITERATIONS)
    assert summary["config"]["num_envs"] == 2 and summary["config"]["rollout_length"] == 20
    final = summary["final"]
    assert len(final["erd"]) == SEEDS and all(0.0 <= e < 5.0 for e in final["erd"])
    assert np.asarray(final["returns"]).shape == (SEEDS, 2)
    per_intention = np.asarray(final["erd_per_intention"])
    assert per_intention.shape == (SEEDS, 2)
    np.testing.assert_allclose(per_intention.mean(1), final["erd"], rtol=1e-5)
    assert len(final["expert_returns"]) == 2 and len(final["random_returns"]) == 2
    # The expert is far better than random actions on every intention.
    assert all(
        e > r + 50 for e, r in zip(final["expert_returns"], final["random_returns"], strict=True)
    )
    if algo == "gail":
        assert final["cluster_accuracy"] is None
    else:
        assert all(0.5 <= a <= 1.0 for a in final["cluster_accuracy"])
    for key in ("compile_time_s", "train_time_s", "iteration_time_s"):
        assert final[key] > 0
    # K intentions x (2 envs x 20 steps of training + 2 evaluation episodes x 100 steps) x
    # iterations x seeds.
    assert final["env_steps"] == 2 * (2 * 20 + 2 * 100) * ITERATIONS * SEEDS
    counts = summary["parameters"]
    assert counts["total"] == sum(
        counts[n] for n in ("policy", "value", "discriminator", "posterior")
    )
    machine = summary["machine"]  # results differ in the last bits from one CPU to another
    assert machine["cpu"] and machine["packages"]["jax"] and machine["python"]
    if algo == "gail":  # no posterior: no demonstration is held by an intention, none re-seeded
        assert "demonstrations_held" not in final and "reseedings" not in final
    else:
        # The default driver demonstrations: 5 per path, each held by one learned intention.
        held = np.asarray(final["demonstrations_held"])
        assert held.shape == (SEEDS, 2) and np.all(held.sum(1) == 10)
        assert len(final["reseedings"]) == SEEDS and all(n >= 0 for n in final["reseedings"])


@pytest.mark.slow  # a whole update of its own (make test-slow); cheaper tests cover its parts
def test_runs_differing_only_in_data_share_one_program(runs, tmp_path):
    """After the fixture's radius-20 EM-GAIL run, a radius-10 run of this process reuses its
    compiled programs (no program is added) and gives what a run compiling afresh gives."""
    from emgail_jax.host.program_cache import SHARED

    assert runs["emgail"].exists()  # its programs compiled before this run's
    programs = SHARED.keys()
    code, shared = _run(tmp_path, "shared", "--radius", "10", "--info-weight", "0.5")
    assert code == 0 and set(SHARED.keys()) == set(programs)
    SHARED.clear()
    code, fresh = _run(tmp_path, "fresh", "--radius", "10", "--info-weight", "0.5")
    assert code == 0 and len(SHARED) == 1
    assert (shared / "metrics.csv").read_text() == (fresh / "metrics.csv").read_text()
    radius20 = (runs["emgail"] / "metrics.csv").read_text()
    assert (shared / "metrics.csv").read_text() != radius20


def test_parameter_counts_hand_computed(runs):
    """The driver (obs 10, action 1, K = 2), 64-64 tanh MLPs: GAIL's policy has 10*64 + 64 +
    64*64 + 64 + 64*1 + 1 = 4929 weights and one log-std, its value and discriminator
    (11 inputs) 4993 each; EM-GAIL's policy, value and discriminator have a head per intention
    and its posterior (11 -> 64 -> 64 -> 2) 768 + 4160 + 130 = 5058."""
    counts = {
        algo: json.loads((runs[algo] / "summary.json").read_text())["parameters"]
        for algo in ("gail", "emgail")
    }
    assert counts["gail"] == {
        "policy": 4930, "value": 4993, "discriminator": 4993, "posterior": 0, "total": 14916
    }  # fmt: skip
    assert counts["emgail"] == {
        "policy": 2 * 4929 + 1,
        "value": 2 * 4993,
        "discriminator": 2 * 4993,
        "posterior": 5058,
        "total": 9859 + 9986 + 9986 + 5058,
    }


@pytest.mark.parametrize("algo", ALGOS)
def test_metrics_csv_has_a_row_per_iteration_and_seed(runs, algo):
    with open(runs[algo] / "metrics.csv") as f:
        rows = list(csv.DictReader(f))
    assert [(int(r["iteration"]), int(r["seed"])) for r in rows] == [
        (i, s) for i in range(1, ITERATIONS + 1) for s in range(SEEDS)
    ]
    for column in ("eval/erd", "eval/returns/0", "eval/returns/1", "policy/kl", "value/loss"):
        assert all(np.isfinite(float(r[column])) for r in rows), column
    assert all(float(r["policy/kl"]) <= 0.01 + 1e-6 for r in rows)
    has_posterior = algo != "gail"
    assert ("posterior/loss" in rows[0]) == has_posterior
    assert (rows[0]["eval/cluster_accuracy"] != "") == has_posterior
    assert (runs[algo] / "tensorboard" / "seed_0").is_dir()


def test_same_seed_gives_identical_metrics(runs):
    first = (runs["emgail"] / "metrics.csv").read_text()
    again = (runs["emgail-again"] / "metrics.csv").read_text()
    assert first == again


def test_different_seeds_differ(runs):
    with open(runs["emgail"] / "metrics.csv") as f:
        rows = list(csv.DictReader(f))
    assert rows[0]["discriminator/loss"] != rows[1]["discriminator/loss"]


def _error(capsys):
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err
    return err


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--env", "nope"], "unknown env 'nope'"),
        (["--intentions", "5"], "has 4 intentions"),
        (["--radius", "0.1"], "tighter than the car can turn"),
        (["--seeds", "0"], "--seeds must be at least 1; got 0"),
        (["--iterations", "0"], "--iterations must be at least 1; got 0"),
        (["--seed-batch", "0"], "--seed-batch must be at least 1"),
        (["--chunk-size", "-1"], "--chunk-size must be at least 1; got -1"),
        (["--set", "trpo.max_kl=-1"], "--set: trpo.max_kl must be a positive number; got -1.0"),
        (["--set", "gamma=2"], "--set: gamma must be in (0, 1]; got 2.0"),
        (["--eval-every", "0"], "--eval-every must be at least 1"),
        (["--random-episodes", "0"], "--random-episodes must be at least 1"),
        (["--set", "trpo.dampng=0"], "--set: unknown setting 'trpo.dampng'"),
        (["--max-intentions", "3"], "--max-intentions goes with --intentions auto"),
        (["--intentions", "auto", "--prior", "uniform"], "drop --prior uniform"),
        (["--intentions", "auto", "--algo", "gail"], "needs a posterior"),
        (["--intentions", "auto", "--max-intentions", "0"], "must be at least 1"),
        (["--intentions", "auto", "--max-intentions", "5"], "has 4 intentions"),
        (["--set", "discriminator_form=bogus"], "discriminator_form must be one of gail, airl"),
        (["--set", "discriminator_form=airl", "--algo", "infogail"], "not infogail"),
        (["--rewards", "for-reuse", "--set", "discriminator_form=airl"], "with --rewards"),
        (["--intentions", "0"], "--intentions must be at least 1; got 0"),
        (["--num-envs", "0"], "--num-envs must be at least 1 (or None, the default); got 0"),
        (["--num-envs", "2", "--set", "num_envs=0"], "--set: num_envs must be at least 1"),
        (["--set", "discriminator_support_in_box=true"], "unknown setting"),
        (["--set", "discriminator_gradient_penalty_from=3"], "unknown setting"),
    ],
)
def test_bad_input_gives_one_line_and_exit_code_2(tmp_path, capsys, extra, message):
    code, out = _run(tmp_path, "bad", *extra)
    assert code == 2
    assert message in _error(capsys)
    assert not out.exists()


def test_malformed_demonstrations_are_rejected(tmp_path, capsys):
    path = tmp_path / "demos.npz"
    np.savez(path, observations=np.zeros((10, 3), np.float32))
    code, _ = _run(tmp_path, "bad", "--demos", str(path))
    assert code == 2
    assert "lacks the key(s) actions, episode_starts" in _error(capsys)


def _driver_demonstrations_file(path, *keys):
    """``path``: the driver's demonstrations as a file of the required arrays and ``keys``."""
    from emgail_jax.host.problem import make_problem

    demos = make_problem("driver", 2).demos
    keys = ("observations", "actions", "episode_starts", *keys)
    np.savez(path, **{key: getattr(demos, key) for key in keys})
    return path


def test_airl_refuses_demonstrations_without_final_observations(tmp_path, capsys):
    path = _driver_demonstrations_file(tmp_path / "no-finals.npz", "intentions")
    code, _ = _run(tmp_path, "airl", "--demos", str(path), "--set", "discriminator_form=airl")
    assert code == 2
    assert "needs each demonstration's final observation" in _error(capsys)


def test_existing_run_is_kept_unless_overwrite(runs, capsys):
    before = (runs["gail"] / "summary.json").read_text()
    code = run.main([*TINY, "--out", str(runs["gail"])])
    assert code == 2
    assert "--overwrite" in _error(capsys)
    assert (runs["gail"] / "summary.json").read_text() == before


def test_out_naming_a_file_is_a_one_line_error(tmp_path, capsys):
    path = tmp_path / "taken"
    path.write_text("keep me")
    assert run.main([*TINY, "--out", str(path)]) == 2
    assert "is a file, not a directory" in _error(capsys)
    assert path.read_text() == "keep me"


def test_a_failed_write_is_a_one_line_error(tmp_path, capsys, monkeypatch):
    from emgail_jax.host import records

    def full_disk(path, data):
        raise OSError(28, "No space left on device", path)

    monkeypatch.setattr(records, "write_json", full_disk)
    code, _ = _run(tmp_path, "full")
    assert code == 2
    err = _error(capsys)
    assert "No space left on device" in err and "summary.json" in err


@pytest.mark.slow  # end to end (make test-slow); cheaper tests cover its parts
def test_demonstrations_without_labels_or_returns(tmp_path, capsys):
    path = _driver_demonstrations_file(tmp_path / "unlabelled.npz")
    code, out = _run(tmp_path, "unlabelled", "--demos", str(path))
    assert code == 0
    printed = capsys.readouterr().out
    assert "no expert_returns, so ERD is reported as null" in printed
    assert "no intention labels, so accuracy is null" in printed
    final = json.loads((out / "summary.json").read_text())["final"]
    assert final["erd"] is None and final["cluster_accuracy"] is None
    assert np.asarray(final["returns"]).shape == (SEEDS, 2)


def test_the_run_defining_options_are_those_the_parser_marks():
    """One list: the options a resumed run refuses are the parser's run-defining group, every
    one refused by its own name."""
    options = run.run_options()
    assert {"env", "algo", "seeds", "set", "seed_batch", "eval_every"} <= set(options)
    assert not {"iterations", "out", "resume", "overwrite", "quiet"} & set(options)
    defaults = vars(run.parse_args([]))
    assert set(options) <= set(defaults)
    for name in ("num_envs", "radius", "seed_batch"):
        args = run.parse_args(["--resume", "somewhere", f"--{name.replace('_', '-')}", "2"])
        with pytest.raises(run.RunError, match=f"drop --{name.replace('_', '-')} "):
            run.spec_from_args(args)


def test_intentions_auto_starts_from_the_env_maximum_with_the_mixture_prior():
    spec = run.spec_from_args(run.parse_args(["--env", "hopper", "--intentions", "auto"]))
    assert spec.intentions == 3
    method = spec.config.method
    assert method.choose_intentions and method.e_step.prior is Prior.MIXTURE
    spec = run.spec_from_args(
        run.parse_args(["--intentions", "auto", "--max-intentions", "3", "--algo", "infogail"])
    )
    assert spec.intentions == 3 and spec.config.method.algo is AlgorithmName.INFOGAIL
    spec = run.spec_from_args(run.parse_args(["--intentions", "2"]))
    assert spec.intentions == 2 and not spec.config.method.choose_intentions
    with pytest.raises(SystemExit):
        run.parse_args(["--intentions", "two"])


def test_re_seeding_is_on_by_default_and_one_flag_from_off():
    assert run.spec_from_args(run.parse_args([])).config.method.e_step.reseed
    off = run.spec_from_args(run.parse_args(["--reseed", "off"]))
    assert not off.config.method.e_step.reseed


def test_the_reward_recipe_is_one_flag_and_each_of_its_settings_one_set_away():
    recipe_keys = (
        "reward_form",
        "discriminator_replay",
        "discriminator_support_noise",
        "discriminator_gradient_penalty",
        "absorbing_state",
    )

    def settings(*argv):
        config = run.spec_from_args(run.parse_args(list(argv))).config.to_dict()
        return {key: config[key] for key in recipe_keys}

    paper = settings()
    assert settings("--rewards", "paper") == paper
    assert paper == {key: RunConfig().to_dict()[key] for key in recipe_keys}
    reuse = settings("--rewards", "for-reuse")
    assert reuse["reward_form"] == "log-d" and reuse["discriminator_replay"] == 400
    assert reuse["discriminator_support_noise"] == 1.0
    assert reuse["discriminator_gradient_penalty"] == 0.1
    # An absorbing state only where an episode may end before its time limit.
    assert not reuse["absorbing_state"]
    assert settings("--env", "hopper", "--rewards", "for-reuse")["absorbing_state"]
    assert not settings("--env", "swimmer", "--rewards", "for-reuse")["absorbing_state"]
    changed = settings("--rewards", "for-reuse", "--set", "discriminator_gradient_penalty=1")
    assert changed == {**reuse, "discriminator_gradient_penalty": 1.0}
    with pytest.raises(run.RunError, match="drop --rewards"):
        run.spec_from_args(run.parse_args(["--resume", "somewhere", "--rewards", "for-reuse"]))


def test_set_reaches_the_config_and_a_resume_refuses_it(tmp_path):
    spec = run.spec_from_args(
        run.parse_args(["--set", "discriminator_steps=3", "--set", "trpo.max_kl=0.02"])
    )
    method = spec.config.method
    assert method.m_step.steps == 3 and method.b_step.trpo.max_kl == 0.02
    with pytest.raises(run.RunError, match="drop --set"):
        run.spec_from_args(run.parse_args(["--resume", str(tmp_path), "--set", "gamma=0.99"]))


def test_the_cards_command_and_its_aliases_are_one_main():
    """``python -m emgail_jax.run`` is the training command as the model card spells it;
    ``emgail_jax.train`` and the console scripts reach the same ``main``."""
    import importlib.metadata
    import subprocess
    import sys

    from emgail_jax import train

    assert train.main is run.main
    scripts = {e.name: e.value for e in importlib.metadata.entry_points(group="console_scripts")}
    assert scripts["emgail-run"] == "emgail_jax.run:main"
    assert scripts["emgail-evaluate"] == "emgail_jax.evaluate:main"
    assert scripts["emgail-reoptimize"] == "emgail_jax.reoptimize:main"
    shown = subprocess.run(
        [sys.executable, "-m", "emgail_jax.run", "--help"], capture_output=True, text=True
    )
    assert shown.returncode == 0 and "python -m emgail_jax.run" in shown.stdout
