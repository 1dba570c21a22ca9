"""The experts' bars: one for every intention of every env with experts, read from the
measures ``quality`` reports."""

import types

import numpy as np
import pytest

import envs
from emgail_jax.experts import SPECS
from emgail_jax.host.expert_bars import BARS, episode_measures, episodes_meeting


@pytest.mark.parametrize("name", sorted(SPECS))
def test_every_intention_of_an_env_with_experts_has_a_bar(name):
    for intention in envs.make(name).intention_names:
        assert (name, intention) in BARS


def test_a_bar_reads_the_measures_of_its_intention():
    described, meets = BARS[("hopper", "backward")]
    assert described == "velocity <= -0.8, upright >= 90 %"
    assert meets({"velocity": -0.9, "upright": 1.0})
    assert not meets({"velocity": -0.74, "upright": 1.0})  # hops backward, too slowly
    assert not meets({"velocity": -0.9, "upright": 0.8})  # falls in 2 episodes of 10
    assert BARS[("reacher", "ball3")][1]({"reached": 0.9})


def test_the_reachers_success_is_the_share_of_episodes_ending_within_002_of_its_ball():
    """Synthetic traces of 2 intentions x 4 episodes of 3 steps: intention 1 (ball2) ends 0.01,
    0.03, 0.019 and 0.5 from its ball, so 2 of its 4 episodes reach it, whatever ball 1's
    distances; the mean final distance is read beside it."""
    steps, k, episodes = 3, 2, 4
    alive = np.ones((steps, k, episodes))
    far = np.full((steps, k, episodes), 0.3)
    ball2 = far.copy()
    ball2[-1, 1] = [0.01, 0.03, 0.019, 0.5]
    trace = {"distance to ball 1": np.zeros_like(far), "distance to ball 2": ball2}
    measures = episode_measures(types.SimpleNamespace(episode_length=steps), 1, alive, trace)
    np.testing.assert_array_equal(measures["reached"], [1, 0, 1, 0])
    assert measures["final_distance"].mean() == pytest.approx((0.01 + 0.03 + 0.019 + 0.5) / 4)
    assert episodes_meeting(BARS[("reacher", "ball2")][1], measures) == 0.5


def test_an_episode_meets_the_bar_on_its_own_measures():
    """Hopper forward, episode by episode: fast and upright, fast but fallen, upright but slow."""
    measures = {"velocity": np.array([1.0, 1.0, 0.5]), "upright": np.array([1.0, 0.0, 1.0])}
    assert episodes_meeting(BARS[("hopper", "forward")][1], measures) == pytest.approx(1 / 3)
