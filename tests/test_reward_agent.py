"""train_agent: a fresh TRPO agent on an env's reward, a learned one through LearnedRewardEnv;
and the README's example of it, run as printed."""

import pathlib
import re
import shutil

import jax
import numpy as np
import pytest

from emgail_jax import refit
from emgail_jax.host.saved_run import SavedRun
from emgail_jax.reward import LearnedRewardEnv, load_reward, train_agent

pytestmark = pytest.mark.heavy

README = pathlib.Path(__file__).resolve().parents[1] / "README.md"


def readme_example() -> str:
    """The README's Python block that trains a fresh agent on a loaded reward."""
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), re.S)
    return next(block for block in blocks if "train_agent" in block)


def test_a_fresh_agent_trains_on_the_learned_reward_and_is_scored_on_the_true_one(tiny_run):
    env = SavedRun.open(str(tiny_run)).problem.env
    reward = load_reward(str(tiny_run), seed=0)
    agent = train_agent(LearnedRewardEnv(env, reward, intention=1), intention=1, iterations=2)
    assert agent.returns.shape == (env.num_intentions,)
    assert np.all(np.isfinite(agent.returns))
    obs = env.reset(jax.random.PRNGKey(0)).obs
    action = jax.jit(agent.policy)(obs)
    assert action.shape == (env.action_size,)
    # The agent's own score is its true returns, not the learned reward it trained on.
    again = train_agent(env, intention=1, iterations=2)
    assert again.returns.shape == agent.returns.shape


def test_the_readme_example_runs_as_printed(tiny_run, tmp_path, monkeypatch, capsys):
    example = readme_example()
    assert len(example.strip().splitlines()) <= 15
    run_dir = tmp_path / "runs" / "driver-emgail"
    shutil.copytree(tiny_run, run_dir, ignore=shutil.ignore_patterns("rewards", "reward"))
    small = ["--set", "consolidate=3", "--set", "consolidate_batch=20", "--quiet"]
    assert refit.main([str(run_dir), *small]) == 0
    monkeypatch.chdir(tmp_path)
    capsys.readouterr()
    exec(compile(example, str(README), "exec"), {})
    printed = capsys.readouterr().out.splitlines()
    assert printed[0] == (
        "LearnedReward(run='runs/driver-emgail', seed=0, source='refit', form='log-d')"
    )
