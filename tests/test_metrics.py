"""ERD, clustering accuracy and separability (paper §5.2)."""

import functools
import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from emgail_jax.method import metrics

jit_accuracy = jax.jit(metrics.cluster_accuracy, static_argnums=2)
jit_erd = jax.jit(metrics.normalized_erd)


def test_permutations_are_all_distinct_orderings():
    perms = metrics.permutations(3)
    assert perms.shape == (6, 3)
    assert {tuple(p) for p in perms} == set(itertools.permutations(range(3)))


# ---- clustering accuracy --------------------------------------------------------------------


@pytest.mark.parametrize("k", [2, 3, 4])
def test_permuted_labelling_scores_one(k):
    rng = np.random.default_rng(k)
    labels = rng.integers(0, k, size=40)
    relabel = rng.permutation(k)
    while np.all(relabel == np.arange(k)):
        relabel = rng.permutation(k)
    predicted = relabel[labels]
    assert float(jit_accuracy(jnp.asarray(predicted), jnp.asarray(labels), k)) == 1.0
    assert metrics.hungarian_accuracy(predicted, labels, k) == 1.0


def test_hand_computed_confusion():
    labels = np.array([0, 0, 0, 0, 1, 1, 1, 2, 2, 2])
    predicted = np.array([1, 1, 1, 0, 2, 2, 0, 0, 0, 1])
    # Confusion (rows predicted, columns true):
    #   pred 0: [1, 1, 2]   pred 1: [3, 0, 1]   pred 2: [0, 2, 0]
    # Best one-to-one mapping: true 0 -> 1 (3), true 1 -> 2 (2), true 2 -> 0 (2): 7 / 10
    # (the identity mapping would get 1 + 0 + 0 = 1 / 10).
    expected = np.array([[1, 1, 2], [3, 0, 1], [0, 2, 0]], np.float32)
    np.testing.assert_array_equal(
        metrics.confusion_matrix(jnp.asarray(predicted), jnp.asarray(labels), 3), expected
    )
    assert float(jit_accuracy(jnp.asarray(predicted), jnp.asarray(labels), 3)) == pytest.approx(0.7)
    assert metrics.hungarian_accuracy(predicted, labels, 3) == pytest.approx(0.7)


def test_one_to_one_mapping_is_not_majority_vote():
    # Both true clusters are mostly predicted as 0; a one-to-one mapping can give 0 to only one.
    labels = np.array([0, 0, 0, 0, 1, 1, 1, 1])
    predicted = np.array([0, 0, 0, 1, 0, 0, 0, 1])
    # true 0 -> 0 (3) + true 1 -> 1 (1) = 4, or true 0 -> 1 (1) + true 1 -> 0 (3) = 4: 4 / 8.
    assert float(jit_accuracy(jnp.asarray(predicted), jnp.asarray(labels), 2)) == 0.5
    assert metrics.hungarian_accuracy(predicted, labels) == 0.5


@pytest.mark.parametrize("k", [2, 3, 4])
def test_enumeration_agrees_with_hungarian_on_random_labellings(k):
    rng = np.random.default_rng(10 + k)
    for _ in range(10):
        labels = rng.integers(0, k, size=25)
        predicted = rng.integers(0, k, size=25)
        enumerated = float(jit_accuracy(jnp.asarray(predicted), jnp.asarray(labels), k))
        assert enumerated == pytest.approx(metrics.hungarian_accuracy(predicted, labels, k))
        # The best of the K! mappings is at least their average, 1/K.
        assert enumerated >= 1.0 / k - 1e-6


def test_cluster_accuracy_jit_matches_eager():
    labels = jnp.array([0, 1, 2, 2, 1, 0, 0])
    predicted = jnp.array([2, 1, 0, 0, 0, 2, 1])
    eager = metrics.cluster_accuracy(predicted, labels, 3)
    assert float(eager) == pytest.approx(5 / 7)
    assert float(jit_accuracy(predicted, labels, 3)) == pytest.approx(float(eager))


# ---- normalised ERD -------------------------------------------------------------------------

EXPERT = jnp.array([10.0, 20.0, 30.0])
RANDOM = jnp.array([0.0, -5.0, 6.0])  # per-intention scales |J_E - J_rand|: 10, 25, 24


def test_erd_expert_returns_give_zero():
    returns = jnp.diag(EXPERT) + 3.0 * (1.0 - jnp.eye(3))  # learned i on true i is the expert
    erd, per_intention, matching = jit_erd(returns, EXPERT, RANDOM)
    assert float(erd) == 0.0
    np.testing.assert_array_equal(per_intention, [0.0, 0.0, 0.0])
    np.testing.assert_array_equal(matching, [0, 1, 2])


def test_erd_random_returns_give_one():
    returns = jnp.broadcast_to(RANDOM, (3, 3))  # every learned intention acts randomly
    erd, per_intention, _ = jit_erd(returns, EXPERT, RANDOM)
    assert float(erd) == pytest.approx(1.0)
    np.testing.assert_allclose(per_intention, [1.0, 1.0, 1.0], rtol=1e-6)


def test_erd_permuted_learned_order_is_matched_back():
    true_order = jnp.diag(EXPERT) + 3.0 * (1.0 - jnp.eye(3))
    learned_is_true = np.array([2, 0, 1])  # learned intention j imitates true intention p[j]
    returns = true_order[learned_is_true]
    erd, _, matching = jit_erd(returns, EXPERT, RANDOM)
    assert float(erd) == 0.0
    # matching[i] is the learned intention assigned to true i: the inverse permutation.
    np.testing.assert_array_equal(matching, np.argsort(learned_is_true))
    np.testing.assert_array_equal(matching, [1, 2, 0])


def test_erd_hand_computed_intermediate_values():
    expert = jnp.array([10.0, 20.0])
    random = jnp.array([0.0, 5.0])  # scales 10 and 15
    # Identity: e = (|10 - 8| / 10, |20 - 14| / 15) = (0.2, 0.4), mean 0.3;
    # swapped: (|10 - 1| / 10, |20 - 2| / 15) = (0.9, 1.2), mean 1.05.
    erd, per_intention, matching = jit_erd(jnp.array([[8.0, 2.0], [1.0, 14.0]]), expert, random)
    assert float(erd) == pytest.approx(0.3)
    np.testing.assert_allclose(per_intention, [0.2, 0.4], rtol=1e-6)
    np.testing.assert_array_equal(matching, [0, 1])
    # Identity: (0.9, 17 / 15), mean 1.0167; swapped: (|10 - 6| / 10, |20 - 17| / 15) =
    # (0.4, 0.2), mean 0.3.
    erd, per_intention, matching = jit_erd(jnp.array([[1.0, 17.0], [6.0, 3.0]]), expert, random)
    assert float(erd) == pytest.approx(0.3)
    np.testing.assert_allclose(per_intention, [0.4, 0.2], rtol=1e-6)
    np.testing.assert_array_equal(matching, [1, 0])


def test_erd_is_a_mean_of_ratios_not_a_ratio_of_sums():
    # Half-cheetah-like scales: intention 0 returns thousands, intention 1 tens.
    expert = jnp.array([2000.0, 40.0])
    random = jnp.array([0.0, -60.0])  # scales 2000 and 100
    # Intention 0 imitated to within 100, intention 1 no better than random.
    returns = jnp.array([[1900.0, -500.0], [-500.0, -60.0]])
    erd, per_intention, matching = jit_erd(returns, expert, random)
    np.testing.assert_array_equal(matching, [0, 1])
    np.testing.assert_allclose(per_intention, [0.05, 1.0], rtol=1e-6)
    assert float(erd) == pytest.approx(0.525)
    # The ratio of sums would hide the failed intention: (100 + 100) / 2100 = 0.095.
    ratio_of_sums = (100.0 + 100.0) / (2000.0 + 100.0)
    assert ratio_of_sums == pytest.approx(0.0952, abs=1e-4)


def test_erd_matching_minimises_the_mean_not_the_sum_of_gaps():
    # The matching that minimises the summed raw gaps is not the one that minimises the mean of
    # the normalised gaps, because the scales differ (10 and 1000).
    expert = jnp.array([10.0, 1000.0])
    random = jnp.array([0.0, 0.0])
    returns = jnp.array([[10.0, 1000.0], [0.0, 500.0]])  # [learned, true]
    # Identity: gaps (0, 500), normalised (0, 0.5), mean 0.25.
    # Swapped:  gaps (10, 0), normalised (1, 0),  mean 0.5, but the summed raw gap is smaller.
    erd, per_intention, matching = jit_erd(returns, expert, random)
    np.testing.assert_array_equal(matching, [0, 1])
    assert float(erd) == pytest.approx(0.25)
    np.testing.assert_allclose(per_intention, [0.0, 0.5])
    # And it is the best of all K! matchings, checked by brute force on random returns.
    rng = np.random.default_rng(0)
    for _ in range(20):
        returns = jnp.asarray(rng.normal(size=(3, 3)) * 20.0)
        erd, _, _ = jit_erd(returns, EXPERT, RANDOM)
        scale = np.abs(np.asarray(EXPERT - RANDOM))
        means = [
            np.mean(np.abs(np.asarray(EXPERT) - np.asarray(returns)[list(p), range(3)]) / scale)
            for p in itertools.permutations(range(3))
        ]
        assert float(erd) == pytest.approx(min(means), rel=1e-5)


def test_erd_of_a_single_policy_gail_style():
    # GAIL: one policy, every row identical; worse than random on intention 1 counts in full.
    row = jnp.array([10.0, -10.0, 30.0])
    erd, per_intention, _ = jit_erd(jnp.broadcast_to(row, (3, 3)), EXPERT, RANDOM)
    np.testing.assert_allclose(per_intention, [0.0, 30.0 / 25.0, 0.0], rtol=1e-6)
    assert float(erd) == pytest.approx(0.4)


def test_erd_jit_matches_eager():
    returns = jnp.array([[1.0, 17.0, 2.0], [6.0, 3.0, 9.0], [0.0, 4.0, 25.0]])
    eager = metrics.normalized_erd(returns, EXPERT, RANDOM)
    jitted = jit_erd(returns, EXPERT, RANDOM)
    np.testing.assert_allclose(eager.mean, jitted.mean, rtol=1e-6)
    np.testing.assert_allclose(eager.per_intention, jitted.per_intention, rtol=1e-6)
    np.testing.assert_array_equal(eager.matching, jitted.matching)


# ---- more intentions learned than demonstrated (--intentions auto) --------------------------


def test_matchings_are_the_one_to_one_maps_of_true_to_learned_intentions():
    maps = metrics.matchings(4, 2)
    assert maps.shape == (12, 2)  # 4 * 3
    assert {tuple(m) for m in maps} == set(itertools.permutations(range(4), 2))
    np.testing.assert_array_equal(metrics.matchings(3, 3), metrics.permutations(3))


def test_erd_matches_each_true_intention_to_its_own_learned_one_and_leaves_the_rest():
    expert, random = EXPERT[:2], RANDOM[:2]
    # Four learned intentions, two true: learned 3 is true 0's expert, learned 1 true 1's; the
    # columns past the true ones (the env's other intentions) do not count.
    returns = jnp.array(
        [[0.0, -5.0, 99.0], [3.0, 20.0, 99.0], [5.0, 0.0, 99.0], [10.0, 10.0, 99.0]]
    )
    erd = metrics.normalized_erd(returns, expert, random)
    np.testing.assert_array_equal(erd.matching, [3, 1])
    assert float(erd.mean) == 0.0
    # Learned 3 retired: true 0 takes the best learned one still in use (2: e = 0.5).
    in_use = jnp.array([True, True, True, False])
    erd = jax.jit(metrics.normalized_erd)(returns, expert, random, in_use)
    np.testing.assert_array_equal(erd.matching, [2, 1])
    np.testing.assert_allclose(erd.per_intention, [0.5, 0.0])
    # One kept for two true intentions: the other is scored as random actions (e = 1), even
    # though a retired one would have matched it better.
    erd = metrics.normalized_erd(returns, expert, random, jnp.array([False, True, False, False]))
    np.testing.assert_allclose(erd.per_intention, [1.0, 0.0])
    np.testing.assert_array_equal(erd.matching[1], 1)


def test_erd_with_every_intention_in_use_is_the_plain_erd():
    returns = jnp.array([[1.0, 17.0, 2.0], [6.0, 3.0, 9.0], [0.0, 4.0, 25.0]])
    plain = metrics.normalized_erd(returns, EXPERT, RANDOM)
    masked = metrics.normalized_erd(returns, EXPERT, RANDOM, jnp.ones(3, bool))
    np.testing.assert_array_equal(plain.per_intention, masked.per_intention)
    np.testing.assert_array_equal(plain.matching, masked.matching)


def test_cluster_accuracy_with_more_clusters_than_intentions():
    labels = jnp.array([0, 0, 0, 1, 1, 1])
    predicted = jnp.array([3, 3, 1, 1, 1, 2])  # true 0 -> cluster 3, true 1 -> cluster 1
    assert float(metrics.cluster_accuracy(predicted, labels, 4, 2)) == pytest.approx(4 / 6)
    assert metrics.hungarian_accuracy(predicted, labels) == pytest.approx(4 / 6)
    # Cluster 3 retired: its pairs count as misclustered, and true 0 takes cluster 1's one
    # pair of it, or another cluster: at best 1 + 1 (true 1 -> cluster 2) or 0 + 2.
    in_use = jnp.array([True, True, True, False])
    accuracy = jax.jit(metrics.cluster_accuracy, static_argnums=(2, 3))
    assert float(accuracy(predicted, labels, 4, 2, in_use)) == pytest.approx(2 / 6)


# ---- separability ---------------------------------------------------------------------------

separability = functools.partial(metrics.separability, seeds=(0, 1, 2))


def _blobs(offset: float, n: int = 300, seed: int = 0):
    rng = np.random.default_rng(seed)
    obs = rng.normal(size=(2 * n, 3))
    actions = rng.normal(size=(2 * n, 1))
    labels = np.repeat([0, 1], n)
    obs[labels == 1] += offset
    actions[labels == 1] += offset
    return obs, actions, labels


def test_separability_of_far_apart_blobs_is_one():
    mean, std = separability(*_blobs(offset=20.0))
    assert mean == pytest.approx(1.0, abs=1e-9)
    assert std == pytest.approx(0.0, abs=1e-9)


def test_separability_of_identical_distributions_is_near_zero():
    mean, _ = separability(*_blobs(offset=0.0))
    assert 0.0 <= mean < 0.15


def test_gaussian_mixture_accuracy_is_the_raw_accuracy_separability_normalises():
    """Table 3's GMM row is the raw accuracy; separability maps chance (1/K) to 0."""
    obs, actions, labels = _blobs(offset=1.5)
    accuracies = metrics.gaussian_mixture_accuracies(obs, actions, labels, seeds=(0, 1, 2))
    assert accuracies.shape == (3,)
    assert np.all((accuracies > 0.5) & (accuracies < 1.0))
    mean, _ = separability(obs, actions, labels)
    assert mean == pytest.approx(np.mean(2 * accuracies - 1))


def test_reward_difference_is_zero_at_the_expert_and_one_at_random():
    from emgail_jax.method.metrics import reward_difference

    expert, random = np.array([10.0, -2.0]), np.array([0.0, -12.0])
    np.testing.assert_allclose(reward_difference(expert, expert, random), [0, 0])
    np.testing.assert_allclose(reward_difference(random, expert, random), [1, 1])
    np.testing.assert_allclose(
        reward_difference(np.array([15.0, -7.0]), expert, random), [0.5, 0.5]
    )
