"""Reopening a run: load_policy / load_reward round trip against the training code."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import emgail_jax
from emgail_jax.host.run_spec import RunError
from emgail_jax.host.saved_run import SavedRun
from emgail_jax.method import normalizer as obs_norm

pytestmark = pytest.mark.heavy


@pytest.fixture(scope="module")
def saved(tiny_run):
    return SavedRun.open(str(tiny_run))


def test_open_restores_the_last_checkpoint(saved):
    assert saved.iteration == 4 and saved.spec.seeds == 2
    assert int(saved.state.iteration[0]) == 4
    assert saved.history["eval/erd"].shape == (2, 4)


def test_load_policy_is_the_trained_policy_and_jits(tiny_run, saved):
    policy = emgail_jax.load_policy(str(tiny_run), seed=1)
    obs = saved.problem.demos.observations[:7]
    state = saved.seed_state(1)
    for intention in (0, 1):
        condition = jax.nn.one_hot(jnp.full(7, intention), 2)
        normalized = obs_norm.normalize(
            state.normalizer, obs, saved.config.method.networks.obs_clip
        )
        mean, _ = saved.networks.policy.apply(state.policy, normalized, condition)
        expected = np.clip(mean, -1, 1)
        np.testing.assert_allclose(policy(obs, intention), expected, rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(jax.jit(policy)(obs, intention), expected, rtol=1e-5, atol=1e-6)
    assert policy(obs[0], 0).shape == (1,)  # a single state works too


def test_load_reward_is_minus_log_one_minus_d(tiny_run, saved):
    reward = emgail_jax.load_reward(str(tiny_run))
    demos = saved.problem.demos
    obs, act = demos.observations[:5], demos.actions[:5]
    state = saved.seed_state(0)
    normalized = obs_norm.normalize(state.normalizer, obs, saved.config.method.networks.obs_clip)
    for intention in (0, 1):
        condition = jax.nn.one_hot(jnp.full(5, intention), 2)
        logit = saved.networks.discriminator.apply(
            state.discriminator.params, normalized, act, condition
        )
        d = jax.nn.sigmoid(logit)
        np.testing.assert_allclose(reward(obs, act, intention), -np.log(1 - d), rtol=1e-4)
    np.testing.assert_allclose(jax.jit(reward)(obs, act, 1), reward(obs, act, 1), rtol=1e-6)


def test_a_run_without_absorbing_states_has_no_absorbing_reward(saved):
    # An episode's end is worth 0 (tests/test_reoptimize.py reads one that has one).
    assert saved.absorbing_reward_function() is None


def test_load_reward_judges_the_executed_action(tiny_run):
    """The discriminator learned on actions clipped to the range, so an action beyond it gets
    the reward of the clipped action."""
    reward = emgail_jax.load_reward(str(tiny_run))
    obs = np.zeros((2, 10), np.float32)
    far = reward(obs, np.array([[5.0], [-7.0]], np.float32), 0)
    edge = reward(obs, np.array([[1.0], [-1.0]], np.float32), 0)
    np.testing.assert_array_equal(far, edge)


def test_responsibilities_are_distributions(saved):
    result = saved.responsibilities(0)
    assert result.gamma.shape == (len(saved.problem.demos), 2)
    np.testing.assert_allclose(result.gamma.sum(-1), 1.0, rtol=1e-5)
    # Trajectory responsibilities (the default): gamma is each demonstration's posterior.
    np.testing.assert_array_equal(result.trajectory_labels, np.argmax(result.gamma, -1))
    episode = saved.demonstration_pairs.episode
    for e in np.unique(episode):
        assert len(np.unique(result.trajectory_labels[episode == e])) == 1


def test_clustering_equals_what_training_logged_last(saved):
    """Same posterior, same normaliser, same pairs, same function: the accuracy of the saved
    run is the one training logged at its last iteration, exactly."""
    for seed in range(2):
        logged = {
            name: float(saved.history[f"eval/{name}"][seed, -1])
            for name in ("cluster_accuracy", "trajectory_cluster_accuracy")
        }
        assert saved.clustering(seed) == logged


def test_unknown_seed_is_refused(saved):
    with pytest.raises(RunError, match=r"seeds 0\.\.1"):
        saved.seed_state(2)


def test_seeds_are_named_by_the_numbers_run_seed_gave_them(tiny_run, renumbered_run, saved):
    run = SavedRun.open(str(renumbered_run))
    assert [run.seed_number(s) for s in range(2)] == [4, 5]
    assert (run.seed_index(None), run.seed_index(4), run.seed_index(5)) == (0, 0, 1)
    with pytest.raises(RunError, match=r"the run has seeds 4\.\.5; got seed 1"):
        run.seed_index(1)
    obs = saved.problem.demos.observations[:3]
    own = emgail_jax.load_policy(str(tiny_run), seed=1)(obs, 0)
    np.testing.assert_array_equal(emgail_jax.load_policy(str(renumbered_run), seed=5)(obs, 0), own)
    reward = emgail_jax.load_reward(str(renumbered_run), seed=5)
    action = own
    np.testing.assert_array_equal(
        reward(obs, action, 1), emgail_jax.load_reward(str(tiny_run), seed=1)(obs, action, 1)
    )
    with pytest.raises(RunError, match="got seed 0"):
        emgail_jax.load_reward(str(renumbered_run), seed=0)


def _learned(state):
    return {
        name: getattr(state, name) for name in ("policy", "normalizer", "intention_weights")
    } | {
        "discriminator": state.discriminator.params,
        "posterior": state.posterior.params,
    }


def _equal(a, b) -> bool:
    leaves = zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True)
    return all(np.array_equal(x, y) for x, y in leaves)


def test_snapshots_are_kept_at_every_multiple_and_the_last_is_the_final_state(tiny_run, saved):
    from emgail_jax.host import checkpoints

    assert checkpoints.snapshot_iterations(str(tiny_run)) == [2, 4]
    last = SavedRun.open(str(tiny_run), snapshot=4)
    assert last.snapshot == 4 and _equal(_learned(last.state), _learned(saved.state))


def test_a_snapshot_replaces_the_learned_networks_only(tiny_run, saved):
    earlier = SavedRun.open(str(tiny_run), snapshot=2)
    assert not _equal(earlier.state.discriminator.params, saved.state.discriminator.params)
    assert not _equal(earlier.state.policy, saved.state.policy)
    assert _equal(earlier.state.value, saved.state.value)  # the checkpoint's, not learned
    obs = np.asarray(saved.demonstration_pairs.observations[:5])
    actions = np.asarray(saved.demonstration_pairs.actions[:5])
    assert not np.allclose(earlier.reward(0)(obs, actions, 0), saved.reward(0)(obs, actions, 0))


def test_a_missing_snapshot_is_a_clear_error(tiny_run):
    from emgail_jax.host.checkpoints import CheckpointError

    with pytest.raises(
        CheckpointError, match=r"no snapshot of iteration 3 \(snapshots kept: 2, 4\)"
    ):
        SavedRun.open(str(tiny_run), snapshot=3)


def test_reward_function_takes_any_seeds_parameters(saved):
    obs = np.asarray(saved.demonstration_pairs.observations[:5])
    actions = np.asarray(saved.demonstration_pairs.actions[:5])
    reward = jax.jit(saved.reward_function())
    for seed in (0, 1):
        np.testing.assert_allclose(
            reward(saved.reward_parameters(seed), obs, actions, 1),
            saved.reward(seed)(obs, actions, 1),
            rtol=1e-6,
        )


def test_aligned_intentions_pair_the_intentions_holding_the_same_demonstrations(saved):
    gamma = [np.asarray(saved.responsibilities(seed).gamma) for seed in (0, 1)]
    aligned = saved.aligned_intentions(1)
    assert aligned.shape == (2, 2)
    np.testing.assert_array_equal(aligned[1], [0, 1])  # a seed is its own alignment
    overlap = lambda renaming: sum(gamma[1][:, i] @ gamma[0][:, renaming[i]] for i in range(2))
    assert overlap(aligned[0]) >= overlap(1 - aligned[0]) - 1e-6  # the other renaming's less


@pytest.mark.parametrize("jitted", [False, True])
def test_the_reward_across_seeds_is_the_mean_of_the_seeds_aligned_rewards(tiny_run, saved, jitted):
    pairs = saved.demonstration_pairs
    aligned = saved.aligned_intentions(1)
    shared = emgail_jax.load_reward(str(tiny_run), seed=1, across_seeds=True)
    shared = jax.jit(shared) if jitted else shared
    for i in range(2):
        every = [
            saved.reward(seed)(pairs.observations, pairs.actions, aligned[seed][i])
            for seed in (0, 1)
        ]
        assert not np.allclose(every[0], every[1])  # two seeds, two discriminators
        np.testing.assert_allclose(
            shared(pairs.observations, pairs.actions, i), np.mean(every, 0), rtol=1e-5
        )


@pytest.fixture(scope="module")
def airl_run(tmp_path_factory):
    """A finished tiny EM-GAIL driver run with AIRL's discriminator, its replay and gradient
    penalty on (the tiny run's sizes)."""
    from emgail_jax import run

    out = tmp_path_factory.mktemp("tiny") / "airl"
    args = [
        *("--env", "driver", "--seeds", "2", "--iterations", "4", "--num-envs", "2"),
        *("--rollout-length", "20", "--chunk-size", "2", "--snapshot-every", "2", "--quiet"),
        *("--set", "discriminator_form=airl", "--set", "discriminator_replay=2"),
        *("--set", "discriminator_gradient_penalty=0.1", "--out", str(out)),
    ]
    assert run.main(args) == 0
    return out


@pytest.mark.slow  # end to end (make test-slow); cheaper tests cover its parts
def test_an_airl_runs_reward_is_its_state_only_g(airl_run):
    """``reoptimize``'s reward of an AIRL run: g_i(s) of the normalised observation, whatever
    the action; no absorbing reward; the GAIL discriminator's readings refused."""
    from emgail_jax import reoptimize

    saved = SavedRun.open(str(airl_run))
    assert saved.absorbing_reward_function() is None
    obs = np.asarray(saved.demonstration_pairs.observations[:5])
    actions = np.asarray(saved.demonstration_pairs.actions[:5])
    reward = jax.jit(saved.reward_function())
    state = saved.seed_state(1)
    normalized = obs_norm.normalize(state.normalizer, obs, saved.config.method.networks.obs_clip)
    for intention in (0, 1):
        condition = jax.nn.one_hot(jnp.full(5, intention), 2)
        g = saved.networks.discriminator.apply(
            state.discriminator.params, normalized, condition, method="reward"
        )
        got = reward(saved.reward_parameters(1), obs, actions, intention)
        np.testing.assert_allclose(got, g, rtol=1e-5)
        np.testing.assert_allclose(saved.reward(1)(obs, -actions, intention), got, rtol=1e-5)
    assert np.all(np.isfinite(saved.history["discriminator/loss"]))
    assert reoptimize.main([str(airl_run), "--set", "reward_form=logit"]) == 2


@pytest.mark.slow  # a fresh agent compiled and trained on the AIRL run's reward
def test_an_airl_runs_check_says_its_fresh_agents_were_paid_g(airl_run):
    import json

    from emgail_jax import reoptimize

    args = [str(airl_run), "--seed", "0", "--iterations", "2", "--no-baseline", "--quiet"]
    assert reoptimize.main(args) == 0
    result = json.loads((airl_run / "reoptimize-seed-0-it-2.json").read_text())
    assert result["reward_form"] == "airl-g" and result["seeds"] == [0]
