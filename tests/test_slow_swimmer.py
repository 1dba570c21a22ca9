"""The swimmer acceptance run, end to end: `make test-slow`, not CI."""

import json

import pytest

from emgail_jax import run

pytestmark = pytest.mark.slow


def test_emgail_separates_the_swimmers_two_intentions_on_every_seed(tmp_path):
    args = ["--env", "swimmer", "--intentions", "2", "--seeds", "4", "--iterations", "400"]
    assert run.main([*args, "--out", str(tmp_path), "--quiet"]) == 0
    final = json.loads((tmp_path / "summary.json").read_text())["final"]
    assert all(a >= 0.97 for a in final["cluster_accuracy"]), final["cluster_accuracy"]
    assert all(erd <= 0.2 for erd in final["erd"]), final["erd"]
