"""The fresh agents' reward is data: one compiled program trains them on whatever reward
parameters it is given, and other parameters pay another reward. A program that had captured
the parameters as constants (stale parameters inside the jitted loop) would pay the same."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from emgail_jax.host.saved_run import SavedRun, stacked
from emgail_jax.method.rl import seeds_chunk
from emgail_jax.reward import check

pytestmark = pytest.mark.heavy

# The budget of test_reoptimize's check of tiny_run (both seeds, 2 iterations, the run's discount):
# the same compiled programs, read from the compilation cache when that check made them first.
BUDGET = check.Budget(iterations=2, gamma=0.995, gae_lambda=0.97)
SEEDS = [0, 1]


@pytest.fixture(scope="module")
def saved(tiny_run):
    return SavedRun.open(str(tiny_run))


def other_parameters(parameters: dict) -> dict:
    """``parameters`` with every weight of the discriminator scaled: another reward."""
    scaled = jax.tree.map(lambda x: x * np.float32(1.5), parameters["discriminator"])
    return {**parameters, "discriminator": scaled}


@pytest.fixture(scope="module")
def fresh(saved):
    """``(trainer, initial states [S, K], the run's reward data [S, ...], another's)`` of the
    run seeds' fresh agents."""
    trainer = check.learned_reward_trainer(saved, BUDGET, saved.reward_function())
    states = jax.jit(jax.vmap(jax.vmap(trainer.init)))(check.fresh_keys(saved, SEEDS))
    own = [saved.reward_parameters(seed) for seed in SEEDS]
    return trainer, states, stacked(own), stacked([other_parameters(p) for p in own])


def test_one_compiled_program_trains_on_the_reward_parameters_it_is_given(saved, fresh):
    trainer, states, own, other = fresh
    chunk = seeds_chunk(trainer, jnp.arange(saved.num_intentions))
    scored = np.zeros(BUDGET.iterations, bool)  # no evaluation episodes: the reward is the point
    program = chunk.lower(states, scored, own).compile()
    ends, metrics = {}, {}
    for name, data in (("own", own), ("other", other), ("own again", own)):
        ends[name], metrics[name] = program(states, scored, data)
    earned = {name: np.asarray(m["train/reward"]) for name, m in metrics.items()}  # [L, S, K]
    np.testing.assert_array_equal(earned["own again"], earned["own"])
    # The first rollout is the same policies' on the same keys: only the reward pays otherwise.
    assert np.all(earned["other"][0] != earned["own"][0])
    policies = [jax.tree.leaves(ends[name].policy) for name in ("own", "other")]
    assert any(not np.array_equal(a, b) for a, b in zip(*policies, strict=True))
    # The jitted chunk, called on both, compiles once and pays what the program paid.
    for name, data in (("own", own), ("other", other)):
        _, again = chunk(states, scored, data)
        np.testing.assert_array_equal(np.asarray(again["train/reward"]), earned[name])
    assert chunk._cache_size() == 1


def test_train_fresh_pays_the_reward_parameters_it_is_given(saved, fresh):
    trainer, _, own, other = fresh
    keys = check.fresh_keys(saved, SEEDS)
    train = lambda data: check.train_fresh(
        trainer, keys, data, BUDGET.iterations, label="", progress=False
    )
    paid_own, paid_other = train(own), train(other)
    assert np.all(paid_other.earned[:, 0] != paid_own.earned[:, 0])
    assert not np.array_equal(paid_other.returns[:, -1], paid_own.returns[:, -1])


def test_the_check_hands_the_parameters_it_is_given_to_the_fresh_agents(saved, monkeypatch):
    """``reoptimize(parameters=...)`` (a refit's) trains on those, not on the run's own."""
    given = [other_parameters(saved.reward_parameters(seed)) for seed in (0, 1)]
    handed = {}

    class Handed(Exception):
        pass

    def train_fresh(trainer, keys, reward_data, iterations, **options):
        handed.update(reward_data=reward_data, keys=keys)
        raise Handed

    monkeypatch.setattr(check, "train_fresh", train_fresh)
    with pytest.raises(Handed):
        check.reoptimize(saved, [0, 1], BUDGET, progress=False, parameters=given)
    leaves = lambda tree: [np.asarray(x) for x in jax.tree.leaves(tree)]
    pairs = zip(leaves(handed["reward_data"]), leaves(stacked(given)), strict=True)
    assert all(np.array_equal(a, b) for a, b in pairs)
    np.testing.assert_array_equal(handed["keys"], check.fresh_keys(saved, [0, 1]))
