"""train_agent: a fresh TRPO agent on an env's reward, a learned one through LearnedRewardEnv;
and the README's example of it, run as printed."""

import pathlib
import re
import shutil

import jax
import numpy as np
import pytest
from falling import FALLS_AT, Falling, toy_reward

from emgail_jax import refit
from emgail_jax.reward import LearnedRewardEnv, train_agent

pytestmark = pytest.mark.heavy

README = pathlib.Path(__file__).resolve().parents[1] / "README.md"


def readme_example() -> str:
    """The README's Python block that trains a fresh agent on a loaded reward."""
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), re.S)
    return next(block for block in blocks if "train_agent" in block)


def test_a_fresh_agent_trains_on_the_learned_reward_and_is_scored_on_the_true_one():
    """On the toy env whose true rewards are 1 and 2 a step until it falls, whatever the
    policy: the agent trains on a learned reward, and its returns are the true ones."""
    agent = train_agent(LearnedRewardEnv(Falling(), toy_reward(), intention=1), intention=1,
                        iterations=2)  # fmt: skip
    np.testing.assert_allclose(agent.returns, [FALLS_AT * 1.0, FALLS_AT * 2.0])
    action = jax.jit(agent.policy)(Falling().reset(jax.random.PRNGKey(0)).obs)
    assert action.shape == (1,) and np.all(np.isfinite(action))


@pytest.mark.parametrize(
    "printed_iterations",
    [
        False,  # the fresh agent trains 2 TRPO iterations: the same lines, run fast
        pytest.param(True, marks=pytest.mark.slow),  # every line as printed
    ],
)
def test_the_readme_example_runs_as_printed(
    tiny_run, tmp_path, monkeypatch, capsys, printed_iterations
):
    example = readme_example()
    assert len(example.strip().splitlines()) <= 15
    run_dir = tmp_path / "runs" / "driver-emgail"
    shutil.copytree(tiny_run, run_dir, ignore=shutil.ignore_patterns("rewards", "reward"))
    small = ["--set", "consolidate=3", "--set", "consolidate_batch=20", "--quiet"]
    assert refit.main([str(run_dir), *small]) == 0
    monkeypatch.chdir(tmp_path)
    capsys.readouterr()
    names = {}
    assert example.count("iterations=50") == 1
    if not printed_iterations:
        example = example.replace("iterations=50", "iterations=2")
    exec(compile(example, str(README), "exec"), names)
    printed = capsys.readouterr().out.splitlines()
    assert printed[0] == (
        "LearnedReward(run='runs/driver-emgail', seed=0, source='refit', form='log-d')"
    )
    # The fresh agent: its true returns under both intentions, and a jittable policy.
    returns = names["agent"].returns
    assert returns.shape == (2,) and np.all(np.isfinite(returns))
    obs = names["env"].reset(jax.random.PRNGKey(0)).obs
    assert jax.jit(names["agent"].policy)(obs).shape == (names["env"].action_size,)
