"""RUN/reward/: what python -m emgail_jax.refit writes for a user to take away, and what
load_reward returns of it (the refit by default, the run's own when asked or when none)."""

import json
import shutil

import jax
import numpy as np
import pytest

import emgail_jax
from emgail_jax import refit
from emgail_jax.host.run_spec import RunError
from emgail_jax.host.saved_run import SavedRun
from emgail_jax.reward import load, product
from emgail_jax.reward import saved as store

pytestmark = pytest.mark.heavy

# A refit small enough for a test; the recipe's other settings as they are.
SMALL = ["--set", "consolidate=3", "--set", "consolidate_batch=20"]
NAME = "consolidated-3-penalty-10-fresh-noise-1-batch-20"
FIELDS = {
    "format",
    "source",
    "form",
    "termination",
    "observation_normalisation",
    "recipe",
    "refit",
    "saved_reward",
    "networks",
    "snapshots",
    "seconds",
    "seeds",
}


def _copy(tiny_run, directory):
    copy = directory / "run"
    shutil.copytree(tiny_run, copy, ignore=shutil.ignore_patterns("rewards", "reward", "reopt*"))
    return copy


@pytest.fixture(scope="module")
def refitted_run(tiny_run, tmp_path_factory):
    """A copy of the tiny run with its reward refitted and saved (RUN/reward/)."""
    copy = _copy(tiny_run, tmp_path_factory.mktemp("product"))
    assert refit.main([str(copy), *SMALL, "--quiet"]) == 0
    return copy


def _pairs(run_dir, count=30):
    pairs = SavedRun.open(str(run_dir)).demonstration_pairs
    return pairs.observations[:count], pairs.actions[:count]


def test_the_refit_writes_the_reward_and_how_to_read_it(refitted_run):
    directory = refitted_run / "reward"
    assert sorted(p.name for p in directory.iterdir()) == [
        "reward.json",
        "seed-0.msgpack",
        "seed-1.msgpack",
    ]
    description = json.loads((directory / "reward.json").read_text())
    assert set(description) == FIELDS
    assert description["source"] == "refit" and description["saved_reward"] == NAME
    # The driver's episodes never end early: read as log D, no termination to pay.
    assert description["form"] == "log-d" and description["termination"] is None
    assert description["observation_normalisation"]["stored"].startswith("seed-S.msgpack")
    assert description["recipe"]["consolidate"] == 3
    assert description["recipe"]["consolidate_batch"] == 20
    assert description["refit"]["steps"] == 3 and description["refit"]["fresh"] is True
    assert description["snapshots"] == [2, 4]
    assert description["networks"] == {"snapshot": None, "iteration": 4}
    assert description["seeds"] == [0, 1]
    assert all(description["seconds"][s] > 0 for s in ("0", "1"))


def test_load_reward_returns_the_refit_by_default_and_says_so(refitted_run):
    reward = emgail_jax.load_reward(str(refitted_run), seed=1)
    assert reward.source == "refit" and reward.form == "log-d"
    assert repr(reward) == (
        f"LearnedReward(run={str(refitted_run)!r}, seed=1, source='refit', form='log-d')"
    )
    obs, actions = _pairs(refitted_run)
    # The refit kept by name, read as the check reads it, pays the same.
    kept = load.load_reward(str(refitted_run), seed=1, refit=NAME, reward_form="log-d")
    assert kept.source == "refit"
    for read in (reward, jax.jit(reward)):
        np.testing.assert_allclose(read(obs, actions, 1), kept(obs, actions, 1), rtol=1e-6)
    assert np.all(np.asarray(reward(obs, actions, 1)) <= 0)  # log D
    np.testing.assert_array_equal(reward.termination(np.array([0, 1])), [0.0, 0.0])


def test_the_runs_own_reward_when_asked_or_when_there_is_no_refit(refitted_run, tiny_run):
    obs, actions = _pairs(refitted_run)
    paper = emgail_jax.load_reward(str(refitted_run), seed=1, source="paper")
    assert paper.source == "paper" and "source='paper'" in repr(paper)
    own = SavedRun.open(str(tiny_run)).reward(1)(obs, actions, 1)
    np.testing.assert_allclose(paper(obs, actions, 1), own, rtol=1e-6)
    without = emgail_jax.load_reward(str(tiny_run), seed=1)  # no RUN/reward/
    assert without.source == "paper"
    np.testing.assert_allclose(without(obs, actions, 1), own, rtol=1e-6)
    with pytest.raises(RunError, match=r"has no refitted reward: python -m emgail_jax\.refit"):
        emgail_jax.load_reward(str(tiny_run), source="refit")
    with pytest.raises(RunError, match="unknown reward source 'mine'"):
        emgail_jax.load_reward(str(tiny_run), source="mine")
    shared = emgail_jax.load_reward(str(refitted_run), seed=1, across_seeds=True)
    assert shared.source == "paper"


def test_the_reward_is_a_pytree_whose_parameters_a_jitted_program_reads(refitted_run):
    reward = emgail_jax.load_reward(str(refitted_run), seed=0)
    obs, actions = _pairs(refitted_run)
    paid = jax.jit(lambda r: r(obs, actions, 0))
    zeroed = jax.tree.map(np.zeros_like, reward)
    assert zeroed.source == "refit"
    assert not np.allclose(paid(reward), paid(zeroed))


def test_an_absorbing_refit_saves_its_termination_price(tiny_run, tmp_path, monkeypatch):
    from emgail_jax.reward.refit import random_actions_reward

    copy = _copy(tiny_run, tmp_path)
    extra = ["--set", "consolidate_absorbing=true", "--set", "absorbing_reward=random"]
    assert refit.main([str(copy), *SMALL, *extra, "--seed", "1", "--quiet"]) == 0
    description = product.read(str(copy))
    termination = description["termination"]
    assert termination["price"] == "random" and description["seeds"] == [1]
    reward = emgail_jax.load_reward(str(copy), seed=1)
    # What reoptimize prices a fall at (--set absorbing_reward=random) for the refit it checks.
    run = SavedRun.open(str(copy)).with_absorbing_states().with_reward_form(description["form"])
    parameters = store.saved_parameters(run, f"{NAME}-absorbing", 1)
    price = random_actions_reward(run, parameters, run.reward_function())
    np.testing.assert_allclose(termination["per_step_left"]["1"], price, rtol=1e-6)
    np.testing.assert_allclose(reward.termination(np.array([0, 1])), price, rtol=1e-6)
    with pytest.raises(RunError, match="has no seed 0"):
        emgail_jax.load_reward(str(copy), seed=0)
    # reoptimize pays its fresh agents' falls what load_reward's termination pays.
    chosen = _checked(copy, monkeypatch, "--seed", "1")["chosen"]
    intentions = np.array([0, 1])
    paid = chosen.absorbing(chosen.parameters[0], intentions)
    np.testing.assert_array_equal(paid, reward.termination(intentions))
    assert chosen.details["reward"]["termination_price"] == "random"
    np.testing.assert_array_equal(chosen.details["termination"][0], paid)


def test_a_price_without_an_absorbing_state_is_refused(tiny_run, tmp_path, capsys):
    copy = _copy(tiny_run, tmp_path)
    assert refit.main([str(copy), *SMALL, "--set", "absorbing_reward=random"]) == 2
    assert "absorbing_reward prices an absorbing state" in capsys.readouterr().err


def test_a_check_reads_the_saved_reward_as_reoptimize_refit_checks_it(refitted_run, monkeypatch):
    """RUN/reward/ holds the very parameters ``reoptimize --refit`` checks, read by the same
    reward function: a check can read it in place of the refit kept by name."""
    from emgail_jax import reoptimize

    captured = {}

    def reoptimized(args, run, seeds, chosen, merged):
        captured.update(run=run, chosen=chosen)
        return 0

    monkeypatch.setattr(reoptimize, "_reoptimized", reoptimized)
    assert reoptimize.main([str(refitted_run), "--refit", *SMALL, "--quiet"]) == 0
    run, description = product.opened(str(refitted_run))
    assert run.algorithm.reward_form == captured["run"].algorithm.reward_form
    for seed, checked in enumerate(captured["chosen"].parameters):
        saved = product.parameters(run, description, seed)
        assert product.PRICE not in saved  # the driver: no termination to price
        for ours, theirs in zip(jax.tree.leaves(saved), jax.tree.leaves(checked), strict=True):
            np.testing.assert_array_equal(ours, theirs)


def _checked(run_dir, monkeypatch, *extra):
    """What ``reoptimize RUN *extra`` would train fresh agents on: its resolved options, the
    run it opened and the reward it chose (nothing trained)."""
    from emgail_jax import reoptimize

    captured = {}

    def reoptimized(args, run, seeds, chosen, merged):
        captured.update(args=args, run=run, seeds=seeds, chosen=chosen)
        return 0

    monkeypatch.setattr(reoptimize, "_reoptimized", reoptimized)
    assert reoptimize.main([str(run_dir), *extra, "--quiet"]) == 0
    return captured


def test_reoptimize_checks_the_saved_reward_by_default_as_load_reward_returns_it(
    refitted_run, monkeypatch
):
    from emgail_jax import reoptimize

    checked = _checked(refitted_run, monkeypatch)
    args, run, chosen = checked["args"], checked["run"], checked["chosen"]
    assert args.reward == "saved" and reoptimize.default_name(args) == "reoptimize-saved.json"
    description = product.read(str(refitted_run))
    details = chosen.details["reward"]
    assert details["source"] == "saved" and details["saved_reward"] == NAME
    assert details["recipe"] == description["recipe"] and details["form"] == "log-d"
    assert details["termination_price"] is None and chosen.absorbing is None
    assert run.algorithm.reward_form == "log-d"
    obs, actions = _pairs(refitted_run)
    for seed, parameters in zip(checked["seeds"], chosen.parameters, strict=True):
        loaded = emgail_jax.load_reward(str(refitted_run), seed=seed)
        for ours, theirs in zip(
            jax.tree.leaves(parameters), jax.tree.leaves(loaded.parameters), strict=True
        ):
            np.testing.assert_array_equal(ours, theirs)
        np.testing.assert_array_equal(
            chosen.function(parameters, obs, actions, 1), loaded(obs, actions, 1)
        )
    identity = reoptimize.check_identity(args, run)
    assert identity["options"]["reward"] == "saved"
    assert identity["saved_reward"] == [NAME, "log-d", None]
    lines = reoptimize._reward_lines({"reward": details})
    assert lines[0].startswith(f"reward checked: the saved reward {refitted_run / 'reward'} (")
    assert "consolidate=3 " in lines[0] and "consolidate_ranking" not in lines[0]  # off
    assert lines[0].endswith("consolidate_batch=20), read as log-d")


def test_reoptimize_checks_the_papers_reward_or_a_refit_when_asked(refitted_run, monkeypatch):
    from emgail_jax import reoptimize

    paper = _checked(refitted_run, monkeypatch, "--set", "reward=paper")
    assert paper["args"].reward == "paper" and paper["chosen"].parameters is None
    assert paper["chosen"].details["reward"] == {"source": "paper"}
    assert reoptimize.default_name(paper["args"]) == "reoptimize.json"
    assert "reward" not in reoptimize.check_identity(paper["args"], paper["run"])["options"]
    assert reoptimize._reward_lines({"reward": {"source": "paper"}, "reward_form": "gail"}) == [
        "reward checked: the paper's, the run's own (gail)"
    ]
    refit = _checked(refitted_run, monkeypatch, "--refit", *SMALL)
    assert refit["args"].reward == "refit" and refit["chosen"].details["saved_reward"] == NAME
    assert refit["chosen"].details["reward"]["recipe"]["consolidate"] == 3
    # A snapshot's own reward: the saved one is of the final networks.
    snapshot = reoptimize.parse_args([str(refitted_run), "--snapshot", "2"])
    assert reoptimize.reward_source(snapshot) == "paper"
    shared = reoptimize.parse_args([str(refitted_run), "--set", "across_seeds=true"])
    assert reoptimize.reward_source(shared) == "paper"


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--set", "reward=saved", "--snapshot", "2"], "refitted from the final networks: drop"),
        (["--set", "reward=saved", "--set", "across_seeds=true"], "give --set reward=paper"),
        (["--set", "absorbing_reward=random"], "absorbing_reward goes with the run's own reward"),
        (["--refit", "--set", "reward=saved"], "checks a reward made before: not with --refit"),
    ],
)
def test_a_saved_reward_with_options_it_does_not_take_is_one_line(
    refitted_run, capsys, extra, message
):
    from emgail_jax import reoptimize

    assert reoptimize.main([str(refitted_run), *extra]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and message in err and err.count("\n") == 1
