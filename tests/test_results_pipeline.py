"""The one path from a run's history and final state to its final results: its pure parts
directly (one call for every seed and evaluation gives what one call each gives), and the
whole pipeline against the summary a tiny run wrote."""

import json
import types

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from emgail_jax.host.records import to_json_value
from emgail_jax.host.results_pipeline import (
    env_steps,
    final_responsibilities,
    final_results,
    kept_clustering,
    matched_again,
)
from emgail_jax.host.saved_run import SavedRun
from emgail_jax.method.batches import DemonstrationPairs
from emgail_jax.method.config import ResponsibilityMode
from emgail_jax.method.metrics import normalized_erd
from emgail_jax.method.posterior import Responsibilities
from emgail_jax.method.training import clustering_metrics, responsibilities_of, seed_state


def _demos(k_true=2, episodes=4, per_episode=3, labels=True, seed=0):
    """Demonstration pairs of ``episodes`` demonstrations with ERD's references."""
    rng = np.random.default_rng(seed)
    n = episodes * per_episode
    episode = np.repeat(np.arange(episodes), per_episode).astype(np.int32)
    return DemonstrationPairs(
        observations=rng.normal(size=(n, 2)).astype(np.float32),
        actions=rng.normal(size=(n, 1)).astype(np.float32),
        episode=episode,
        labels=(episode % k_true).astype(np.int32) if labels else np.full(n, -1, np.int32),
        expert_returns=np.float32([-1.0, -2.0, -1.5][:k_true]),
        random_returns=np.float32([-100.0, -80.0, -90.0][:k_true]),
        episodes=episodes,
        has_labels=labels,
    )


def test_env_steps_count_rollouts_and_evaluations():
    """K = 3 intentions x (4 envs x 25 steps per iteration, 5 iterations, + 2 evaluations of
    100-step episodes: 4 phases of 4 x 25 steps) x 2 seeds."""
    returns = np.full((2, 5, 3), np.nan)
    returns[:, [1, 4]] = 1.0
    env = types.SimpleNamespace(num_intentions=3, episode_length=100)
    config = types.SimpleNamespace(rollout=types.SimpleNamespace(num_envs=4, rollout_length=25))
    steps = env_steps({"eval/returns": returns}, env, config)
    assert steps == 3 * (4 * 25 * 5 + 4 * 4 * 25 * 2) * 2


def _learned_returns(seeds, iterations, m, k, seed=0):
    """``eval/learned_returns [S, L, M * K]`` with NaN where nothing was evaluated."""
    rng = np.random.default_rng(seed)
    returns = rng.uniform(-100, -1, size=(seeds, iterations, m * k)).astype(np.float32)
    returns[:, : iterations - 12 : 2] = np.nan  # the early iterations only every other one
    return returns


def test_matched_again_is_the_mean_of_each_evaluations_erd():
    """One call for every seed and evaluation gives, to the bit, what matching each of the
    last ten evaluations alone and averaging them gives."""
    seeds, iterations, m, k = 3, 25, 4, 3
    demos = _demos(k_true=k)
    learned = _learned_returns(seeds, iterations, m, k)
    kept = np.array([[1, 1, 0, 1], [0, 1, 1, 1], [1, 1, 1, 1]], bool)
    got = matched_again({"eval/learned_returns": learned}, kept, demos)
    returns = learned.reshape(seeds, iterations, m, k)
    # The references as JAX arrays, as training holds them: with numpy ones e_i would be
    # numpy's division, which rounds otherwise than XLA's.
    expert, random = jnp.asarray(demos.expert_returns), jnp.asarray(demos.random_returns)
    for seed in range(seeds):
        evaluated = np.flatnonzero(~np.isnan(returns[seed, :, 0, 0]))[-10:]
        erds = [normalized_erd(returns[seed, i], expert, random, kept[seed]) for i in evaluated]
        assert got["erd"][seed] == np.mean([float(e.mean) for e in erds])
        np.testing.assert_array_equal(
            got["erd_per_intention"][seed], np.mean([e.per_intention for e in erds], 0)
        )
        matched = [
            returns[seed, i][np.asarray(e.matching), np.arange(k)]
            for i, e in zip(evaluated, erds, strict=True)
        ]
        np.testing.assert_array_equal(got["returns"][seed], np.mean(matched, 0))


def test_matched_again_scores_a_retired_match_as_random():
    """Learned intention 1 is the better match of true intention 1 but retired: true
    intention 1 goes to learned 2 (e from its returns); with only learned 0 kept, it scores 1."""
    demos = _demos(k_true=2)
    returns = np.float32([[-1.0, -90.0], [-50.0, -2.0], [-60.0, -41.0]])  # [M, K]
    learned = np.tile(returns.reshape(1, 1, -1), (1, 10, 1))
    got = matched_again({"eval/learned_returns": learned}, np.array([[True, False, True]]), demos)
    e1 = abs(-2.0 - -41.0) / abs(-2.0 - -80.0)
    np.testing.assert_allclose(got["erd_per_intention"][0], [0.0, e1], rtol=1e-6)
    np.testing.assert_allclose(got["returns"][0], [-1.0, -41.0])
    only_first = np.array([[True, False, False]])
    alone = matched_again({"eval/learned_returns": learned}, only_first, demos)
    np.testing.assert_allclose(alone["erd_per_intention"][0], [0.0, 1.0], rtol=1e-6)


def test_kept_clustering_is_each_seeds_clustering():
    seeds, k = 2, 3
    demos = _demos(k_true=2, episodes=4)
    rng = np.random.default_rng(1)
    n = demos.episode.shape[0]
    scores = rng.normal(size=(seeds, n, k)).astype(np.float32)
    gamma = np.asarray(jax.nn.softmax(scores, -1))
    responsibilities = Responsibilities(
        gamma=gamma,
        pair_labels=scores.argmax(-1),
        trajectory_labels=gamma.argmax(-1),
        pair_scores=scores,
    )
    kept = np.array([[True, False, True], [True, True, True]])
    got = kept_clustering(responsibilities, kept, demos, ResponsibilityMode.TRAJECTORY)
    for seed in range(seeds):
        one = jax.tree.map(lambda x, s=seed: x[s], responsibilities)
        expected = clustering_metrics(one, demos, k, ResponsibilityMode.TRAJECTORY, kept[seed])
        assert got["cluster_accuracy"][seed] == float(expected["eval/cluster_accuracy"])
        trajectory = float(expected["eval/trajectory_cluster_accuracy"])
        assert got["trajectory_cluster_accuracy"][seed] == trajectory


@pytest.fixture(scope="module")
def saved(tiny_run):
    return SavedRun.open(str(tiny_run))


def test_final_responsibilities_are_each_seeds_e_step(saved):
    """One compiled call over the seeds: each seed's responsibilities as training computes
    them for one seed alone (the same labels; gamma to float rounding)."""
    pairs = saved.demonstration_pairs
    every = final_responsibilities(saved.networks, saved.config.method, saved.state, pairs)
    for seed in range(saved.spec.seeds):
        state = seed_state(saved.state, seed)
        alone = responsibilities_of(saved.networks, saved.config.method, state, pairs)
        np.testing.assert_allclose(every.gamma[seed], alone.gamma, rtol=1e-5, atol=1e-6)
        np.testing.assert_array_equal(every.pair_labels[seed], alone.pair_labels)
        np.testing.assert_array_equal(every.trajectory_labels[seed], alone.trajectory_labels)


def test_the_pipeline_gives_the_summary_the_run_wrote(tiny_run, saved):
    """From the checkpoint's history and final state (and the timings the summary holds), the
    final results are those in the run's summary.json."""
    summary = json.loads((tiny_run / "summary.json").read_text())
    problem = saved.problem
    pairs = DemonstrationPairs.create(
        problem.demos, problem.random_returns, problem.true_intentions
    )
    timings = summary["timings"]
    final = final_results(
        saved.history,
        problem=problem,
        config=saved.config,
        states=saved.state,
        demos=pairs,
        timings=timings,
    )
    assert to_json_value(final.to_summary()) == summary["final"]
    assert final.demonstrations_held.shape == (2, 2)
