"""python -m emgail_jax.refit on a tiny run: every seed's refit saved where reoptimize and
load_reward find it, reused by a second run, made anew with --overwrite."""

import json

import jax
import numpy as np
import pytest

from emgail_jax import refit, reoptimize

pytestmark = pytest.mark.heavy

# A refit small enough for a test; the recipe's other settings as they are.
SMALL = ["--set", "consolidate=3", "--set", "consolidate_batch=20"]
NAME = "consolidated-3-penalty-10-fresh-noise-1-batch-20"


def test_the_refit_is_saved_once_then_reused_or_made_anew(copied_run, capsys):
    assert refit.main([str(copied_run), *SMALL]) == 0
    out = capsys.readouterr().out
    directory = copied_run / "rewards" / NAME
    files = ["reward.json", "seed-0.json", "seed-0.msgpack", "seed-1.json", "seed-1.msgpack"]
    assert sorted(p.name for p in directory.iterdir()) == files
    assert all(str(directory / name) in out for name in files)
    # Each seed's progress as it goes; last, what was written and the time it took.
    for seed in (0, 1):
        assert f"refit seed {seed}: one rollout of each of 2 snapshots, 80 samples per " in out
        assert f"refit seed {seed} 3/3  loss " in out
        assert f"refit seed {seed}: done, " in out
    last = out.strip().split("\n")[-1]
    assert last.startswith(f"wrote {copied_run / 'reward'} in ") and " s: load_reward(" in last
    assert f"refit='{NAME}'" in last
    first = (directory / "seed-1.msgpack").read_bytes()
    losses = json.loads((directory / "seed-1.json").read_text())
    assert losses["seconds"] > 0 and losses["after"]["discriminator/loss"] > 0
    assert refit.main([str(copied_run), *SMALL]) == 0
    assert f"seed 1: the refitted reward '{NAME}' saved before, reused" in capsys.readouterr().out
    assert json.loads((directory / "seed-1.json").read_text()) == losses  # not made again
    assert refit.main([str(copied_run), *SMALL, "--overwrite", "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "reused" not in out and "refit seed" not in out and "wrote " in out
    assert (directory / "seed-1.msgpack").read_bytes() == first  # the same refit, made anew
    assert json.loads((directory / "seed-1.json").read_text())["seconds"] != losses["seconds"]


def test_a_saved_refit_is_the_one_reoptimize_refit_checks_and_load_reward_reads(
    copied_run, monkeypatch
):
    import emgail_jax

    assert refit.main([str(copied_run), *SMALL, "--seed", "1", "--quiet"]) == 0
    captured = {}

    def reoptimized(args, run, seeds, chosen, merged):
        captured.update(args=args, run=run, chosen=chosen)
        return 0

    monkeypatch.setattr(reoptimize, "_reoptimized", reoptimized)
    assert reoptimize.main([str(copied_run), "--refit", *SMALL, "--seed", "1", "--quiet"]) == 0
    chosen, run = captured["chosen"], captured["run"]
    assert chosen.details["saved_reward"] == NAME
    assert chosen.details["consolidation"][0]["run_seed"] == 1
    pairs = run.demonstration_pairs
    obs, actions = pairs.observations[:20], pairs.actions[:20]
    # The check reads the driver's refit as log D; load_reward in the form asked.
    checked = run.reward_function()(chosen.parameters[0], obs, actions, 1)
    loaded = emgail_jax.load_reward(str(copied_run), seed=1, refit=NAME, reward_form="log-d")
    np.testing.assert_allclose(loaded(obs, actions, 1), checked, rtol=1e-6)
    assert run.algorithm.reward_form == "log-d"
    leaves = jax.tree.leaves(chosen.parameters[0]["discriminator"])
    assert all(np.isfinite(leaf).all() for leaf in leaves)


def test_the_recipe_is_the_runs_env_and_any_setting_replaces_its_part():
    hopper = refit.parse_args(["RUN"], env="hopper")
    assert (hopper.consolidate, hopper.consolidate_ranking, hopper.consolidate_absorbing) == (
        4000,
        10.0,
        True,
    )
    plain = refit.parse_args(["RUN", "--set", "consolidate_absorbing=false"], env="hopper")
    assert plain.consolidate_absorbing is False and plain.consolidate_fresh is True
    # The name of the refit it saves is the one reoptimize --refit reads.
    check = reoptimize.parse_args(["RUN", "--refit"], env="hopper")
    from emgail_jax.reward import recipe

    assert recipe.refit_parts(hopper) == recipe.refit_parts(check)


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--set", "gamma=0.9"], "--set: unknown key 'gamma'; the keys: consolidate, "),
        (["--set", "consolidate_noise=-1"], "consolidate_noise takes a standard deviation >= 0"),
        (["--ensemble", "2"], "unrecognized arguments: --ensemble"),
    ],
)
def test_a_setting_it_does_not_take_is_one_line_and_exit_code_2(tmp_path, capsys, extra, message):
    with pytest.raises(SystemExit) as exited:
        refit.main([str(tmp_path), *extra])
    assert exited.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and message in err and err.count("\n") == 1


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--set", "consolidate=0"], "--set consolidate=0 refits nothing"),
        (["--seed", "5"], "the run has seeds 0..1"),
        (["--snapshot", "3"], "no snapshot of iteration 3"),
    ],
)
def test_bad_input_gives_one_line_and_exit_code_2(tiny_run, capsys, extra, message):
    assert refit.main([str(tiny_run), *extra]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and message in err and err.count("\n") == 1


def test_help_lists_at_most_15_options(capsys):
    with pytest.raises(SystemExit):
        refit.main(["--help"])
    options = [line for line in capsys.readouterr().out.split("\n") if line.startswith("  -")]
    assert len(options) <= 15


def test_the_console_script_is_the_command():
    import pathlib
    import tomllib

    pyproject = pathlib.Path(__file__).resolve().parents[1] / "pyproject.toml"
    scripts = tomllib.loads(pyproject.read_text())["project"]["scripts"]
    assert scripts["emgail-refit"] == "emgail_jax.refit:main"
