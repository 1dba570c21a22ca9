"""The driver acceptance run, end to end: `make test-slow`, not CI."""

import json

import pytest

from emgail_jax import run

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def finals(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("driver")
    out = {}
    for algo in ("emgail", "gail"):
        args = ["--env", "driver", "--algo", algo, "--seeds", "4", "--iterations", "400"]
        assert run.main([*args, "--out", str(tmp / algo), "--quiet"]) == 0
        out[algo] = json.loads((tmp / algo / "summary.json").read_text())["final"]
    return out


def test_emgail_recovers_both_intentions_on_every_seed(finals):
    assert all(erd <= 0.10 for erd in finals["emgail"]["erd"]), finals["emgail"]["erd"]
    accuracy = finals["emgail"]["cluster_accuracy"]
    assert all(a >= 0.95 for a in accuracy), accuracy


def test_gail_is_at_least_three_times_worse(finals):
    emgail, gail = finals["emgail"]["erd"], finals["gail"]["erd"]
    assert min(gail) >= 3 * max(emgail), (gail, emgail)
