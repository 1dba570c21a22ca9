"""Smoke runs of the experiment scripts under experiments/ on tiny settings: they are not part
of the package, so nothing else would notice when one of them no longer runs."""

import importlib.util
import pathlib

import pytest

EXPERIMENTS = pathlib.Path(__file__).resolve().parents[1] / "experiments"


def _load(name):
    spec = importlib.util.spec_from_file_location(name, EXPERIMENTS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.slow  # a child process with a cold compilation cache: 60-100 s
def test_bench_measures_the_driver(capsys):
    """The benchmark's child process on the driver with few seeds and chunks: every number it
    reports is there and positive."""
    bench = _load("bench")
    assert bench.main(["--envs", "driver:2", "--seeds", "2", "--chunks", "1"]) == 0
    out = capsys.readouterr().out
    for line in ("== driver-2", "2 seed(s):", "E-step", "M-step", "B-step", "evaluation",
                 "compile (2 seeds", "warm cache", "peak resident memory"):  # fmt: skip
        assert line in out, line


def test_driver_separability_writes_its_table(tmp_path, capsys):
    module = _load("driver_separability")
    assert module.main(["--radii", "4", "20", "--out", str(tmp_path)]) == 0
    rows = (tmp_path / "separability.csv").read_text().splitlines()
    assert rows[0].startswith("radius,destination_gap,separability")
    radii = [float(row.split(",")[0]) for row in rows[1:]]
    assert radii == pytest.approx([4.0, 20.0])
    # More overlap at the smaller radius.
    separabilities = [float(row.split(",")[2]) for row in rows[1:]]
    assert separabilities[0] < separabilities[1]
