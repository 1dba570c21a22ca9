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
    assert "normalised ERD" in capsys.readouterr().out


def test_reoptimize_bad_input(tmp_path, capsys):
    assert reoptimize.main([str(tmp_path)]) == 2
    assert "no summary.json" in capsys.readouterr().err
