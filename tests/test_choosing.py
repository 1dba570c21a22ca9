import jax.numpy as jnp
import numpy as np
import pytest

from emgail_jax.method.choosing import (
    agreed_groups,
    consensus_intentions,
    demonstration_intentions,
    holds_demonstrations,
    kept_share,
)


def test_an_intention_holds_demonstrations_from_half_a_demonstration_share():
    # 10 demonstrations: an intention is kept from a weight of 1/20 on.
    weights = jnp.array([0.6, 0.349, 0.05, 0.001])
    assert kept_share(10) == pytest.approx(0.05)
    np.testing.assert_array_equal(holds_demonstrations(weights, 10), [True, True, True, False])
    np.testing.assert_array_equal(holds_demonstrations(weights, 5), [True, True, False, False])


def test_a_demonstration_goes_to_the_held_intention_with_most_responsibility():
    gamma = np.array([[0.6, 0.4, 0.0], [0.2, 0.3, 0.5], [0.1, 0.1, 0.8], [0.1, 0.2, 0.7]])
    episode = np.array([0, 0, 1, 1])
    # Demonstration 0: 0.8, 0.7, 0.5; demonstration 1: 0.2, 0.3, 1.5.
    held = np.array([True, True, True])
    np.testing.assert_array_equal(demonstration_intentions(gamma, episode, 2, held), [0, 2])
    held = np.array([False, True, False])
    np.testing.assert_array_equal(demonstration_intentions(gamma, episode, 2, held), [1, 1])


# Two true intentions of 6 demonstrations each (0-5 and 6-11), 4 learned ones, 4 seeds: each
# seed splits the first true intention differently between two of its learned intentions.
SPLIT_SEEDS = np.array(
    [
        [0, 0, 0, 0, 2, 2, 1, 1, 1, 1, 1, 1],
        [3, 3, 0, 0, 0, 0, 2, 2, 2, 2, 2, 2],
        [1, 1, 1, 1, 1, 3, 0, 0, 0, 0, 0, 0],
        [0, 2, 0, 2, 0, 2, 3, 3, 3, 3, 3, 3],
    ]
)


def test_the_seeds_agree_on_the_true_intentions_when_each_splits_one_differently():
    groups = agreed_groups(SPLIT_SEEDS, 4)
    assert len(set(groups[:6])) == 1 and len(set(groups[6:])) == 1
    assert groups[0] != groups[6]


def test_one_seed_of_four_merging_two_intentions_does_not_merge_them():
    labels = np.array([[0] * 4 + [1] * 4, [0] * 4 + [1] * 4, [2] * 4 + [3] * 4, [1] * 8])
    groups = agreed_groups(labels, 4)
    assert len(set(groups[:4])) == 1 and len(set(groups[4:])) == 1
    assert groups[0] != groups[4]


def test_a_split_every_seed_makes_is_kept():
    """Three groups of 4 demonstrations, told apart by every seed (under other numbers): three
    intentions, whatever the seeds call them."""
    labels = np.array([[0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2, 2], [3, 3, 3, 3, 0, 0, 0, 0, 1, 1, 1, 1]])
    groups = agreed_groups(labels, 4)
    assert len(set(groups)) == 3
    np.testing.assert_array_equal(groups[::4] == groups[1::4], [True, True, True])


def test_consensus_keeps_per_seed_the_intention_holding_most_of_each_group():
    weights = np.array(
        [
            [0.3, 0.5, 0.15, 0.05],
            [0.1, 0.0, 0.5, 0.4],
            [0.45, 0.5, 0.0, 0.05],
            [0.25, 0.5, 0.2, 0.05],
        ]
    )
    kept = consensus_intentions(SPLIT_SEEDS, weights)
    expected = [
        [True, True, False, False],  # 0 holds 4 of the first group, 2 holds 2
        [True, False, True, False],  # 0 holds 4, 3 holds 2
        [True, True, False, False],  # 1 holds 5, 3 holds 1
        [True, False, False, True],  # 0 and 2 hold 3 each: 0 is heavier
    ]
    np.testing.assert_array_equal(kept, expected)


def test_one_seed_keeps_every_intention_holding_a_demonstration():
    kept = consensus_intentions(SPLIT_SEEDS[:1], np.array([[0.4, 0.45, 0.15, 0.001]]))
    np.testing.assert_array_equal(kept, [[True, True, True, False]])
