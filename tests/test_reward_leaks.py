"""Tests that a leak cannot pass: the refit and the draw choice read only what a user has (the
demonstrations' pairs, the run's networks and snapshots, the learned reward), never the
demonstrations' hidden labels, their recorded rewards or the experts' returns. Tiny driver runs
on the same pairs with those fields tampered with must train and refit bit for bit alike, and
the draw rules must keep the same draws whatever the true returns say; only the scores (ERD)
may differ."""

import dataclasses
import json
import shutil

import jax
import numpy as np
import pytest

from emgail_jax import refit, run
from emgail_jax.host import demonstration_files
from emgail_jax.host.problem import make_problem
from emgail_jax.host.run_spec import read_summary
from emgail_jax.host.saved_run import SavedRun
from emgail_jax.method.metrics import reward_difference
from emgail_jax.reward import check, draws, saved
from emgail_jax.reward.refit import Refit

pytestmark = pytest.mark.heavy

# tiny_run's options (tests/conftest.py): the run on the tampered demonstrations is that run on
# other labels, rewards and returns, and shares its compiled program.
TINY = [
    *("--env", "driver", "--seeds", "2", "--iterations", "4", "--num-envs", "2"),
    *("--rollout-length", "20", "--chunk-size", "2", "--snapshot-every", "2", "--quiet"),
]
# A few steps of a refit that reads everything a refit may read: the recipe's penalty, fresh
# weights, noisy negatives and batches, the snapshots ranked above random and still actions,
# and the demonstrations' terminations as absorbing states.
REFIT = [
    *("--set", "consolidate=3", "--set", "consolidate_batch=20"),
    *("--set", "consolidate_ranking=1", "--set", "consolidate_ranking_random=true"),
    *("--set", "consolidate_ranking_still=true", "--set", "consolidate_absorbing=true"),
    *("--seed", "0", "--quiet"),
]
RETURNS_SCALE = 7.3


def tampered(demos, labels: bool = True, returns: bool = True):
    """``demos`` with what no user has changed, the pairs as they were: the hidden labels
    shuffled pair by pair (``labels``); the experts' returns scaled and the recorded rewards
    replaced by noise (``returns``)."""
    rng = np.random.default_rng(67)
    if labels:
        demos = dataclasses.replace(demos, intentions=rng.permutation(demos.intentions))
    if returns:
        demos = dataclasses.replace(
            demos,
            expert_returns=demos.expert_returns * np.float32(RETURNS_SCALE),
            rewards=rng.normal(size=demos.rewards.shape).astype(np.float32),
        )
    return demos


def refitted(run_dir) -> str:
    """``run_dir`` with its seed 0 refitted by ``python -m emgail_jax.refit``."""
    assert refit.main([str(run_dir), *REFIT]) == 0
    return str(run_dir)


def refitted_run(root, name: str, demos) -> str:
    """A tiny driver run trained on ``demos`` (``run --demos root/name.npz``) and refitted: its
    directory."""
    path, run_dir = root / f"{name}.npz", root / name
    demonstration_files.save(demos, str(path))
    assert run.main([*TINY, "--demos", str(path), "--out", str(run_dir)]) == 0
    return refitted(run_dir)


@pytest.fixture(scope="module")
def demos():
    """The driver's demonstrations, as a run without ``--demos`` generates them."""
    return make_problem("driver").demos


@pytest.fixture(scope="module")
def runs(tiny_run, demos, tmp_path_factory):
    """``(own, leaked)``: the run on the demonstrations as they are (``tiny_run``, whose
    generated demonstrations are those of ``demos``), and the run on them with the labels
    shuffled, the rewards replaced and the experts' returns scaled at once."""
    root = tmp_path_factory.mktemp("leaks")
    own = root / "own"
    shutil.copytree(tiny_run, own, ignore=shutil.ignore_patterns("rewards", "reoptimize*"))
    return refitted(own), refitted_run(root, "leaked", tampered(demos))


def differing_leaves(a, b) -> list[str]:
    """The paths of the leaves in which the pytrees ``a`` and ``b`` differ, bit for bit."""
    leaves_a, tree_a = jax.tree_util.tree_flatten_with_path(a)
    leaves_b, tree_b = jax.tree_util.tree_flatten_with_path(b)
    assert tree_a == tree_b
    return [
        jax.tree_util.keystr(path)
        for (path, x), (_, y) in zip(leaves_a, leaves_b, strict=True)
        if not np.array_equal(np.asarray(x), np.asarray(y))
    ]


def assert_same_training(own_dir: str, other_dir: str) -> None:
    """The runs' networks, final and every snapshot's, are bit-identical."""
    for snapshot in (None, 2, 4):
        own, other = (SavedRun.open(d, snapshot=snapshot) for d in (own_dir, other_dir))
        assert differing_leaves(own.state, other.state) == [], f"snapshot {snapshot}"


def assert_same_refit(own_dir: str, other_dir: str) -> None:
    """The runs' saved refits, array by array, their losses, the responsibilities they weight
    the demonstrations by and what the demonstrations earn under them (the ``nearest`` draw
    rule's reference) are bit-identical."""
    (name,) = saved.saved_refits(own_dir)
    assert saved.saved_refits(other_dir) == [name]
    as_refitted = lambda d: saved.run_to_refit(
        SavedRun.open(d), Refit(**saved.read_description(d, name)["refit"])
    )
    own, other = as_refitted(own_dir), as_refitted(other_dir)
    for seed in (0,):  # the seed refitted
        gamma = [np.asarray(r.responsibilities(seed).gamma) for r in (own, other)]
        np.testing.assert_array_equal(*gamma)
        parameters = [saved.saved_parameters(r, name, seed) for r in (own, other)]
        assert differing_leaves(*parameters) == [], f"seed {seed}"
        losses = [saved.read_losses(r.run_dir, name, r.seed_number(seed)) for r in (own, other)]
        untimed = [{k: v for k, v in x.items() if k != "seconds"} for x in losses]
        assert untimed[0] == untimed[1]
        earned = [
            check.demonstrations_reward(r, seed, p)
            for r, p in zip((own, other), parameters, strict=True)
        ]
        np.testing.assert_array_equal(*earned)


def test_the_tampered_run_read_other_labels_rewards_and_returns_and_the_same_pairs(demos, runs):
    """Not a vacuous test: the leaked run's demonstrations differ in every field no user has,
    and its scores read them."""
    own, leaked = (SavedRun.open(d).problem.demos for d in runs)
    for name in ("observations", "actions", "episode_starts"):
        np.testing.assert_array_equal(getattr(own, name), getattr(leaked, name))
    assert (own.intentions != leaked.intentions).mean() > 0.3
    assert not np.array_equal(own.rewards, leaked.rewards)
    np.testing.assert_allclose(leaked.expert_returns, own.expert_returns * RETURNS_SCALE, 1e-6)
    finals = [read_summary(d)["final"]["expert_returns"] for d in runs]
    np.testing.assert_allclose(finals[1], np.multiply(finals[0], RETURNS_SCALE), 1e-5)


def test_training_reads_no_hidden_label_recorded_reward_or_expert_return(runs):
    assert_same_training(*runs)


def test_the_refit_reads_no_hidden_label_recorded_reward_or_expert_return(runs):
    assert_same_refit(*runs)


@pytest.mark.slow
@pytest.mark.parametrize(
    "changed",
    [
        pytest.param({"labels": True, "returns": False}, id="labels-shuffled"),
        pytest.param({"labels": False, "returns": True}, id="rewards-and-returns"),
    ],
)
def test_each_field_alone_changes_neither_training_nor_refit(demos, runs, tmp_path, changed):
    """Each tampering on its own, to say which field a leak reads."""
    other = refitted_run(tmp_path, "tampered", tampered(demos, **changed))
    assert_same_training(runs[0], other)
    assert_same_refit(runs[0], other)


@pytest.mark.slow
def test_demonstrations_without_labels_rewards_or_returns_train_and_refit_alike(
    demos, runs, tmp_path
):
    """A user's demonstrations carry none of them: the run is scored on nothing, and trains
    and refits as the run that had them."""
    bare = dataclasses.replace(demos, intentions=None, expert_returns=None, rewards=None)
    other = refitted_run(tmp_path, "bare", bare)
    assert_same_training(runs[0], other)
    assert_same_refit(runs[0], other)


@pytest.mark.slow
@pytest.mark.parametrize("rule", draws.DRAW_RULES)
def test_the_check_keeps_the_same_draws_of_the_tampered_run(runs, tmp_path, rule):
    """Two draws of fresh agents on each run's refit, kept by ``rule``: the same agents, paid
    the same learned reward, for every learned intention."""
    from emgail_jax import reoptimize

    options = ["--refit", *REFIT, "--draws", "2", "--keep-draw", rule, "--iterations", "10"]
    options.append("--no-baseline")
    checks = []
    for number, run_dir in enumerate(runs):
        out = tmp_path / f"check-{number}.json"
        assert reoptimize.main([run_dir, *options, "--out", str(out)]) == 0
        checks.append(json.loads(out.read_text()))
    kept = [by_learned_intention(c["per_seed"][0], len(c["per_seed"][0]["draw"])) for c in checks]
    assert kept[0] == kept[1]
    paid = [c["per_seed"][0]["learned_reward_per_step"] for c in checks]
    assert paid[0] == paid[1]
    every = [[d["per_seed"][0]["learned_reward_per_step"] for d in c["draws"]] for c in checks]
    assert every[0] == every[1]


# ---- the draw rules, on made-up checks ---------------------------------------------------------

DRAWS, SEEDS, K, ITERATIONS = 4, 2, 3, 12


def made_up_check(learned: dict, true_returns: np.ndarray, expert: np.ndarray) -> list[dict]:
    """``DRAWS`` draws of a check of ``SEEDS`` seeds and ``K`` intentions as
    :func:`check.reoptimize` writes them: the ``learned`` side (``earned [D, S, K learned]``
    per step, ``demonstrations [S, K]``, ``matching [S, K true]``) and the true side
    (``true_returns [D, S, K true]`` of the matched agents, the experts' ``expert [K]``)."""
    random = np.zeros(K)
    every = []
    for d in range(DRAWS):
        per_seed = []
        for s in range(SEEDS):
            returns = true_returns[d, s]
            per_intention = np.tile(reward_difference(returns, expert, random), (ITERATIONS, 1))
            per_seed.append(
                {
                    "run_seed": s,
                    "matching": learned["matching"][s],
                    "returns": returns,
                    **check.erd_summary(per_intention),
                    "success": [{"meets_bar": bool(m)} for m in returns > 0.9 * expert],
                    "learned_reward_per_step": {
                        "fresh_policies": learned["earned"][d, s],
                        "demonstrations": learned["demonstrations"][s],
                    },
                }
            )
        shared = {**dict.fromkeys(check.DRAW_SHARED), "expert_returns": expert, "rl_seed": d}
        every.append(
            {
                **shared,
                "seeds": list(range(SEEDS)),
                **check.over_seeds(per_seed),
                "compile_time_s": 1.0,
                "train_time_s": 1.0,
            }
        )
    return every


def learned_side(rng) -> dict:
    return {
        "matching": [rng.permutation(K) for _ in range(SEEDS)],
        "earned": rng.normal(size=(DRAWS, SEEDS, K)),
        "demonstrations": rng.normal(size=(SEEDS, K)),
    }


def by_learned_intention(seed_result: dict, k: int = K) -> list[int]:
    """The draw kept for each of the ``k`` learned intentions of one seed's chosen result
    (whose ``draw`` is per true intention)."""
    kept = np.empty(k, int)
    kept[np.asarray(seed_result["matching"])] = seed_result["draw"]
    return kept.tolist()


@pytest.mark.parametrize("rule", draws.DRAW_RULES)
@pytest.mark.parametrize("case", range(3))
def test_the_draw_rules_keep_the_same_draws_whatever_the_true_side_says(rule, case):
    """The true returns of the draws reversed and scaled, the experts' scaled and the run's
    matching (made from the true returns) another: every seed keeps the same draw for every
    learned intention, paid the same learned reward, under either rule. The rule that reads the
    true ERD, which no user can follow, keeps others: the tampering is material."""
    rng = np.random.default_rng(case)
    learned = learned_side(rng)
    expert = rng.uniform(50.0, 100.0, K)
    true_returns = rng.uniform(0.0, 100.0, (DRAWS, SEEDS, K))
    own = made_up_check(learned, true_returns, expert)
    other_matching = {**learned, "matching": [np.roll(m, 1) for m in learned["matching"]]}
    scale = RETURNS_SCALE
    leaked = made_up_check(other_matching, true_returns[::-1] * scale, expert * scale)
    kept = lambda every: [
        by_learned_intention(r) for r in draws.chosen_by_learned_reward(every, rule)["per_seed"]
    ]
    assert kept(own) == kept(leaked)
    paid = lambda every: [
        r["learned_reward_per_step"]["fresh_policies"]
        for r in draws.chosen_by_learned_reward(every, rule)["per_seed"]
    ]
    np.testing.assert_array_equal(paid(own), paid(leaked))
    for s in range(SEEDS):
        rows = [[d["per_seed"][s] for d in every] for every in (own, leaked)]
        np.testing.assert_array_equal(*(draws.kept_draws(r, rule) for r in rows))
        hindsight = [draws.kept_per_true_intention(r, draws.BY_TRUE_ERD) for r in rows]
        assert hindsight[0] != hindsight[1]


def test_the_fresh_agents_are_paid_the_learned_reward_never_the_true_one(monkeypatch):
    """What the draw rules compare, the learned reward each fresh agent earned, is paid by the
    reward's parameters alone: the true reward the rollout carries is not read."""
    from types import SimpleNamespace

    made = {}

    def fresh_trainer(run, budget, reward_fn=None, absorbing_reward=None):
        made.update(reward_fn=reward_fn)

    monkeypatch.setattr(check, "fresh_trainer", fresh_trainer)
    learned = lambda parameters, obs, action, intention: (
        parameters * obs.sum(-1) + action[..., 0] + intention
    )
    check.learned_reward_trainer(
        SimpleNamespace(absorbing_reward_function=lambda: None), None, learned
    )
    rng = np.random.default_rng(0)
    obs, action = rng.normal(size=(5, 1, 2, 4)), rng.normal(size=(5, 1, 2, 1))
    true = rng.normal(size=(5, 1, 2, K))
    paid = [made["reward_fn"](obs, action, t, 1, 2.0) for t in (true, true * RETURNS_SCALE + 1.0)]
    np.testing.assert_array_equal(*paid)
    np.testing.assert_array_equal(paid[0], learned(2.0, obs, action, 1))
