"""What defines a run in its summary.json, and reading a summary back: each failure is one line
that says what is wrong."""

import json

import pytest

from emgail_jax.host.run_spec import RunError, RunSpec, read_summary, stored_seeds
from emgail_jax.method.config import RunConfig


def _spec(sources=()):
    return RunSpec(
        env="driver", intentions=2, env_options={"radius": 10.0}, algo="emgail", seeds=2,
        first_seed=3, demo_sources=sources, demo_seed=7, config=RunConfig(), random_episodes=20,
    )  # fmt: skip


@pytest.mark.parametrize(
    ("sources", "stored"),
    [((), None), (("a.npz",), "a.npz"), (("a.npz", "minari:b"), ["a.npz", "minari:b"])],
)
def test_a_spec_comes_back_from_its_summary(sources, stored):
    """None, one source (a string, as runs have stored it) or a list of them."""
    summary = json.loads(json.dumps(_spec(sources).to_summary()))  # as written to the file
    assert summary["demonstrations"] == {"path": stored, "seed": 7}
    assert RunSpec.from_summary(summary) == _spec(sources)


def test_a_summary_written_before_random_episodes_were_stored_takes_the_default():
    summary = _spec().to_summary()
    del summary["random_episodes"]
    assert RunSpec.from_summary(summary).random_episodes == 50


def test_a_summary_that_is_no_run_or_holds_a_refused_config_is_one_line():
    summary = _spec().to_summary()
    del summary["algo"]
    with pytest.raises(RunError, match=r"does not describe a run \(no 'algo'\)"):
        RunSpec.from_summary(summary)
    summary = _spec().to_summary()
    summary["config"]["gamma"] = 2.0
    with pytest.raises(RunError, match=r"refuses: gamma must be in \(0, 1\]") as refused:
        RunSpec.from_summary(summary)
    assert "\n" not in str(refused.value)


def test_a_summary_of_a_deleted_setting_loads_at_its_old_default_and_is_refused_else():
    summary = _spec().to_summary()
    summary["config"]["discriminator_support_in_box"] = False
    assert RunSpec.from_summary(summary) == _spec()
    summary["config"]["discriminator_support_in_box"] = True
    with pytest.raises(RunError, match="discriminator_support_in_box was deleted") as refused:
        RunSpec.from_summary(summary)
    assert "\n" not in str(refused.value)


def test_stored_seeds_reads_the_summary_or_says_1(tmp_path):
    assert stored_seeds(str(tmp_path)) == 1  # no summary: the command fails later
    (tmp_path / "summary.json").write_text(json.dumps(_spec().to_summary()))
    assert stored_seeds(str(tmp_path)) == 2


def test_reading_a_summary_names_the_directory_or_the_file_at_fault(tmp_path):
    with pytest.raises(RunError, match=r"is not a run directory: it has no summary\.json"):
        read_summary(str(tmp_path))
    (tmp_path / "summary.json").write_text('{"env": "driver"')  # cut short
    with pytest.raises(RunError, match=r"summary\.json' is not valid JSON"):
        read_summary(str(tmp_path))
    (tmp_path / "summary.json").write_text('{"env": "driver"}')
    assert read_summary(str(tmp_path)) == {"env": "driver"}
