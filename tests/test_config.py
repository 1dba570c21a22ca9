"""Run hyper-parameters: paper defaults, env-dependent rollout sizes, and serialisation."""

import dataclasses
import json
import types

import pytest

import envs
from emgail_jax.method.config import DOMAINS, Config, SettingError, rollout_defaults
from emgail_jax.method.trpo import TRPOConfig


def _fake_env(name, episode_length):
    """``resolved`` reads only the env's name and episode length."""
    return types.SimpleNamespace(name=name, episode_length=episode_length)


def test_paper_defaults():
    config = Config()
    assert config.algo == "emgail" and config.iterations == 400
    assert config.gamma == 0.995 and 0.97 <= config.gae_lambda <= 0.98
    assert config.trpo == TRPOConfig()
    assert config.trpo.max_kl == 0.01 and config.trpo.cg_iterations == 10
    assert config.discriminator_learning_rate == config.posterior_learning_rate == 1e-3
    assert config.hidden == (64, 64) and config.obs_clip == 5.0
    # ERD from at least 5 deterministic episodes: one per env of the rollout.
    assert config.resolved(envs.make("driver")).num_envs >= 5
    assert config.num_envs is None and config.rollout_length is None


def test_resolved_fills_the_driver_defaults():
    resolved = Config().resolved(envs.make("driver", intentions=2))
    assert (resolved.num_envs, resolved.rollout_length) == (5, 100)
    # Everything else is unchanged.
    assert resolved.replace(num_envs=None, rollout_length=None) == Config()


def test_resolved_follows_the_env_episode_length_and_wrappers():
    driver = envs.make("driver", intentions=2, episode_length=30)
    assert Config().resolved(driver).rollout_length == 30
    wrapped = envs.wrap_for_training(driver)
    assert Config().resolved(wrapped).rollout_length == 30


@pytest.mark.parametrize(
    ("name", "length", "expected"),
    [
        ("reacher", 50, (50, 50)),
        ("hopper", 500, (5, 500)),
        ("swimmer", 500, (5, 500)),
        ("driver", 100, (5, 100)),
    ],
)
def test_rollout_defaults_collect_the_paper_sample_counts(name, length, expected):
    defaults = rollout_defaults(name, length)
    assert (defaults["num_envs"], defaults["rollout_length"]) == expected
    resolved = Config().resolved(_fake_env(name, length))
    assert (resolved.num_envs, resolved.rollout_length) == expected
    # 2500 pairs per intention per iteration on the robotics tasks (5 x 500 or 50 x 50).
    if name != "driver":
        assert expected[0] * expected[1] == 2500


def test_explicit_sizes_win_over_the_env_defaults():
    config = Config(num_envs=2, rollout_length=20)
    resolved = config.resolved(_fake_env("reacher", 50))
    assert (resolved.num_envs, resolved.rollout_length) == (2, 20)
    partial = Config(num_envs=3).resolved(_fake_env("reacher", 50))
    assert (partial.num_envs, partial.rollout_length) == (3, 50)
    assert resolved.resolved(_fake_env("driver", 100)) == resolved  # idempotent once filled


def test_replace_returns_a_new_config_and_the_original_is_frozen():
    config = Config()
    changed = config.replace(algo="gail", iterations=3, trpo=TRPOConfig(max_kl=0.05))
    assert (changed.algo, changed.iterations, changed.trpo.max_kl) == ("gail", 3, 0.05)
    assert (config.algo, config.iterations, config.trpo.max_kl) == ("emgail", 400, 0.01)
    with pytest.raises(dataclasses.FrozenInstanceError):
        config.algo = "gail"
    with pytest.raises(TypeError):
        config.replace(no_such_field=1)


def test_config_is_hashable_for_use_as_a_static_argument():
    assert hash(Config()) == hash(Config())
    assert Config(hidden=(8,)) != Config()
    assert len({Config(), Config(), Config(algo="gail")}) == 2


def test_to_dict_is_json_serialisable_and_complete():
    config = Config(num_envs=2, hidden=(8, 8)).resolved(_fake_env("driver", 100))
    data = json.loads(json.dumps(config.to_dict()))
    assert set(data) == {f.name for f in dataclasses.fields(Config)}
    assert data["num_envs"] == 2 and data["rollout_length"] == 100
    assert data["hidden"] == [8, 8]
    assert data["trpo"] == dataclasses.asdict(TRPOConfig())
    # The dict rebuilds an equal config.
    rebuilt = Config(
        **{**data, "hidden": tuple(data["hidden"]), "trpo": TRPOConfig(**data["trpo"])}
    )
    assert rebuilt == config


def test_intention_input_defaults_to_heads_and_rejects_unknown_values():
    assert Config().intention_input == "heads"
    assert Config(intention_input="onehot").intention_input == "onehot"
    with pytest.raises(ValueError, match="intention_input must be one of onehot, heads"):
        Config(intention_input="twoheads")


def test_choosing_k_needs_a_posterior_and_the_mixture_prior():
    assert Config(prior="mixture", choose_intentions=True).choose_intentions
    for wrong in ({}, {"prior": "mixture", "algo": "gail"}):
        with pytest.raises(ValueError, match="needs a posterior and the mixture prior"):
            Config(choose_intentions=True, **wrong)


def test_from_dict_round_trip_and_older_runs_without_the_intention_input():
    config = Config(intention_input="onehot", hidden=(8,))
    assert Config.from_dict(json.loads(json.dumps(config.to_dict()))) == config
    older = {k: v for k, v in Config().to_dict().items() if k != "intention_input"}
    assert Config.from_dict(older).intention_input == "onehot"


def test_with_settings_parses_each_value_as_the_type_of_its_default():
    config = Config().with_settings(
        ["discriminator_steps=5", "trpo.cg_damping=0", "hidden=(32, 32)", "algo=gail"]
    )
    assert config.discriminator_steps == 5
    assert config.trpo.cg_damping == 0.0 and isinstance(config.trpo.cg_damping, float)
    assert config.hidden == (32, 32)
    assert config.algo == "gail"
    assert config.trpo.max_kl == Config().trpo.max_kl  # the rest untouched
    assert Config().with_settings([]) == Config()


@pytest.mark.parametrize(
    "setting, message",
    [
        ("discriminator_step=5", "unknown setting 'discriminator_step'"),
        ("trpo.damping=0", "unknown setting 'trpo.damping'"),
        ("discriminator_steps=0.5", "like its default 10"),
        ("gamma=fast", "not a number"),
        ("trpo=1", "has fields"),
        ("gamma", "KEY=VALUE"),
        ("eval_every=0", "eval_every must be at least 1"),
    ],
)
def test_with_settings_rejects_what_it_cannot_apply_in_one_line(setting, message):
    with pytest.raises(ValueError, match=message) as error:
        Config().with_settings([setting])
    assert "\n" not in str(error.value)


def test_program_key_clears_what_does_not_shape_the_update():
    base = Config()
    same = Config(iterations=50, eval_every=7, chunk_size=5, info_weight=0.3)
    assert same.program_key() == base.program_key()
    assert hash(same.program_key()) == hash(base.program_key())
    for changed in (Config(discriminator_steps=3), Config(algo="gail"), Config(seed_batch=2)):
        assert changed.program_key() != base.program_key()


def _leaf_keys(node, prefix=""):
    for f in dataclasses.fields(node):
        value = getattr(node, f.name)
        if dataclasses.is_dataclass(value):
            yield from _leaf_keys(value, f"{prefix}{f.name}.")
        else:
            yield f"{prefix}{f.name}"


def test_every_hyper_parameter_has_a_domain_its_default_is_in():
    assert sorted(DOMAINS) == sorted(_leaf_keys(Config()))
    for key, domain in DOMAINS.items():
        value = Config()
        for name in key.split("."):
            value = getattr(value, name)
        assert domain.holds(value), key


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
        ("prior=flat", "prior must be one of uniform, mixture; got 'flat'"),
    ],
)
def test_a_value_outside_its_domain_is_refused_in_one_line(setting, message):
    with pytest.raises(SettingError) as error:
        Config().with_settings([setting])
    assert message in str(error.value) and "\n" not in str(error.value)
    assert error.value.key == setting.partition("=")[0]


def test_values_at_the_edges_of_their_domains_are_accepted():
    config = Config().with_settings(
        ["gamma=1", "gae_lambda=1", "trpo.cg_damping=0", "seed_batch=1"]
    )
    assert (config.gamma, config.gae_lambda, config.trpo.cg_damping) == (1.0, 1.0, 0.0)
