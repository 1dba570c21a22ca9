"""python -m emgail_jax.evaluate: scores, figures, and bad input."""

import pytest

from emgail_jax import evaluate

PNG = b"\x89PNG\r\n\x1a\n"


def test_evaluate_writes_its_figures(tiny_run, capsys):
    out = tiny_run / "figs"
    assert evaluate.main([str(tiny_run), "--episodes", "2", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "seed 0: ERD" in printed and "seed 1: ERD" in printed and "accuracy" in printed
    for name in ("learning_curves.png", "paths_seed0.png"):
        data = (out / name).read_bytes()
        assert data.startswith(PNG) and len(data) > 10_000, name


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda tmp, run: tmp / "nothing", "no summary.json"),
        (lambda tmp, run: run, "seeds 0..1"),
    ],
)
def test_evaluate_bad_input(tmp_path, tiny_run, capsys, make, message):
    target = make(tmp_path, tiny_run)
    extra = ["--seed", "5"] if target == tiny_run else []
    assert evaluate.main([str(target), *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and "\n" not in err and "Traceback" not in err
