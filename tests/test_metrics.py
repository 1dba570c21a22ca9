"""ERD, clustering accuracy and separability (paper §5.2)."""

import functools
import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from emgail_jax import metrics

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
RANDOM = jnp.array([0.0, -5.0, 6.0])  # scale = 10 + 25 + 24 = 59


def test_erd_expert_returns_give_zero():
    returns = jnp.diag(EXPERT) + 3.0 * (1.0 - jnp.eye(3))  # learned i on true i is the expert
    erd, matching = jit_erd(returns, EXPERT, RANDOM)
    assert float(erd) == 0.0
    np.testing.assert_array_equal(matching, [0, 1, 2])


def test_erd_random_returns_give_one():
    returns = jnp.broadcast_to(RANDOM, (3, 3))  # every learned intention acts randomly
    erd, _ = jit_erd(returns, EXPERT, RANDOM)
    assert float(erd) == pytest.approx(1.0)


def test_erd_permuted_learned_order_is_matched_back():
    true_order = jnp.diag(EXPERT) + 3.0 * (1.0 - jnp.eye(3))
    learned_is_true = np.array([2, 0, 1])  # learned intention j imitates true intention p[j]
    returns = true_order[learned_is_true]
    erd, matching = jit_erd(returns, EXPERT, RANDOM)
    assert float(erd) == 0.0
    # matching[i] is the learned intention assigned to true i: the inverse permutation.
    np.testing.assert_array_equal(matching, np.argsort(learned_is_true))
    np.testing.assert_array_equal(matching, [1, 2, 0])


def test_erd_hand_computed_intermediate_values():
    expert = jnp.array([10.0, 20.0])
    random = jnp.array([0.0, 5.0])  # scale |10 - 0| + |20 - 5| = 25
    # Identity: |10 - 8| + |20 - 14| = 8 ; swapped: |10 - 1| + |20 - 2| = 27  -> 8 / 25.
    erd, matching = jit_erd(jnp.array([[8.0, 2.0], [1.0, 14.0]]), expert, random)
    assert float(erd) == pytest.approx(0.32)
    np.testing.assert_array_equal(matching, [0, 1])
    # Identity: |10 - 1| + |20 - 3| = 26 ; swapped: |10 - 6| + |20 - 17| = 7  -> 7 / 25.
    erd, matching = jit_erd(jnp.array([[1.0, 17.0], [6.0, 3.0]]), expert, random)
    assert float(erd) == pytest.approx(0.28)
    np.testing.assert_array_equal(matching, [1, 0])


def test_erd_of_a_single_policy_gail_style():
    # GAIL: one policy, every row identical; worse than random on intention 1 counts in full.
    row = jnp.array([10.0, -10.0, 30.0])
    erd, _ = jit_erd(jnp.broadcast_to(row, (3, 3)), EXPERT, RANDOM)
    assert float(erd) == pytest.approx(30.0 / 59.0)


def test_erd_jit_matches_eager():
    returns = jnp.array([[1.0, 17.0, 2.0], [6.0, 3.0, 9.0], [0.0, 4.0, 25.0]])
    eager = metrics.normalized_erd(returns, EXPERT, RANDOM)
    jitted = jit_erd(returns, EXPERT, RANDOM)
    np.testing.assert_allclose(eager[0], jitted[0], rtol=1e-6)
    np.testing.assert_array_equal(eager[1], jitted[1])


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
