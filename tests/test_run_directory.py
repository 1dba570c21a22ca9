"""A run's directory: where a new run goes, and what a new run may replace."""

import os

import pytest

from emgail_jax.host import run_lock
from emgail_jax.host.run_directory import (
    OUTPUTS,
    create_output,
    default_output,
    prepare_output,
    writing,
)
from emgail_jax.host.run_spec import RunError


def test_default_output_never_takes_an_earlier_run(tmp_path):
    root = str(tmp_path)
    assert default_output("driver", "gail", root) == f"{root}/driver-gail"
    os.makedirs(f"{root}/driver-gail")
    os.makedirs(f"{root}/driver-gail-2")
    assert default_output("driver", "gail", root) == f"{root}/driver-gail-3"


def test_create_output_refuses_a_file(tmp_path):
    path = tmp_path / "a-file"
    path.write_text("")
    with pytest.raises(RunError, match="is a file"):
        create_output(str(path))
    create_output(str(tmp_path / "new" / "run"))
    assert (tmp_path / "new" / "run").is_dir()


def test_a_refused_new_run_leaves_no_directory(tmp_path):
    out = tmp_path / "run"
    with pytest.raises(RuntimeError), writing(str(out), new=True):
        assert (out / run_lock.LOCK_NAME).exists()
        raise RuntimeError("refused")
    assert not out.exists()
    with writing(str(out), new=True):
        (out / "summary.json").write_text("{}")
    assert (out / "summary.json").exists()  # a run that wrote something keeps its directory


def test_writing_an_existing_run_needs_its_summary(tmp_path):
    with pytest.raises(RunError, match="not a run directory"), writing(str(tmp_path / "x"), False):
        pass


def test_prepare_output_replaces_a_run_only_when_told(tmp_path):
    out = tmp_path / "run"
    (out / "checkpoints").mkdir(parents=True)
    (out / "metrics.csv").write_text("iteration\n")
    (out / "notes.txt").write_text("mine")
    with pytest.raises(RunError, match=r"already holds a run \(metrics.csv, checkpoints\)"):
        prepare_output(str(out), overwrite=False)
    assert (out / "metrics.csv").exists()
    (out / "reoptimize.json").write_text("{}")
    (out / "reoptimize-refit.json").write_text("{}")
    (out / "rewards" / "refit").mkdir(parents=True)
    (out / "reoptimize-refit.draws").mkdir()
    (out / "reoptimize-refit.parts").mkdir()
    with pytest.raises(RunError, match="already holds a run"):
        prepare_output(str(out), overwrite=False)
    assert (out / "reoptimize.json").exists() and (out / "rewards" / "refit").exists()
    prepare_output(str(out), overwrite=True)
    assert not any((out / name).exists() for name in OUTPUTS)
    # The checks and refits of the replaced networks go with them.
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]
    assert (out / "notes.txt").read_text() == "mine"  # not a run's output: kept


def test_prepare_output_keeps_checks_where_there_is_no_run_to_replace(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    (out / "reoptimize.json").write_text("{}")
    prepare_output(str(out), overwrite=False)
    assert (out / "reoptimize.json").read_text() == "{}"
