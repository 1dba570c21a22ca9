import jax
import jax.numpy as jnp
import numpy as np
import pytest

from emgail_jax.method.reseeding import (
    Reseeding,
    ReseedingRule,
    count_down,
    demonstration_responsibilities,
    held_responsibilities,
    reseeding_step,
    worse_half,
)

# 6 demonstrations of 2 pairs each, all held by intention 0 of 2: intention 1 is empty.
EPISODE = jnp.repeat(jnp.arange(6), 2)
COLLAPSED = jnp.tile(jnp.array([[1.0, 0.0]]), (12, 1))
# How badly intention 0 explains each demonstration: 1, 3 and 5 worst.
SCORES = jnp.array([0.1, 2.0, 0.3, 1.5, 0.2, 3.0])
RULE = ReseedingRule(patience=3, window=2, attempts=1)


def plain_step(memory, per_demonstration, scores, rule):
    return reseeding_step(memory, per_demonstration, lambda holder: scores, rule)


def e_steps(memory, gamma, steps, rule=RULE, scores=SCORES, step=plain_step):
    """``steps`` E-steps of a run whose posterior gives ``gamma`` every time: the gamma the
    M-step saw at each, and the memory after them."""
    seen = []
    for _ in range(steps):
        per_demonstration = demonstration_responsibilities(
            held_responsibilities(gamma, memory, EPISODE), EPISODE, 6
        )
        memory = step(memory, per_demonstration, scores, rule)
        seen.append(held_responsibilities(gamma, memory, EPISODE))
        memory = count_down(memory)
    return seen, memory


def test_demonstration_responsibilities_are_the_mean_over_their_pairs():
    gamma = jnp.array([[0.2, 0.8], [0.4, 0.6], [1.0, 0.0]])
    per_demonstration = demonstration_responsibilities(gamma, jnp.array([0, 0, 1]), 2)
    np.testing.assert_allclose(per_demonstration, [[0.3, 0.7], [1.0, 0.0]])


def test_the_worse_explained_half_of_the_donor_is_taken():
    holder = jnp.array([0, 0, 0, 1, 0, 0])
    # The donor 0 holds 5: the 3 (rounded up) it explains worst (scores 3.0, 2.0, 0.3), never
    # another's (1.5).
    np.testing.assert_array_equal(
        worse_half(SCORES, holder, jnp.int32(0)), [False, True, True, False, False, True]
    )


def test_an_intention_empty_for_patience_e_steps_takes_the_worst_explained_half():
    seen, memory = e_steps(Reseeding.create(2, 6), COLLAPSED, 2)
    for gamma in seen:  # not yet: the gamma passes through
        np.testing.assert_array_equal(gamma, COLLAPSED)
    seen, memory = e_steps(memory, COLLAPSED, 3)
    taken = np.repeat([False, True, False, True, False, True], 2)
    expected = np.where(taken[:, None], [0.0, 1.0], [1.0, 0.0])
    # Held for the window (2 E-steps), then the posterior's gamma again.
    np.testing.assert_array_equal(seen[0], expected)
    np.testing.assert_array_equal(seen[1], expected)
    np.testing.assert_array_equal(seen[2], COLLAPSED)
    np.testing.assert_array_equal(memory.reseedings, [0, 1])
    assert int(memory.target) == -1


def test_the_split_teaches_the_taken_as_the_target_and_the_rest_as_the_donor():
    # Demonstration 0 is intention 1's; 1-5 are the donor 0's, of which 1, 3, 5 are taken
    # for the emptied intention 2 (of 3).
    gamma = jnp.where((EPISODE == 0)[:, None], jnp.array([0.0, 1.0, 0.0]), jnp.array([1.0, 0, 0]))
    _, memory = e_steps(Reseeding.create(3, 6), gamma, 3)
    assert int(memory.target) == 2 and int(memory.donor) == 0
    np.testing.assert_array_equal(memory.split, [False, True, True, True, True, True])
    np.testing.assert_array_equal(memory.taken, [False, True, False, True, False, True])
    np.testing.assert_array_equal(memory.taught_intentions()[1:], [2, 0, 2, 0, 2])


def test_an_intention_is_re_seeded_at_most_attempts_times():
    _, memory = e_steps(Reseeding.create(2, 6), COLLAPSED, 14)
    np.testing.assert_array_equal(memory.reseedings, [0, 1])
    rule = ReseedingRule(patience=3, window=2, attempts=2)
    _, memory = e_steps(Reseeding.create(2, 6), COLLAPSED, 14, rule)
    np.testing.assert_array_equal(memory.reseedings, [0, 2])


def test_no_intention_empty_leaves_gamma_and_memory_alone():
    gamma = jnp.where((EPISODE < 3)[:, None], jnp.array([0.9, 0.1]), jnp.array([0.2, 0.8]))
    seen, memory = e_steps(Reseeding.create(2, 6), gamma, 20)
    for held in seen:
        np.testing.assert_array_equal(held, gamma)
    assert int(memory.empty_for) == 0 and int(memory.reseedings.sum()) == 0


def test_whole_sets_moving_between_intentions_still_count_as_one_emptied():
    """A collapsed set can move whole from one intention to the other every E-step; an
    intention is empty all along."""
    flipped = 1.0 - COLLAPSED
    memory = Reseeding.create(2, 6)
    for gamma in (COLLAPSED, flipped, COLLAPSED):
        _, memory = e_steps(memory, gamma, 1)
    assert int(memory.reseedings.sum()) == 1


def test_the_jitted_rule_equals_the_plain_one():
    step = jax.jit(plain_step, static_argnums=(3,))
    plain_seen, plain = e_steps(Reseeding.create(2, 6), COLLAPSED, 6)
    jitted_seen, jitted = e_steps(Reseeding.create(2, 6), COLLAPSED, 6, step=step)
    for a, b in zip(plain_seen, jitted_seen, strict=True):
        np.testing.assert_array_equal(a, b)
    jax.tree.map(np.testing.assert_array_equal, plain, jitted)


@pytest.mark.parametrize("field", ["reseed_patience", "reseed_window"])
def test_the_rule_needs_at_least_one_e_step(field):
    from emgail_jax.method.config import RunConfig

    with pytest.raises(ValueError, match=field):
        RunConfig().with_values(**{field: 0})
