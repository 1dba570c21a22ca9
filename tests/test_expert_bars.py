"""The experts' bars: one for every intention of every env with experts, read from the
measures ``quality`` reports."""

import pytest

import envs
from emgail_jax.experts import SPECS
from emgail_jax.host.expert_bars import BARS


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
