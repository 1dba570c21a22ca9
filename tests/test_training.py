"""One training iteration (rollout, E-step, M-step, B-step, metrics) on a tiny driver config:
the train state, the metrics, jit against no jit, GAIL's missing posterior and unlabelled
demonstrations."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from emgail_jax.method import demonstrations
from emgail_jax.method import normalizer as obs_norm
from emgail_jax.method.batches import DemonstrationPairs
from emgail_jax.method.config import RunConfig
from emgail_jax.method.demonstrations import Demonstrations
from emgail_jax.method.rollout import intention_major
from emgail_jax.method.training import (
    RunData,
    TrainState,
    make_networks,
    make_policy_stages,
    normalized_batch,
    responsibilities_of,
    training_env,
)
from emgail_jax.variants import hooks_for, make_train

pytestmark = pytest.mark.heavy

K, B, T = 2, 2, 10
RANDOM_RETURNS = np.array([-300.0, -250.0])
CONFIG = RunConfig().with_values(
    num_envs=B,
    rollout_length=T,
    hidden=(8,),
    discriminator_steps=2,
    posterior_steps=2,
    value_epochs=1,
    value_minibatches=2,
)
COMMON_KEYS = {
    "eval/erd",
    "eval/erd_per_intention",
    "eval/cluster_accuracy",
    "eval/returns",
    "eval/matching",
    "train/pseudo_reward",
    "discriminator/loss",
    "discriminator/expert_d",
    "discriminator/policy_d",
    "policy/kl",
    "policy/entropy",
    "policy/accepted",
    "value/loss",
    "value/loss_before",
}
POSTERIOR_KEYS = {"posterior/loss", "posterior/policy_accuracy"}


@pytest.fixture(scope="module")
def env():
    return envs.make("driver", intentions=K)


@pytest.fixture(scope="module")
def demos(env):
    return demonstrations.generate(env, env.expert_policy, 2, jax.random.PRNGKey(0))


@pytest.fixture(scope="module")
def expert(demos):
    return DemonstrationPairs.create(demos, RANDOM_RETURNS, K)


def _train(config, env, expert, iterations, evaluating=(True, False)):
    """``(state_0, [(state_i, metrics_i)] for i = 1..iterations)`` with jitted init/update;
    iteration i evaluates if ``evaluating[i]``."""
    init, update = make_train(config.method, env)
    data = RunData.create(expert, env, config.info_weight)
    state = jax.jit(init)(jax.random.PRNGKey(0), data)
    step = jax.jit(update)
    steps = []
    for i in range(iterations):
        previous = steps[-1][0] if steps else state
        state_next, metrics = step(previous, jnp.bool_(evaluating[i]), data)
        steps.append((state_next, jax.device_get(metrics)))
    return state, steps, (init, update, data)


@pytest.fixture(scope="module")
def emgail(env, expert):
    """Two iterations, the first with the evaluation episodes and the second without."""
    return _train(CONFIG, env, expert, 2)


@pytest.fixture(scope="module")
def gail(env, expert):
    return _train(CONFIG.with_values(algo="gail"), env, expert, 1)


def _leaves(tree):
    return jax.tree.leaves(tree)


def _first_kernel(params):
    """The first kernel: ``[K, in, out]`` with one head per intention, else ``[in, out]``."""
    layers = params["params"]
    return (layers["heads"] if "heads" in layers else layers["MLP_0"])["Dense_0"]["kernel"]


def _initial_shapes(config, env, expert):
    """The shapes and dtypes of ``config``'s initial train state, traced, not compiled."""
    init, _ = make_train(config.method, env)
    data = RunData.create(expert, env, config.info_weight)
    return jax.eval_shape(init, jax.random.PRNGKey(0), data)


@pytest.fixture(scope="module")
def emgail_onehot(env, expert):
    return _train(CONFIG.with_values(intention_input="onehot"), env, expert, 1)


@pytest.fixture(scope="module")
def emgail_pair(env, expert):
    """The paper's per-pair E-step (eq. 18); the default is trajectory responsibilities."""
    return _train(CONFIG.with_values(responsibilities="pair"), env, expert, 1)


# ---- DemonstrationPairs --------------------------------------------------------------------------


def test_demonstration_pairs_from_labelled_demos(demos, expert):
    n = len(demos)
    assert expert.observations.shape == (n, 10) and expert.observations.dtype == np.float32
    assert expert.actions.shape == (n, 1) and expert.actions.dtype == np.float32
    assert expert.labels.dtype == np.int32
    np.testing.assert_array_equal(expert.labels, demos.intentions)
    # Episode index of every pair: 0, 0, ..., 1, 1, ... from the episode starts.
    np.testing.assert_array_equal(expert.episode, np.cumsum(demos.episode_starts) - 1)
    assert expert.episode.min() == 0 and demos.episode_starts[0]
    np.testing.assert_allclose(expert.expert_returns, demos.expert_returns)
    np.testing.assert_allclose(expert.random_returns, RANDOM_RETURNS)
    # Host arrays, compiled into the update as constants (see DemonstrationPairs).
    assert isinstance(expert.observations, np.ndarray)
    assert expert.episodes == 2 * K and expert.has_labels


def test_demonstration_pairs_from_unlabelled_demos(demos):
    bare = Demonstrations(demos.observations, demos.actions, demos.episode_starts)
    expert = DemonstrationPairs.create(bare, RANDOM_RETURNS, K)
    assert not expert.has_labels
    np.testing.assert_array_equal(expert.labels, np.full(len(demos), -1))
    assert expert.expert_returns.shape == (K,) and np.all(np.isnan(expert.expert_returns))
    labels_only = Demonstrations(
        demos.observations, demos.actions, demos.episode_starts, demos.intentions
    )
    expert = DemonstrationPairs.create(labels_only, RANDOM_RETURNS, K)
    np.testing.assert_array_equal(expert.labels, demos.intentions)
    assert np.all(np.isnan(expert.expert_returns))


# ---- init -------------------------------------------------------------------------------


def test_init_gives_a_finite_state_with_k_by_b_envs(emgail):
    state, _, _ = emgail
    assert isinstance(state, TrainState)
    assert all(np.all(np.isfinite(leaf)) for leaf in _leaves(state))
    assert state.env_state.obs.shape == (K, B, 10)
    assert state.env_state.done.shape == (K, B)
    np.testing.assert_array_equal(state.env_state.info["steps"], np.zeros((K, B)))
    assert int(state.iteration) == 0 and state.iteration.dtype == jnp.int32
    assert float(state.normalizer.count) == 0.0
    np.testing.assert_allclose(
        state.policy["params"]["log_std"], [CONFIG.method.networks.init_log_std]
    )
    assert state.posterior is not None and state.posterior.opt_state is not None


def test_init_network_inputs_follow_the_algorithm(env, expert, emgail):
    heads = emgail[0]
    onehot = _initial_shapes(CONFIG.with_values(intention_input="onehot"), env, expert)
    gail_state = _initial_shapes(CONFIG.with_values(algo="gail"), env, expert)
    obs, act = 10, 1
    # EM-GAIL: pi(a | s, i), V(s, i, t) and D(s, a, i), with one head per intention (default)
    # or a K one-hot input; V sees the time too.
    assert _first_kernel(heads.policy).shape == (K, obs, 8)
    assert _first_kernel(heads.value.params).shape == (K, obs + 1, 8)
    assert _first_kernel(heads.discriminator.params).shape == (K, obs + act, 8)
    assert _first_kernel(onehot.policy).shape == (obs + K, 8)
    assert _first_kernel(onehot.value.params).shape == (obs + 1 + K, 8)
    assert _first_kernel(onehot.discriminator.params).shape == (obs + act + K, 8)
    # P(i | s, a) is not conditioned; GAIL conditions nothing and has no posterior.
    assert _first_kernel(heads.posterior.params).shape == (obs + act, 8)
    assert _first_kernel(gail_state.policy).shape == (obs, 8)
    assert _first_kernel(gail_state.discriminator.params).shape == (obs + act, 8)
    assert gail_state.posterior is None


@pytest.mark.slow  # a whole update; test_skeleton's and test_networks' one-hot cases cover it
def test_one_hot_intention_input_trains_too(emgail_onehot):
    _, steps, _ = emgail_onehot
    state, metrics = steps[0]
    assert all(np.all(np.isfinite(leaf)) for leaf in _leaves(state))
    assert set(metrics) >= COMMON_KEYS | POSTERIOR_KEYS
    assert float(metrics["policy/accepted"]) == 1.0


def test_init_depends_on_the_key(emgail):
    state, _, (init, _, data) = emgail
    again = jax.jit(init)(jax.random.PRNGKey(0), data)
    other = jax.jit(init)(jax.random.PRNGKey(1), data)
    for a, b in zip(_leaves(state), _leaves(again), strict=True):
        np.testing.assert_array_equal(a, b)
    assert not np.allclose(_first_kernel(state.policy), _first_kernel(other.policy))
    assert not np.allclose(state.env_state.obs, other.env_state.obs)


# ---- update -----------------------------------------------------------------------------


EVAL_KEYS = {"eval/erd", "eval/erd_per_intention", "eval/returns", "eval/matching"}


def test_update_metrics_have_the_documented_keys_and_shapes(emgail):
    _, steps, _ = emgail
    for _, metrics in steps:
        assert set(metrics) >= COMMON_KEYS | POSTERIOR_KEYS
        for name, value in metrics.items():
            per_intention = (
                "eval/returns",
                "eval/matching",
                "eval/erd_per_intention",
                "reseed/demonstrations",
            )
            expected = (K,) if name in per_intention else ()
            assert np.shape(value) == expected, name
    evaluated, skipped = (metrics for _, metrics in steps)
    for name, value in evaluated.items():
        assert np.all(np.isfinite(value)), name
    assert sorted(evaluated["eval/matching"]) == list(range(K))
    # Without evaluation: NaN (matching -1), never stale values; the rest is measured.
    for name, value in skipped.items():
        if name == "eval/matching":
            np.testing.assert_array_equal(value, [-1] * K)
        elif name in EVAL_KEYS:
            assert np.all(np.isnan(value)), name
        else:
            assert np.all(np.isfinite(value)), name


def test_update_respects_the_trust_region(emgail):
    _, steps, _ = emgail
    for _, metrics in steps:
        assert 0.0 <= metrics["policy/kl"] <= CONFIG.method.b_step.trpo.max_kl * (1 + 1e-3)


def test_erd_is_the_mean_normalised_gap_of_the_matched_returns(emgail, expert):
    _, [(_, metrics), _], _ = emgail
    gaps = np.abs(expert.expert_returns - metrics["eval/returns"])
    scales = np.abs(expert.expert_returns - expert.random_returns)
    np.testing.assert_allclose(metrics["eval/erd_per_intention"], gaps / scales, rtol=1e-5)
    assert metrics["eval/erd"] == pytest.approx(np.mean(gaps / scales), rel=1e-5)
    # A driver return is minus a distance summed over 100 steps.
    assert np.all(metrics["eval/returns"] < 0)


def test_cluster_accuracy_is_a_fraction_of_the_expert_pairs(emgail, expert):
    _, steps, _ = emgail
    n = len(expert.labels)
    for _, metrics in steps:
        accuracy = metrics["eval/cluster_accuracy"]
        # With K = 2 the better of the two matchings gets at least half the pairs right.
        assert 0.5 <= accuracy <= 1.0
        assert accuracy * n == pytest.approx(round(accuracy * n), abs=1e-3)


def _with_log_std(state, log_std):
    """``state`` as an init with ``init_log_std=log_std`` gives it: the policy's log-std is its
    one parameter that setting changes, and the update never reads the setting."""
    fill = lambda path, leaf: jnp.full_like(leaf, log_std) if "log_std" in str(path) else leaf
    return state.replace(policy=jax.tree_util.tree_map_with_path(fill, state.policy))


def test_discriminator_and_posterior_see_the_executed_actions(env, emgail):
    """With a policy std of e^2, nearly every raw sample lies outside the action range [-1, 1];
    the batch the E-step and the M-step learn from (``normalized_batch``) holds them clipped, as
    the env executed them, while TRPO is handed the raw samples."""
    first, _, (_, update, data) = emgail
    config = CONFIG.with_values(init_log_std=2.0).method.resolved(env)
    # The run's own update, compiled once for the module (see _with_log_std).
    state = _with_log_std(first, 2.0)
    stages = make_policy_stages(config, env, make_networks(config, env))

    def seen(state, key):
        policy = stages.acting(state.policy, state.normalizer, explore=True)
        _, transitions = stages.collect(training_env(env, data), policy, state.env_state, key)
        normalizer = obs_norm.update(state.normalizer, transitions.obs)
        obs_clip = config.networks.obs_clip
        batch = normalized_batch(normalizer, transitions, data.demos, env, obs_clip)
        return transitions, batch

    transitions, batch = jax.jit(seen)(state, jax.random.PRNGKey(1))
    assert batch.extra is None  # nothing a variant attaches
    assert np.abs(transitions.action).max() > 2.0
    np.testing.assert_array_equal(
        batch.executed, np.clip(intention_major(transitions.action), -1.0, 1.0)
    )
    assert np.abs(batch.expert_actions).max() <= 1.0
    # TRPO saw the raw samples: their entropy is that of the wide Gaussian.
    _, metrics = jax.jit(update)(state, jnp.bool_(False), data)
    assert metrics["policy/entropy"] > 2.0


def test_update_advances_the_state(emgail):
    state0, steps, _ = emgail
    (state1, _), (state2, _) = steps
    assert (int(state1.iteration), int(state2.iteration)) == (1, 2)
    # T steps per rollout into 100-step episodes: no episode has ended yet.
    np.testing.assert_array_equal(state1.env_state.info["steps"], np.full((K, B), T))
    np.testing.assert_array_equal(state2.env_state.info["steps"], np.full((K, B), 2 * T))
    assert float(state1.normalizer.count) == T * K * B
    assert float(state2.normalizer.count) == 2 * T * K * B
    assert not np.array_equal(state0.key, state1.key)
    assert not np.array_equal(state1.key, state2.key)
    for name in ("policy", "value", "discriminator", "posterior"):
        before, after = getattr(state0, name), getattr(state1, name)
        changed = [
            not np.allclose(a, b) for a, b in zip(_leaves(before), _leaves(after), strict=True)
        ]
        assert any(changed), name
    assert all(np.all(np.isfinite(leaf)) for leaf in _leaves(state2))


@pytest.mark.slow  # a whole update; test_run's GAIL run checks the same in its summary and csv
def test_gail_has_no_posterior_and_no_accuracy(gail):
    _, [(state, metrics)], _ = gail
    assert state.posterior is None
    assert np.isnan(metrics["eval/cluster_accuracy"])
    assert not any(name.startswith("posterior/") for name in metrics)
    assert set(metrics) >= COMMON_KEYS
    assert metrics["eval/returns"].shape == (K,)
    for name, value in metrics.items():
        if name != "eval/cluster_accuracy":
            assert np.all(np.isfinite(value)), name
    assert 0.0 <= metrics["policy/kl"] <= CONFIG.method.b_step.trpo.max_kl * (1 + 1e-3)


@pytest.mark.slow  # two more compiles of the whole update (vmapped init and update)
def test_vmapped_update_over_seeds_equals_one_seed_at_a_time(env, expert, emgail):
    """The runner's form, vmap over seeds: seeds do not interact, so seed 0 of a batch of two
    is the single-seed run with the same key."""
    _, [(_, metrics), _], (init, update, data) = emgail
    keys = jnp.stack([jax.random.PRNGKey(0), jax.random.PRNGKey(1)])
    states = jax.jit(jax.vmap(init, in_axes=(0, None)))(keys, data)
    vmapped = jax.vmap(update, in_axes=(0, None, None))
    _, batched = jax.jit(vmapped)(states, jnp.bool_(True), data)
    for name in metrics:
        assert batched[name].shape == (2, *np.shape(metrics[name])), name
        np.testing.assert_allclose(batched[name][0], metrics[name], rtol=1e-4, atol=1e-5)
    assert not np.allclose(batched["discriminator/loss"][0], batched["discriminator/loss"][1])


@pytest.mark.slow  # op-by-op execution of a whole update takes about half a minute
def test_update_without_jit_equals_the_jitted_update(env, expert, gail):
    state0, [(state1, metrics)], _ = gail
    config = CONFIG.with_values(algo="gail")
    _, update = make_train(config.method, env)
    data = RunData.create(expert, env, config.info_weight)
    eager_state, eager_metrics = update(state0, jnp.bool_(True), data)
    assert set(eager_metrics) == set(metrics)
    for name in metrics:
        np.testing.assert_allclose(
            eager_metrics[name], metrics[name], rtol=1e-4, atol=1e-5, err_msg=name
        )
    for a, b in zip(_leaves(eager_state), _leaves(state1), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5)


@pytest.mark.slow  # a whole update of its own (make test-slow); cheaper tests cover its parts
def test_unlabelled_demos_give_nan_erd_and_accuracy(env, demos):
    bare = Demonstrations(demos.observations, demos.actions, demos.episode_starts)
    expert = DemonstrationPairs.create(bare, RANDOM_RETURNS, K)
    _, [(_, metrics)], _ = _train(CONFIG, env, expert, 1)
    assert np.isnan(metrics["eval/erd"])
    assert np.isnan(metrics["eval/cluster_accuracy"])
    # Training itself does not need labels or expert returns.
    for name in ("eval/returns", "posterior/loss", "discriminator/loss", "policy/kl"):
        assert np.all(np.isfinite(metrics[name])), name
    assert sorted(metrics["eval/matching"]) == list(range(K))


def test_trajectory_responsibilities_label_whole_demonstrations(emgail, expert):
    """With trajectory responsibilities every demonstration's pairs fall into one cluster, so
    the trajectory accuracy is a multiple of one demonstration's share of the pairs; the
    paper's accuracy (eq. 29) is still the posterior's own per-pair argmax."""
    _, steps, _ = emgail
    _, metrics = steps[0]
    episodes = expert.episodes
    assert episodes == int(expert.episode.max()) + 1
    accuracy = float(metrics["eval/trajectory_cluster_accuracy"])
    assert accuracy * episodes == pytest.approx(round(accuracy * episodes), abs=1e-4)
    n = len(expert.labels)
    per_pair = float(metrics["eval/cluster_accuracy"])
    assert per_pair * n == pytest.approx(round(per_pair * n), abs=1e-3)


def test_runs_that_differ_only_in_data_share_one_program(expert):
    """The driver's radius and Info/IntentionGAIL's lambda are data: the lowered update is the
    same program at another radius and another lambda (so the compilation cache serves both)."""
    config = CONFIG.with_values(algo="infogail")

    def lowered(radius, info_weight):
        env = envs.make("driver", intentions=K, radius=radius)
        init, update = make_train(config.method, env)
        data = RunData.create(expert, env, info_weight)
        state = jax.eval_shape(init, jax.random.PRNGKey(0), data)
        return jax.jit(update).lower(state, jnp.bool_(True), data).as_text()

    assert lowered(20.0, 1.0) == lowered(5.0, 0.3)


@pytest.mark.slow  # a whole update of its own (make test-slow); cheaper tests cover its parts
def test_pair_mode_logs_no_trajectory_accuracy(emgail_pair):
    _, [(_, metrics)], _ = emgail_pair
    assert "eval/trajectory_cluster_accuracy" not in metrics
    assert 0.0 <= float(metrics["eval/cluster_accuracy"]) <= 1.0


@pytest.mark.slow  # a whole update of its own (make test-slow); cheaper tests cover its parts
def test_reward_from_previous_changes_only_which_networks_score_the_reward(env, expert, emgail):
    """The M-step is the same either way; only the B-step's reward (and so the policy) differs:
    it comes from the discriminator and posterior before this iteration's E- and M-step."""
    _, updated, _ = emgail
    _, previous, _ = _train(CONFIG.with_values(reward_from="previous"), env, expert, 1)
    (state_updated, metrics_updated), (state_previous, metrics_previous) = updated[0], previous[0]
    for a, b in zip(
        _leaves(state_updated.discriminator), _leaves(state_previous.discriminator), strict=True
    ):
        np.testing.assert_array_equal(a, b)
    assert metrics_updated["discriminator/loss"] == metrics_previous["discriminator/loss"]
    assert metrics_updated["train/pseudo_reward"] != metrics_previous["train/pseudo_reward"]
    assert not np.array_equal(_leaves(state_updated.policy)[0], _leaves(state_previous.policy)[0])


@pytest.mark.slow  # end to end (make test-slow); cheaper tests cover its parts
def test_the_mixture_prior_carries_its_weights_from_one_e_step_to_the_next(env, expert, emgail):
    """Under the uniform prior the weights stay 1/K and are not logged; under the mixture prior
    each iteration's E-step re-estimates them and the next one starts from them."""
    first, [(uniform_state, uniform_metrics), _], _ = emgail
    np.testing.assert_array_equal(first.intention_weights, np.full(K, 1 / K, np.float32))
    np.testing.assert_array_equal(uniform_state.intention_weights, first.intention_weights)
    assert "posterior/intention_weights" not in uniform_metrics
    _, steps, _ = _train(CONFIG.with_values(prior="mixture"), env, expert, 2)
    for state, metrics in steps:
        weights = metrics["posterior/intention_weights"]
        assert weights.shape == (K,) and np.isclose(weights.sum(), 1.0, atol=1e-5)
        np.testing.assert_array_equal(state.intention_weights, weights)


def test_an_intention_emptied_by_the_posterior_is_re_seeded(emgail):
    """A posterior that gives every demonstration to intention 0 (a large bias on its logit,
    which 2 Adam steps per iteration cannot undo) leaves intention 1 empty; after `patience`
    E-steps it takes the worse-explained half of the demonstrations, for `window` E-steps.
    The run's own update (its settings' patience and window), compiled once for the module."""
    state, _, (_, update, data) = emgail
    e_step = CONFIG.method.resolved(envs.make("driver", intentions=K)).e_step
    patience, window = e_step.reseed_patience, e_step.reseed_window
    layers = state.posterior.params["params"]["MLP_0"]
    last = f"Dense_{len(CONFIG.method.networks.hidden)}"
    bias = layers[last]["bias"].at[0].add(30.0)
    params = {"params": {"MLP_0": {**layers, last: {**layers[last], "bias": bias}}}}
    state = state.replace(posterior=state.posterior.replace(params=params))
    step = jax.jit(update)
    history = []
    for _ in range(patience + window):
        state, metrics = step(state, jnp.bool_(False), data)
        history.append(jax.device_get(metrics))
    # The posterior's own responsibilities: every one of the 4 demonstrations in intention 0.
    for metrics in history:
        np.testing.assert_allclose(metrics["reseed/demonstrations"], [4.0, 0.0], atol=1e-3)
    waiting, reseeding = [-1] * (patience - 1), [1] * window
    assert [int(m["reseed/target"]) for m in history] == [*waiting, *reseeding, -1]
    assert [int(m["reseed/reseedings"]) for m in history] == [0] * (patience - 1) + [1] * (
        window + 1
    )
    assert int(state.reseeding.taken.sum()) == 2  # half of intention 0's demonstrations


@pytest.mark.parametrize(
    "algo",
    [
        "emgail",
        pytest.param("infogail", marks=pytest.mark.slow),
        pytest.param("gail", marks=pytest.mark.slow),
    ],
)
def test_a_replay_changes_only_the_m_steps_negatives(env, expert, request, algo):
    """With ``discriminator_replay`` the state carries the rollouts of the last R iterations
    (raw, intention-major) and the M-step sees more negatives; the E-step and every key are
    the run's without it. Off, the state holds no replay."""
    config = CONFIG.with_values(algo=algo, discriminator_replay=3)
    state0, [(state1, metrics), *_], _ = _train(config, env, expert, 1)
    replay = state1.negatives
    assert replay.obs.shape == (3, K, B * T, env.observation_size)
    assert int(replay.pushed) == 1 and not np.any(replay.obs[1:])
    # Slot 0 is the first rollout, time-major per intention: the envs' starts lead it.
    np.testing.assert_array_equal(replay.obs[0][:, :B], state0.env_state.obs)
    if algo == "infogail":  # Info/IntentionGAIL's run without a replay is not trained here
        return
    without = request.getfixturevalue(algo)  # GAIL's only when its slow case runs
    _, [(plain, plain_metrics), *_], _ = without
    assert plain.negatives is None
    np.testing.assert_array_equal(state1.key, plain.key)
    if algo != "gail":
        for a, b in zip(_leaves(state1.posterior), _leaves(plain.posterior), strict=True):
            np.testing.assert_array_equal(a, b)
    assert metrics["discriminator/loss"] != plain_metrics["discriminator/loss"]


@pytest.mark.slow  # a whole update of its own (make test-slow); cheaper tests cover its parts
@pytest.mark.parametrize("algo", ["emgail", "gail"])
def test_support_noise_changes_only_the_m_steps_negatives(env, expert, emgail, gail, algo):
    """With ``discriminator_support_noise`` the M-step sees noisy copies of its negatives too:
    its loss changes, while the state's structure, the E-step and every key are the run's
    without it."""
    config = CONFIG.with_values(algo=algo, discriminator_support_noise=0.5)
    _, [(state, metrics), *_], _ = _train(config, env, expert, 1)
    _, [(plain, plain_metrics), *_], _ = {"emgail": emgail, "gail": gail}[algo]
    assert jax.tree.structure(state) == jax.tree.structure(plain)
    np.testing.assert_array_equal(state.key, plain.key)
    np.testing.assert_array_equal(state.env_state.obs, plain.env_state.obs)
    if algo == "emgail":
        for a, b in zip(_leaves(state.posterior), _leaves(plain.posterior), strict=True):
            np.testing.assert_array_equal(a, b)
    assert metrics["discriminator/loss"] != plain_metrics["discriminator/loss"]


def test_absorbing_states_add_only_the_indicators_weights_and_the_replays_flags(env, expert):
    """Off, nothing of the state changes; on, the discriminator's first layer has one input
    more (so its Adam moments too) and a replay keeps each sample's termination flag."""
    data = RunData.create(expert, env, 1.0)

    def shapes(config):
        init = make_train(config.method, env).init
        return jax.eval_shape(init, jax.random.PRNGKey(0), data)

    plain = CONFIG.with_values(discriminator_replay=2)
    off = shapes(plain)
    assert jax.tree.map(jnp.shape, shapes(plain.with_values(absorbing_state=False))) == (
        jax.tree.map(jnp.shape, off)
    )
    on = shapes(plain.with_values(absorbing_state=True))
    assert off.negatives.terminal is None and on.negatives.terminal.shape == (2, K, B * T)
    on = on.replace(negatives=on.negatives.replace(terminal=None))
    paths = lambda tree: {
        jax.tree_util.keystr(path): leaf.shape
        for path, leaf in jax.tree_util.tree_leaves_with_path(tree)
    }
    off_shapes, on_shapes = paths(off), paths(on)
    assert off_shapes.keys() == on_shapes.keys()
    changed = {path for path in off_shapes if off_shapes[path] != on_shapes[path]}
    assert len(changed) == 3  # the kernel, and Adam's two moments of it
    for path in changed:
        assert "discriminator" in path and "Dense_0" in path and "kernel" in path
        assert on_shapes[path] == (K, 10 + 1 + 1, 8) and off_shapes[path] == (K, 10 + 1, 8)


@pytest.mark.slow  # end to end (make test-slow); cheaper tests cover its parts
def test_an_absorbing_run_learns_the_absorbing_states_reward(env, expert):
    """One iteration with absorbing states (and a replay): the M-step reports D of the
    absorbing state and the reward stage its reward. The driver never terminates, so every
    flag is 0 and the absorbing pair is only ever scored, never trained on."""
    config = CONFIG.with_values(absorbing_state=True, discriminator_replay=2)
    _, [(state, metrics)], _ = _train(config, env, expert, 1, (False,))
    assert {"discriminator/absorbing_d", "train/absorbing_reward"} <= set(metrics)
    assert 0.0 < metrics["discriminator/absorbing_d"] < 1.0
    assert metrics["train/absorbing_reward"] > 0.0  # -log(1 - D), the default form
    assert not np.any(state.negatives.terminal)
    assert all(np.all(np.isfinite(leaf)) for leaf in _leaves(state))


@pytest.mark.slow  # end to end (make test-slow); cheaper tests cover its parts
def test_a_tempered_e_step_weighs_the_evidence_by_the_iteration(env, expert, emgail):
    """``trajectory_temper_iterations``: the E-step of update n tempers by the beta of iteration
    n (``state.iteration`` before the update), and ``responsibilities_of`` the state after it
    gives back the demonstrations each intention held then; the untempered run's differ."""
    _, steps, _ = _train(CONFIG.with_values(trajectory_temper_iterations=4), env, expert, 2)
    config = CONFIG.method.replace(
        e_step=CONFIG.method.e_step.replace(trajectory_temper_iterations=4)
    ).resolved(env)
    hooks = hooks_for(config)
    networks = make_networks(config, env, hooks)
    for state, metrics in steps:
        held = responsibilities_of(networks, config, state, expert, hooks).gamma
        per_demonstration = jax.ops.segment_sum(held, expert.episode, expert.episodes)
        pairs = jax.ops.segment_sum(np.ones(len(expert.episode)), expert.episode, expert.episodes)
        np.testing.assert_allclose(
            (per_demonstration / pairs[:, None]).sum(0), metrics["reseed/demonstrations"], rtol=1e-4
        )
    _, untempered = emgail[1][0]
    assert not np.allclose(
        steps[0][1]["reseed/demonstrations"], untempered["reseed/demonstrations"]
    )


@pytest.mark.slow  # a whole update of its own (make test-slow); cheaper tests cover its parts
@pytest.mark.parametrize("algo", ["emgail", "gail"])
def test_airl_discriminator_trains_with_its_successors_and_log_densities(env, expert, algo):
    """``discriminator_form=airl``: g and h state-only networks, finite updates with the
    replay (its successors kept) and the gradient penalty on, and the B-step's reward the
    logit f - log pi of the rollout's own samples."""
    config = CONFIG.with_settings(
        [f"algo={algo}", "discriminator_form=airl", "discriminator_replay=2"]
    ).with_values(discriminator_gradient_penalty=0.1)
    state, steps, _ = _train(config, env, expert, 2)
    assert set(state.discriminator.params["params"]) == {"reward_net", "shaping_net"}
    assert state.negatives.successor.shape[-1] == env.observation_size + 1
    for _, metrics in steps:
        for key in ("discriminator/loss", "train/pseudo_reward", "discriminator/gradient_norm"):
            assert np.isfinite(metrics[key]), key
    assert 0 < metrics["discriminator/policy_d"] < 1
