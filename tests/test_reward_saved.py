"""A refit saved in its run directory: saved once, then read, refused where it no longer fits."""

import shutil

import jax
import numpy as np
import pytest

from emgail_jax.host.checkpoints import CheckpointError
from emgail_jax.host.saved_run import SavedRun
from emgail_jax.reward import load
from emgail_jax.reward import refit as refitting
from emgail_jax.reward import saved as store


def test_a_refit_saved_before_an_option_existed_reads_as_its_default(copied_run):
    run = SavedRun.open(str(copied_run))
    refit = refitting.Refit(steps=5, fresh=True)
    description = store.refit_description(refit, None, run.iteration)
    older = {
        **description,
        "refit": {k: v for k, v in description["refit"].items() if not k.startswith("ranking")},
    }
    parameters, losses = refitting.consolidated_parameters(run, 0, refit, jax.random.PRNGKey(0))
    store.save_refitted(str(copied_run), "older", 0, parameters["discriminator"], older, losses)
    assert store.read_description(str(copied_run), "older") == description
    # Saved before the iteration was recorded: a snapshot's refit is of its iteration, the
    # final networks' of an unknown one, which no run is read with.
    del older["iteration"]
    store.save_refitted(str(copied_run), "older", 0, parameters["discriminator"], older, losses)
    assert store.read_description(str(copied_run), "older")["iteration"] is None
    with pytest.raises(CheckpointError, match="an unrecorded iteration"):
        load.reward_of(run, 0, refit="older")
    store.save_refitted(
        str(copied_run), "older", 0, parameters["discriminator"], {**older, "snapshot": 2}, losses
    )
    assert store.read_description(str(copied_run), "older")["iteration"] == 2


def test_a_refit_of_networks_the_run_has_replaced_is_refused_in_one_line(copied_run):
    """A run resumed after its reward was refitted holds other networks than those the refit
    was made from: reading the refit with them would pair it with other statistics."""
    import emgail_jax

    run = SavedRun.open(str(copied_run))
    refit = refitting.Refit(steps=5, fresh=True)
    parameters, losses = refitting.consolidated_parameters(run, 0, refit, jax.random.PRNGKey(0))
    earlier = store.refit_description(refit, None, run.iteration - 1)
    store.save_refitted(str(copied_run), "earlier", 0, parameters["discriminator"], earlier, losses)
    expected = (
        f"refitted from the networks of iteration {run.iteration - 1}, not those of iteration "
        f"{run.iteration}: delete .*rewards/earlier to refit it"
    )
    with pytest.raises(CheckpointError, match=expected):
        emgail_jax.load_reward(str(copied_run), seed=0, refit="earlier")


def test_a_refit_is_saved_once_and_reused(tiny_run, tmp_path, capsys):
    from emgail_jax.host.run_spec import RunError

    copy = tmp_path / "run"
    shutil.copytree(tiny_run, copy, ignore=shutil.ignore_patterns("rewards"))
    run = SavedRun.open(str(copy))
    first, first_losses = store.saved_or_refitted(
        run, [1], refitting.Refit(steps=3), "consolidated-3"
    )
    assert "reused" not in capsys.readouterr().out
    again, again_losses = store.saved_or_refitted(
        run, [1], refitting.Refit(steps=3), "consolidated-3"
    )
    assert "seed 1: the refitted reward 'consolidated-3' saved before, reused" in (
        capsys.readouterr().out
    )
    for a, b in zip(jax.tree.leaves(first), jax.tree.leaves(again), strict=True):
        np.testing.assert_array_equal(a, b)
    loss = lambda losses: losses[0]["after"]["discriminator/loss"]
    assert loss(again_losses) == pytest.approx(float(loss(first_losses)))
    with pytest.raises(RunError, match=r"'consolidated-3' .* was refitted otherwise"):
        store.saved_or_refitted(run, [1], refitting.Refit(steps=4), "consolidated-3")


def test_a_refit_saved_with_an_option_since_deleted_is_read_at_its_one_value(copied_run):
    """A reward.json written when the refit had more options reads as this refit where they
    are at the one value they still have, and is refused where they are not."""
    import json

    run = SavedRun.open(str(copied_run))
    refit = refitting.Refit(steps=5, fresh=True)
    parameters, losses = refitting.consolidated_parameters(run, 0, refit, jax.random.PRNGKey(0))
    description = store.refit_description(refit, None, run.iteration)
    older = {**description, "refit": {**description["refit"], **store.RETIRED_OPTIONS}}
    store.save_refitted(str(copied_run), "older", 0, parameters["discriminator"], older, losses)
    assert store.read_description(str(copied_run), "older") == description
    path = copied_run / "rewards" / "older" / "reward.json"
    path.write_text(json.dumps({**older, "refit": {**older["refit"], "agent_rounds": 2}}))
    with pytest.raises(
        CheckpointError, match="refitted with agent_rounds, an option since deleted"
    ):
        store.read_description(str(copied_run), "older")
