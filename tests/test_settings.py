"""The flat namespace of a run's settings: the table of keys, ``--set``'s parsing, the flat
dict of ``summary.json`` and the saved configs of earlier versions (also the committed runs)."""

import dataclasses
import glob
import json
import os
import types

import pytest

from emgail_jax.method import settings
from emgail_jax.method.config import (
    AlgorithmName,
    IntentionInput,
    Prior,
    RunConfig,
    SettingError,
    TRPOConfig,
)
from emgail_jax.method.settings import DELETED, SETTINGS

RUNS = os.path.join(os.path.dirname(__file__), "..", "results", "runs")


def _fake_env(name, episode_length):
    """``resolved`` reads only the env's name and episode length."""
    return types.SimpleNamespace(name=name, episode_length=episode_length)


def _stored_config(cell: str) -> dict:
    with open(os.path.join(RUNS, cell, "summary.json")) as f:
        return json.load(f)["config"]


def test_to_dict_is_the_flat_namespace_json_serialisable_and_complete():
    config = RunConfig().with_values(num_envs=2, hidden=(8, 8)).resolved(_fake_env("driver", 100))
    data = json.loads(json.dumps(config.to_dict()))
    assert list(data) == list(SETTINGS)
    assert data["num_envs"] == 2 and data["rollout_length"] == 100
    assert data["hidden"] == [8, 8] and data["intention_input"] == "heads"
    assert data["trpo"] == dataclasses.asdict(TRPOConfig())
    assert data["discriminator_steps"] == config.method.m_step.steps


def test_from_dict_round_trips_what_new_runs_write():
    config = RunConfig().with_values(
        intention_input="onehot",
        hidden=(8,),
        prior="mixture",
        choose_intentions=True,
        reward_form="logit",
        absorbing_state=True,
        info_weight=0.3,
        seed_batch=2,
        snapshot_every=0,
    )
    written = json.loads(json.dumps(config.to_dict()))
    assert RunConfig.from_dict(written) == config
    assert RunConfig.from_dict(written).to_dict() == config.to_dict()


def test_older_runs_without_an_option_read_as_they_ran():
    older = {k: v for k, v in RunConfig().to_dict().items() if k != "intention_input"}
    assert RunConfig.from_dict(older).method.networks.intention_input is IntentionInput.ONEHOT
    with pytest.raises(TypeError, match="unknown settings"):
        RunConfig.from_dict({**RunConfig().to_dict(), "no_such_setting": 1})


def test_a_committed_summary_is_read_back_identically():
    """``driver-r4-emgail`` (re-seeding on) holds every setting of its time: the stored flat
    dict lands in the layers and comes back out unchanged."""
    stored = _stored_config("driver-r4-emgail")
    config = RunConfig.from_dict(stored)
    assert config.method.e_step.reseed and config.method.e_step.responsibilities == "trajectory"
    assert config.method.networks.intention_input is IntentionInput.HEADS
    written = json.loads(json.dumps(config.to_dict()))
    kept = {key: value for key, value in stored.items() if key not in DELETED}
    assert {key: written[key] for key in kept} == kept


def test_an_old_committed_summary_takes_the_defaults_of_its_time():
    """``driver-r10-emgail`` predates the prior, re-seeding and the gradient penalty: it reads
    with re-seeding off and the settings it lacks at their defaults."""
    stored = _stored_config("driver-r10-emgail")
    assert "reseed" not in stored and "prior" not in stored
    config = RunConfig.from_dict(stored)
    assert not config.method.e_step.reseed and config.method.e_step.prior is Prior.UNIFORM
    assert config.method.m_step.gradient_penalty == 0.0
    written = config.to_dict()
    kept = {key: value for key, value in stored.items() if key not in ("hidden", *DELETED)}
    assert {key: written[key] for key in kept} == kept


def test_every_committed_summary_reads():
    cells = glob.glob(os.path.join(RUNS, "*", "summary.json"))
    assert len(cells) >= 79
    for path in cells:
        with open(path) as f:
            RunConfig.from_dict(json.load(f)["config"])


def test_with_settings_parses_each_value_as_the_type_of_its_default():
    config = RunConfig().with_settings(
        ["discriminator_steps=5", "trpo.cg_damping=0", "hidden=(32, 32)", "algo=gail"]
    )
    method = config.method
    assert method.m_step.steps == 5
    assert method.b_step.trpo.cg_damping == 0.0 and isinstance(method.b_step.trpo.cg_damping, float)
    assert method.networks.hidden == (32, 32)
    assert method.algo is AlgorithmName.GAIL
    assert method.b_step.trpo.max_kl == TRPOConfig().max_kl  # the rest untouched
    assert RunConfig().with_settings([]) == RunConfig()


@pytest.mark.parametrize("text", ["true", "True", "TRUE"])
def test_a_boolean_setting_takes_the_shells_spelling_too(text):
    assert RunConfig().with_settings([f"absorbing_state={text}"]).method.reward.absorbing_state
    off = RunConfig().with_settings(["absorbing_state=true", "absorbing_state=false"])
    assert off == RunConfig() and not RunConfig().method.reward.absorbing_state


@pytest.mark.parametrize(
    ("flat", "layered"),
    [
        ("discriminator_steps=5", "method.m_step.steps=5"),
        ("trpo.max_kl=0.02", "method.b_step.trpo.max_kl=0.02"),
        ("posterior_steps=3", "method.e_step.steps=3"),
        ("reward_from=previous", "method.reward.source=previous"),
        ("iterations=7", "schedule.iterations=7"),
        ("info_weight=0.5", "info_weight=0.5"),
    ],
)
def test_set_takes_todays_flat_keys_and_the_layered_paths_alike(flat, layered):
    assert RunConfig().with_settings([flat]) == RunConfig().with_settings([layered])
    assert RunConfig().with_settings([flat]) != RunConfig()


@pytest.mark.parametrize(
    "setting, message",
    [
        ("discriminator_step=5", "unknown setting 'discriminator_step'"),
        ("trpo.damping=0", "unknown setting 'trpo.damping'"),
        ("method.m_step.step=5", "unknown setting 'method.m_step.step'"),
        ("discriminator_steps=0.5", "like its default 10"),
        ("gamma=fast", "not a number"),
        ("trpo=1", "has fields"),
        ("method.e_step=1", "has fields"),
        ("gamma", "KEY=VALUE"),
        ("eval_every=0", "eval_every must be at least 1"),
    ],
)
def test_with_settings_rejects_what_it_cannot_apply_in_one_line(setting, message):
    with pytest.raises(ValueError, match=message) as error:
        RunConfig().with_settings([setting])
    assert "\n" not in str(error.value)


def _leaf_paths(node, prefix=()):
    for f in dataclasses.fields(node):
        value = getattr(node, f.name)
        if dataclasses.is_dataclass(value) and not isinstance(value, TRPOConfig):
            yield from _leaf_paths(value, (*prefix, f.name))
        else:
            yield (*prefix, f.name)


def test_the_flat_table_covers_every_field_once():
    paths = list(SETTINGS.values())
    assert sorted(paths) == sorted(_leaf_paths(RunConfig()))
    assert len(set(paths)) == len(paths)


@pytest.mark.parametrize(
    ("setting", "message"),
    [
        ("trpo.max_kl=-1", "trpo.max_kl must be a positive number; got -1.0"),
        ("trpo.max_kl=0", "trpo.max_kl must be a positive number"),
        ("value_learning_rate=0", "value_learning_rate must be a positive number"),
        ("discriminator_learning_rate=1e999", "must be a positive number; got inf"),
        ("gamma=0", "gamma must be in (0, 1]"),
        ("gamma=1.5", "gamma must be in (0, 1]"),
        ("gae_lambda=-0.1", "gae_lambda must be in (0, 1]"),
        ("posterior_steps=0", "posterior_steps must be at least 1"),
        ("value_minibatches=-2", "value_minibatches must be at least 1"),
        ("num_envs=0", "num_envs must be at least 1 (or None, the default)"),
        ("hidden=(64, 0)", "hidden must be a tuple of layer widths >= 1"),
        ("trpo.line_search_decay=1", "trpo.line_search_decay must be in (0, 1)"),
        ("trpo.cg_damping=-1", "trpo.cg_damping must be a number >= 0"),
        ("choose_intentions=3", "choose_intentions must be True or False"),
        ("absorbing_state=3", "absorbing_state must be True or False; got 3"),
        ("prior=flat", "prior must be one of uniform, mixture; got 'flat'"),
        ("discriminator_form=bogus", "discriminator_form must be one of gail, airl; got 'bogus'"),
        ("snapshot_every=-1", "snapshot_every must be an integer >= 0; got -1"),
        (
            "trajectory_temper_iterations=-1",
            "trajectory_temper_iterations must be an integer >= 0; got -1",
        ),
    ],
)
def test_a_value_outside_its_domain_is_refused_in_one_line(setting, message):
    with pytest.raises(SettingError) as error:
        RunConfig().with_settings([setting])
    assert message in str(error.value) and "\n" not in str(error.value)
    assert error.value.key == setting.partition("=")[0]


def test_values_at_the_edges_of_their_domains_are_accepted():
    config = RunConfig().with_settings(
        ["gamma=1", "gae_lambda=1", "trpo.cg_damping=0", "seed_batch=1", "snapshot_every=0"]
    )
    b_step = config.method.b_step
    assert (b_step.gamma, b_step.gae_lambda, b_step.trpo.cg_damping) == (1.0, 1.0, 0.0)


@pytest.mark.parametrize("key", sorted(DELETED))
def test_a_deleted_setting_is_an_unknown_key(key):
    with pytest.raises(ValueError, match=f"unknown setting '{key}'") as error:
        RunConfig().with_settings([f"{key}=1"])
    assert "\n" not in str(error.value)
    with pytest.raises(ValueError, match=f"unknown setting '{key}'"):
        RunConfig().with_values(**{key: DELETED[key]})


def test_a_saved_config_drops_a_deleted_setting_at_its_old_default_and_refuses_it_else():
    stored = {**RunConfig().to_dict(), **DELETED}
    assert RunConfig.from_dict(stored) == RunConfig()
    for key in DELETED:
        tried = {**stored, key: 1 if key.endswith("_from") else True}
        with pytest.raises(ValueError, match=f"{key} was deleted as refuted") as error:
            RunConfig.from_dict(tried)
        assert "\n" not in str(error.value)


def test_a_committed_summary_holds_the_deleted_settings_at_their_old_defaults():
    stored = _stored_config("hopper-2-gail")
    assert {key: stored[key] for key in DELETED} == DELETED
    written = json.loads(json.dumps(RunConfig.from_dict(stored).to_dict()))
    kept = {key: value for key, value in stored.items() if key not in DELETED}
    assert {key: written[key] for key in kept} == kept and not set(DELETED) & set(written)


def test_keys_and_paths_name_each_other():
    for key, path in SETTINGS.items():
        assert settings.path_of(key) == path and settings.key_of(path) == key
    assert settings.path_of("trpo.max_kl") == ("method", "b_step", "trpo", "max_kl")
    assert settings.key_of(("method", "b_step", "trpo", "max_kl")) == "trpo.max_kl"
    assert settings.path_of("method.m_step.steps") == SETTINGS["discriminator_steps"]


def test_parsed_texts_are_values_by_flat_key_the_later_winning():
    parsed = settings.parsed(
        ["method.m_step.steps=3", "trpo.max_kl=0.02", "discriminator_steps=4"], like=RunConfig()
    )
    assert parsed == {"discriminator_steps": 4, "trpo.max_kl": 0.02}


def test_with_values_checks_each_layer_once_with_all_its_new_values():
    """Settings that need each other are given together, in either order."""
    config = RunConfig().with_values(choose_intentions=True, prior="mixture")
    assert config.method.choose_intentions and config.method.e_step.prior is Prior.MIXTURE
    tempered = RunConfig().with_values(
        trajectory_temper_iterations=3, responsibilities="trajectory-centered"
    )
    assert tempered.method.e_step.trajectory_temper_iterations == 3
