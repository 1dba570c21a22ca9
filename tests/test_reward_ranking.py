"""The ranking of a run's snapshots (and the demonstrations above them) as a discriminator loss."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from emgail_jax.reward.ranking import drawn_by_weight, ranked_levels, ranking_loss

K, S, M, N = 2, 5, 16, 12


def scaled_first_feature(params, obs, actions, conditions, intention_major=False):
    """A logit ``params * obs[..., 0]`` (the layout ``[K, M, ...]`` of the real heads)."""
    assert intention_major and obs.shape[:2] == actions.shape[:2] == conditions.shape[:2]
    return params * obs[..., 0]


def leveled_inputs(order=1.0, expert_weights=None):
    """Snapshot s's samples have first feature ``order * s``, the demonstrations
    ``order * (S + 1)``: ordered as the loss ranks them when ``order`` > 0."""
    level = np.arange(S, dtype=np.float32)[None, :, None, None]
    policy_obs = np.broadcast_to(order * level, (K, S, M, 3)).copy()
    weights = np.ones((N, K), np.float32) if expert_weights is None else expert_weights
    return dict(
        policy_obs=jnp.asarray(policy_obs),
        policy_actions=jnp.zeros((K, S, M, 1)),
        expert_obs=jnp.full((N, 3), order * (S + 1.0)),
        expert_actions=jnp.zeros((N, 1)),
        expert_weights=jnp.asarray(weights),
        condition_of=lambda intentions: jax.nn.one_hot(intentions, K),
        pairs=8,
        samples=4,
    )


@pytest.mark.parametrize("jitted", [False, True])
def test_ranked_levels_are_ordered_distinct_and_cover_every_pair(jitted):
    draw = jax.jit(ranked_levels, static_argnums=(1, 2)) if jitted else ranked_levels
    lower, upper = draw(jax.random.PRNGKey(0), (3000,), 3)
    assert bool(jnp.all(lower < upper)) and int(lower.min()) == 0 and int(upper.max()) == 2
    counts = np.unique(np.stack([lower, upper], 1), axis=0, return_counts=True)[1]
    assert len(counts) == 3 and counts.min() > 900  # (0, 1), (0, 2), (1, 2) alike


@pytest.mark.parametrize("jitted", [False, True])
def test_levels_in_their_order_are_ranked_and_reversed_ones_are_not(jitted):
    loss = lambda params, key, **inputs: ranking_loss(scaled_first_feature, params, key, **inputs)
    if jitted:
        loss = jax.jit(loss, static_argnames=("condition_of", "pairs", "samples"))
    key = jax.random.PRNGKey(1)
    ordered, ordered_metrics = loss(1.0, key, **leveled_inputs(1.0))
    reversed_, reversed_metrics = loss(1.0, key, **leveled_inputs(-1.0))
    assert float(ordered_metrics["ranking/accuracy"]) == 1.0
    assert float(ordered_metrics["ranking/expert_accuracy"]) == 1.0
    assert float(reversed_metrics["ranking/accuracy"]) == 0.0
    assert float(ordered) < np.log(2) < float(reversed_)
    assert float(ordered_metrics["ranking/loss"]) == pytest.approx(float(ordered))


def test_the_gradient_steepens_a_reward_that_already_ranks_the_levels():
    inputs = leveled_inputs(1.0)

    def loss(params):
        return ranking_loss(scaled_first_feature, params, jax.random.PRNGKey(2), **inputs)[0]

    assert float(jax.grad(loss)(0.5)) < 0


def test_an_intention_that_holds_no_demonstration_still_gives_a_finite_loss():
    weights = np.ones((N, K), np.float32)
    weights[:, 1] = 0.0
    loss, metrics = ranking_loss(
        scaled_first_feature, 1.0, jax.random.PRNGKey(3), **leveled_inputs(1.0, weights)
    )
    assert np.isfinite(float(loss)) and float(metrics["ranking/expert_accuracy"]) == 1.0


@pytest.mark.parametrize("jitted", [False, True])
def test_demonstrations_are_drawn_in_proportion_to_their_weight(jitted):
    draw = jax.jit(drawn_by_weight, static_argnums=2) if jitted else drawn_by_weight
    weights = jnp.array([[1.0, 0.0], [0.0, 0.0], [3.0, 0.0]])  # intention 1 holds none
    rows = np.asarray(draw(jax.random.PRNGKey(4), weights, (4000,)))
    assert rows.shape == (2, 4000)
    first = np.bincount(rows[0], minlength=3) / 4000
    assert first[1] == 0 and first[0] == pytest.approx(0.25, abs=0.03)
    assert np.bincount(rows[1], minlength=3).min() > 1100  # the emptied column: all alike
