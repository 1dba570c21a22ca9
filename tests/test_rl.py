"""Plain RL of one policy per intention (the experts' trainer and re-optimisation's)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from emgail_jax.host.seed_runner import chunks, run_chunks
from emgail_jax.method.config import Config
from emgail_jax.method.rl import intention_chunk, make_rl_train

CONFIG = Config(hidden=(8,), num_envs=2, rollout_length=10, value_epochs=1)


@pytest.fixture(scope="module")
def trainer():
    return make_rl_train(CONFIG, envs.make("driver"), eval_episodes=1)


def test_one_seed_chunk_trains_every_intention_on_its_own_reward(trainer):
    k = 2
    states = jax.jit(jax.vmap(trainer.init))(jax.random.split(jax.random.PRNGKey(0), k))
    chunk = intention_chunk(trainer, jnp.arange(k))
    seen = []
    record = lambda first, length, states, metrics: seen.append((first, metrics)) or True
    states = run_chunks(chunk, states, chunks(0, 4, 2), lambda f, n: np.zeros(n, bool), record)
    assert [first for first, _ in seen] == [0, 2]
    assert seen[0][1]["eval/returns"].shape == (2, k, k)  # [chunk, learned, true]
    # Each policy is scored on its own intention's reward.
    returns, own = seen[1][1]["eval/returns"], seen[1][1]["eval/own_return"]
    np.testing.assert_allclose(own, np.stack([returns[:, i, i] for i in range(k)], -1))
    assert np.asarray(states.iteration).tolist() == [4, 4]
