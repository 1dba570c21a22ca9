"""Run hyper-parameters by layer: paper defaults, env-dependent rollout sizes, the typed options,
the domains each layer checks, and what the settings need of each other (the flat namespace:
test_settings.py)."""

import dataclasses
import json
import types

import pytest

import envs
from emgail_jax.method.config import (
    RESEED_WINDOWS,
    AlgorithmName,
    BStepConfig,
    EStepConfig,
    IntentionInput,
    MethodConfig,
    Prior,
    ResponsibilityMode,
    RewardForm,
    RewardFrom,
    RewardRecipe,
    RunConfig,
    RunSchedule,
    SettingError,
    TRPOConfig,
    rollout_defaults,
)


def _fake_env(name, episode_length):
    """``resolved`` reads only the env's name and episode length."""
    return types.SimpleNamespace(name=name, episode_length=episode_length)


def test_paper_defaults():
    config = RunConfig()
    method, schedule = config.method, config.schedule
    assert method.algo is AlgorithmName.EMGAIL and schedule.iterations == 400
    assert method.b_step.gamma == 0.995 and 0.97 <= method.b_step.gae_lambda <= 0.98
    assert method.b_step.trpo == TRPOConfig()
    assert method.b_step.trpo.max_kl == 0.01 and method.b_step.trpo.cg_iterations == 10
    assert method.m_step.learning_rate == method.e_step.learning_rate == 1e-3
    assert method.networks.hidden == (64, 64) and method.networks.obs_clip == 5.0
    # ERD from at least 5 deterministic episodes: one per env of the rollout.
    assert config.resolved(envs.make("driver")).method.rollout.num_envs >= 5
    assert method.rollout.num_envs is None and method.rollout.rollout_length is None


def test_resolved_fills_the_driver_defaults():
    resolved = RunConfig().resolved(envs.make("driver", intentions=2))
    rollout = resolved.method.rollout
    assert (rollout.num_envs, rollout.rollout_length) == (5, 100)
    # Everything else is unchanged.
    assert resolved.with_values(num_envs=None, rollout_length=None, reseed_window=None) == (
        RunConfig()
    )


@pytest.mark.parametrize(
    ("algo", "window"), [("emgail", 30), ("infogail", 10), ("gail", RESEED_WINDOWS["gail"])]
)
def test_the_reseeding_window_is_the_algorithms_unless_given(algo, window):
    driver = _fake_env("driver", 100)
    config = RunConfig().with_values(algo=algo)
    assert config.value("reseed_window") is None
    assert config.resolved(driver).value("reseed_window") == window
    given = config.with_values(reseed_window=7).resolved(driver)
    assert given.value("reseed_window") == 7
    assert given.resolved(driver) == given  # idempotent once filled


def test_resolved_follows_the_env_episode_length_and_wrappers():
    driver = envs.make("driver", intentions=2, episode_length=30)
    assert MethodConfig().resolved(driver).rollout.rollout_length == 30
    wrapped = envs.wrap_for_training(driver)
    assert MethodConfig().resolved(wrapped).rollout.rollout_length == 30


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
    rollout = MethodConfig().resolved(_fake_env(name, length)).rollout
    assert (rollout.num_envs, rollout.rollout_length) == expected
    # 2500 pairs per intention per iteration on the robotics tasks (5 x 500 or 50 x 50).
    if name != "driver":
        assert expected[0] * expected[1] == 2500


def test_explicit_sizes_win_over_the_env_defaults():
    config = RunConfig().with_values(num_envs=2, rollout_length=20)
    resolved = config.resolved(_fake_env("reacher", 50))
    assert (resolved.value("num_envs"), resolved.value("rollout_length")) == (2, 20)
    partial = RunConfig().with_values(num_envs=3).resolved(_fake_env("reacher", 50))
    assert (partial.value("num_envs"), partial.value("rollout_length")) == (3, 50)
    assert resolved.resolved(_fake_env("driver", 100)) == resolved  # idempotent once filled


def test_with_values_returns_a_new_config_and_the_original_is_frozen():
    config = RunConfig()
    changed = config.with_values(algo="gail", iterations=3, trpo=TRPOConfig(max_kl=0.05))
    assert (changed.method.algo, changed.schedule.iterations) == ("gail", 3)
    assert changed.method.b_step.trpo.max_kl == 0.05
    assert (config.method.algo, config.schedule.iterations) == ("emgail", 400)
    with pytest.raises(dataclasses.FrozenInstanceError):
        config.method.algo = "gail"
    with pytest.raises(ValueError, match="unknown setting 'no_such_field'"):
        config.with_values(no_such_field=1)


def test_configs_are_hashable_for_use_as_static_arguments():
    assert hash(MethodConfig()) == hash(MethodConfig())
    assert RunConfig().with_values(hidden=(8,)) != RunConfig()
    gail = RunConfig().with_values(algo="gail")
    assert len({RunConfig().method, RunConfig().method, gail.method}) == 2


def test_options_are_typed_once_and_keep_their_spellings():
    """A string given for an option becomes its enum member, equal to its name, and JSON and
    the command line keep the names."""
    method = (
        RunConfig()
        .with_values(
            responsibilities="trajectory-centered", prior="mixture", reward_from="previous"
        )
        .method
    )
    assert method.e_step.responsibilities is ResponsibilityMode.TRAJECTORY_CENTERED
    assert method.e_step.prior is Prior.MIXTURE and method.reward.source is RewardFrom.PREVIOUS
    assert method.e_step.responsibilities == "trajectory-centered"
    assert json.dumps(method.e_step.prior) == '"mixture"'
    assert isinstance(MethodConfig(algo="gail").algo, AlgorithmName)


def test_the_options_behaviour_is_their_properties():
    modes = {
        mode: (mode.per_demonstration, mode.centered, mode.oracle) for mode in ResponsibilityMode
    }
    assert modes == {
        ResponsibilityMode.TRAJECTORY: (True, False, False),
        ResponsibilityMode.TRAJECTORY_CENTERED: (True, True, False),
        ResponsibilityMode.PAIR: (False, False, False),
        ResponsibilityMode.LABELS: (False, False, True),
    }
    assert Prior.MIXTURE.estimated and not Prior.UNIFORM.estimated
    assert IntentionInput.HEADS.heads and not IntentionInput.ONEHOT.heads
    assert RewardFrom.UPDATED.choose(updated=1, previous=2) == 1
    assert RewardFrom.PREVIOUS.choose(updated=1, previous=2) == 2
    assert [name.learns_posterior for name in AlgorithmName] == [True, True, False]


@pytest.mark.parametrize("terminates", [False, True])
def test_a_reward_recipe_is_settings_every_config_takes(terminates):
    assert RewardRecipe.PAPER.settings(terminates) == {}
    recipe = RewardRecipe.FOR_REUSE.settings(terminates)
    config = RunConfig().with_values(**recipe)
    assert {key: config.value(key) for key in recipe} == recipe
    assert config.method.reward_form is RewardForm.LOG_D
    assert config.method.reward.absorbing_state is terminates
    # Every algorithm takes it, and AIRL's discriminator refuses it in one line.
    for algo in AlgorithmName:
        assert RunConfig().with_values(algo=algo, **recipe).method.algo is algo
    with pytest.raises(ValueError, match=r"^discriminator_form airl "):
        RunConfig().with_values(**recipe).with_settings(["discriminator_form=airl"])


def test_choosing_k_needs_a_posterior_and_the_mixture_prior():
    assert RunConfig().with_values(prior="mixture", choose_intentions=True).method.choose_intentions
    for wrong in ({}, {"prior": "mixture", "algo": "gail"}):
        with pytest.raises(ValueError, match="needs a posterior and the mixture prior"):
            MethodConfig(
                algo=wrong.get("algo", "emgail"),
                e_step=EStepConfig(prior=wrong.get("prior", "uniform")),
                choose_intentions=True,
            )


@pytest.mark.parametrize(
    ("settings", "message"),
    [
        (["algo=infogail"], "takes algo emgail or gail, not infogail"),
        (["absorbing_state=true"], "does not take absorbing_state=true"),
        (["reward_form=log-d"], "reward_form applies to discriminator_form gail only"),
        (["discriminator_support_noise=1"], "it takes discriminator_form gail"),
    ],
)
def test_airl_refuses_what_it_does_not_combine_with_in_one_line(settings, message):
    with pytest.raises(ValueError, match=message) as error:
        RunConfig().with_settings([*settings, "discriminator_form=airl"])
    assert "\n" not in str(error.value)


def test_airl_rewards_its_logit_and_gail_its_reward_form():
    airl = RunConfig().with_settings(["discriminator_form=airl", "algo=gail"]).method
    assert airl.m_step.form.airl and airl.reward_form is RewardForm.LOGIT
    log_d = RunConfig().with_settings(["reward_form=log-d"]).method
    assert not log_d.m_step.form.airl and log_d.reward_form is RewardForm.LOG_D
    assert RunConfig().to_dict()["discriminator_form"] == "gail"


@pytest.mark.parametrize("mode", ["pair", "labels"])
def test_tempering_needs_a_trajectory_e_step(mode):
    with pytest.raises(ValueError, match=f"responsibilities {mode} has none") as error:
        RunConfig().with_values(responsibilities=mode).with_settings(
            ["trajectory_temper_iterations=10"]
        )
    assert "\n" not in str(error.value)
    assert RunConfig().with_values(responsibilities=mode).method.e_step == EStepConfig(
        responsibilities=mode
    )  # off, any E-step


def test_tempering_goes_with_either_trajectory_e_step_and_the_mixture_prior():
    assert RunConfig().method.e_step.trajectory_temper_iterations == 0
    for mode in ("trajectory", "trajectory-centered"):
        config = RunConfig().with_settings(
            [f"responsibilities={mode}", "prior=mixture", "trajectory_temper_iterations=30"]
        )
        e_step = config.method.e_step
        assert (e_step.trajectory_temper_iterations, e_step.prior) == (30, Prior.MIXTURE)
        assert RunConfig.from_dict(config.to_dict()) == config
    older = {k: v for k, v in RunConfig().to_dict().items() if k != "trajectory_temper_iterations"}
    assert RunConfig.from_dict(older).method.e_step.trajectory_temper_iterations == 0


def test_program_key_is_the_method_config():
    base = RunConfig()
    same = RunConfig(
        schedule=RunSchedule(iterations=50, eval_every=7, chunk_size=5, seed_batch=2),
        info_weight=0.3,
    )
    assert same.program_key() == base.program_key() == base.method
    assert hash(same.program_key()) == hash(base.program_key())
    for changed in (
        {"discriminator_steps": 3},
        {"algo": "gail"},
        {"reward_form": "logit"},
        {"absorbing_state": True},
    ):
        assert base.with_values(**changed).program_key() != base.program_key()


def _layers(node):
    yield node
    for f in dataclasses.fields(node):
        if "domain" not in f.metadata:
            yield from _layers(getattr(node, f.name))


def test_every_field_is_a_layer_or_has_a_domain_its_default_is_in():
    for layer in _layers(RunConfig()):
        for f in dataclasses.fields(layer):
            value = getattr(layer, f.name)
            if "domain" in f.metadata:
                assert f.metadata["domain"].holds(value), (type(layer).__name__, f.name)
            else:
                assert dataclasses.is_dataclass(value), f.name


def test_a_layer_built_alone_is_checked_too():
    with pytest.raises(SettingError, match="gamma must be in"):
        BStepConfig(gamma=2.0)
    with pytest.raises(SettingError, match=r"trpo\.max_kl must be a positive number"):
        TRPOConfig(max_kl=0.0)
    with pytest.raises(SettingError, match="algo must be one of emgail, infogail, gail"):
        MethodConfig(algo="ppo")
