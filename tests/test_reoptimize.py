"""python -m emgail_jax.reoptimize on a tiny run."""

import json

import numpy as np

from emgail_jax import reoptimize


def test_reoptimize_writes_an_erd(tiny_run, capsys):
    assert reoptimize.main([str(tiny_run), "--iterations", "2", "--quiet"]) == 0
    result = json.loads((tiny_run / "reoptimize.json").read_text())
    assert result["iterations"] == 2 and len(result["erd_curve"]) == 2
    assert np.isfinite(result["erd"]) and result["erd"] >= 0
    assert np.asarray(result["returns"]).shape == (2, 2)
    assert sorted(result["matching"]) == [0, 1]
    earned = result["learned_reward_per_step"]
    assert np.asarray(earned["fresh_policies"]).shape == (2,)
    assert np.asarray(earned["demonstrations"]).shape == (2,)
    assert np.all(np.isfinite(earned["fresh_policies"]))
    out = capsys.readouterr().out
    assert "normalised ERD" in out and "fresh policies / demonstrations" in out


def test_demonstrations_reward_weights_pairs_by_their_responsibilities(tiny_run):
    from emgail_jax.host.saved_run import SavedRun

    run = SavedRun.open(str(tiny_run))
    expert = run.demonstration_pairs
    gamma = np.asarray(run.responsibilities(0).gamma)
    reward = run.reward(0)
    earned = reoptimize.demonstrations_reward(run, 0)
    for i in range(2):
        if gamma[:, i].sum() == 0:  # no demonstration assigned: nothing to earn on
            assert np.isnan(earned[i])
            continue
        per_pair = np.asarray(reward(expert.observations, expert.actions, i))
        expected = (gamma[:, i] * per_pair).sum() / gamma[:, i].sum()
        np.testing.assert_allclose(earned[i], expected, rtol=1e-5)


def test_reoptimize_bad_input(tmp_path, capsys):
    assert reoptimize.main([str(tmp_path)]) == 2
    assert "no summary.json" in capsys.readouterr().err
