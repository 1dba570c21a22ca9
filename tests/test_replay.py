"""The M-step's replay of past policy samples: a ring of the last R iterations, drawn per
intention from the filled slots only."""

import jax
import jax.numpy as jnp
import numpy as np

from emgail_jax.method.batches import NormalizedBatch
from emgail_jax.method.normalizer import RunningStats
from emgail_jax.variants.extras import attached
from emgail_jax.variants.replay import Replay, with_replay

R, K, M, D, A = 3, 2, 4, 2, 1


def _samples(iteration: int):
    """``[K, M, D]``, ``[K, M, A]`` whose values name the iteration, intention and sample."""
    k, m = np.meshgrid(np.arange(K), np.arange(M), indexing="ij")
    code = 100 * iteration + 10 * k + m
    obs = np.stack([code, -code], -1).astype(np.float32)
    return jnp.asarray(obs), jnp.asarray(code[..., None], jnp.float32)


def _replay(pushed: int) -> Replay:
    replay = Replay.create(R, K, M, D, A, jax.random.PRNGKey(0))
    for iteration in range(1, pushed + 1):
        replay = replay.push(*_samples(iteration))
    return replay


def test_push_fills_the_oldest_slot():
    replay = _replay(4)  # iterations 1, 2, 3, then 4 over 1
    assert int(replay.pushed) == 4
    for slot, iteration in enumerate((4, 2, 3)):
        obs, executed = _samples(iteration)
        np.testing.assert_array_equal(replay.obs[slot], obs)
        np.testing.assert_array_equal(replay.executed[slot], executed)


def test_draws_come_from_filled_slots_under_their_own_intention():
    replay = _replay(2)
    replay_after, obs, executed, terminal, successor = replay.draw(500)
    assert terminal is None and replay.terminal is None  # no absorbing states
    assert successor is None and replay.successor is None  # no AIRL
    assert obs.shape == (K, 500, D) and executed.shape == (K, 500, A)
    code = np.asarray(executed[..., 0]).astype(int)
    assert set(np.unique(code // 100)) == {1, 2}  # never the empty third slot
    np.testing.assert_array_equal(
        code // 10 % 10, np.broadcast_to(np.arange(K)[:, None], code.shape)
    )
    np.testing.assert_array_equal(obs[..., 0], executed[..., 0])  # pairs stay pairs
    assert len(np.unique(code % 10)) == M
    _, again, *_ = replay_after.draw(500)
    assert not np.array_equal(again, obs)  # the key moves on


def test_with_replay_appends_as_many_normalised_draws():
    replay = _replay(1)
    obs, executed = _samples(2)
    stats = RunningStats.create(D)
    stats = stats.replace(mean=jnp.full(D, 1.0))
    normalize = lambda x: x - stats.mean
    seen = NormalizedBatch(
        normalizer=stats,
        obs=normalize(obs),
        executed=executed,
        expert_obs=jnp.zeros((3, D)),
        expert_actions=jnp.zeros((3, A)),
    )
    replay, negatives = with_replay(replay, seen, obs, normalize)
    assert int(replay.pushed) == 2
    assert negatives.obs.shape == (K, 2 * M, D) and negatives.executed.shape == (K, 2 * M, A)
    np.testing.assert_array_equal(negatives.obs[:, :M], seen.obs)
    drawn = np.asarray(negatives.executed[:, M:, 0]).astype(int)
    np.testing.assert_array_equal(negatives.obs[:, M:, 0], drawn - 1.0)  # normalised when drawn
    assert set(np.unique(drawn // 100)) <= {1, 2}
    np.testing.assert_array_equal(negatives.expert_obs, seen.expert_obs)


def test_termination_flags_travel_with_their_samples():
    """With absorbing states the replay keeps each sample's termination flag: a drawn
    terminated transition brings its absorbing negative along."""
    replay = Replay.create(R, K, M, D, A, jax.random.PRNGKey(0), absorbing=True)
    assert replay.terminal.shape == (R, K, M)
    even = lambda executed: (executed[..., 0] % 2 == 0).astype(jnp.float32)  # "terminated"
    for iteration in (1, 2):
        obs, executed = _samples(iteration)
        replay = replay.push(obs, executed, even(executed))
    _, obs, executed, terminal, _ = jax.jit(lambda r: r.draw(500))(replay)
    np.testing.assert_array_equal(terminal, even(executed))
    seen = NormalizedBatch(
        normalizer=RunningStats.create(D),
        obs=obs[:, :M],
        executed=executed[:, :M],
        expert_obs=jnp.zeros((3, D)),
        expert_actions=jnp.zeros((3, A)),
    )
    seen = attached(seen, terminal=even(executed[:, :M]), expert_terminal=jnp.zeros(3))
    _, negatives = with_replay(replay, seen, obs[:, :M], lambda x: x)
    assert negatives.extra.terminal.shape == (K, 2 * M)
    np.testing.assert_array_equal(negatives.extra.terminal, even(negatives.executed))


def test_successors_travel_with_their_samples_normalised_when_drawn():
    """With AIRL's discriminator the replay keeps each sample's raw successor; drawn, its
    next observation is normalised like the observations and its flag kept."""
    replay = Replay.create(R, K, M, D, A, jax.random.PRNGKey(0), successors=True)
    assert replay.successor.shape == (R, K, M, D + 1)
    obs, executed = _samples(1)
    raw = jnp.concatenate([obs + 1.0, (executed[..., :1] % 2 == 0).astype(jnp.float32)], -1)
    seen = NormalizedBatch(
        normalizer=None,
        obs=obs - 1.0,
        executed=executed,
        expert_obs=jnp.zeros((3, D)),
        expert_actions=jnp.zeros((3, A)),
    )
    seen = attached(
        seen,
        successor=jnp.concatenate([obs, raw[..., -1:]], -1),
        expert_successor=jnp.zeros((3, D + 1)),
    )
    normalize = lambda x: x - 1.0
    for jit in (False, True):
        together = lambda r: with_replay(r, seen, obs, normalize, raw)
        replay_after, negatives = (jax.jit(together) if jit else together)(replay)
        assert negatives.extra.successor.shape == (K, 2 * M, D + 1)
        drawn = negatives.extra.successor[:, M:]
        # Every sample's successor is its own observation + 1 (normalised: - 1), its flag its
        # action's parity.
        np.testing.assert_allclose(drawn[..., :-1], negatives.obs[:, M:] + 1.0)
        np.testing.assert_array_equal(
            drawn[..., -1], (negatives.executed[:, M:, 0] % 2 == 0).astype(np.float32)
        )
    assert int(replay_after.pushed) == 1
