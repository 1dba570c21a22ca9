"""Run hyper-parameters by layer: paper defaults, env-dependent rollout sizes, the typed options,
the flat --set namespace, domains, and serialisation (also of the committed runs)."""

import dataclasses
import glob
import json
import os
import types

import pytest

import envs
from emgail_jax.method.config import (
    DOMAINS,
    RESEED_WINDOWS,
    SETTINGS,
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

RUNS = os.path.join(os.path.dirname(__file__), "..", "results", "runs")


def _fake_env(name, episode_length):
    """``resolved`` reads only the env's name and episode length."""
    return types.SimpleNamespace(name=name, episode_length=episode_length)


def _stored_config(cell: str) -> dict:
    with open(os.path.join(RUNS, cell, "summary.json")) as f:
        return json.load(f)["config"]


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
    assert {key: written[key] for key in stored} == stored


def test_an_old_committed_summary_takes_the_defaults_of_its_time():
    """``driver-r10-emgail`` predates the prior, re-seeding and the gradient penalty: it reads
    with re-seeding off and the settings it lacks at their defaults."""
    stored = _stored_config("driver-r10-emgail")
    assert "reseed" not in stored and "prior" not in stored
    config = RunConfig.from_dict(stored)
    assert not config.method.e_step.reseed and config.method.e_step.prior is Prior.UNIFORM
    assert config.method.m_step.gradient_penalty == 0.0
    written = config.to_dict()
    assert {key: written[key] for key in stored if key != "hidden"} == {
        key: value for key, value in stored.items() if key != "hidden"
    }


def test_every_committed_summary_reads():
    cells = glob.glob(os.path.join(RUNS, "*", "summary.json"))
    assert len(cells) >= 79
    for path in cells:
        with open(path) as f:
            RunConfig.from_dict(json.load(f)["config"])


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


@pytest.mark.parametrize(
    ("alone", "message", "with_what_it_needs", "field", "value"),
    [
        (
            "discriminator_support_in_box=true",
            "give discriminator_support_noise=S too",
            "discriminator_support_noise=3",
            "support_in_box",
            True,
        ),
        (
            "discriminator_gradient_penalty_from=100",
            "give discriminator_gradient_penalty=W too",
            "discriminator_gradient_penalty=10",
            "gradient_penalty_from",
            100,
        ),
    ],
)
def test_an_option_without_the_one_it_modifies_is_refused_in_one_line(
    alone, message, with_what_it_needs, field, value
):
    with pytest.raises(ValueError, match=message) as error:
        RunConfig().with_settings([alone])
    assert "\n" not in str(error.value)
    config = RunConfig().with_settings([with_what_it_needs, alone])
    assert getattr(config.method.m_step, field) == value
    assert getattr(RunConfig().method.m_step, field) != value  # off by default


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


def _leaf_paths(node, prefix=()):
    for f in dataclasses.fields(node):
        value = getattr(node, f.name)
        if dataclasses.is_dataclass(value) and not isinstance(value, TRPOConfig):
            yield from _leaf_paths(value, (*prefix, f.name))
        else:
            yield (*prefix, f.name)


def test_the_flat_table_covers_every_field_once():
    paths = [setting.path for setting in SETTINGS.values()]
    assert sorted(paths) == sorted(_leaf_paths(RunConfig()))
    assert len(set(paths)) == len(paths)


def test_every_hyper_parameter_has_a_domain_its_default_is_in():
    trpo = {f"trpo.{f.name}" for f in dataclasses.fields(TRPOConfig)}
    assert set(DOMAINS) == (set(SETTINGS) - {"trpo"}) | trpo
    for key, domain in DOMAINS.items():
        name, _, field = key.partition(".")
        value = RunConfig().value(name)
        assert domain.holds(getattr(value, field) if field else value), key


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


def test_a_layer_built_alone_is_checked_too():
    with pytest.raises(SettingError, match="gamma must be in"):
        BStepConfig(gamma=2.0)
    with pytest.raises(SettingError, match=r"trpo\.max_kl must be a positive number"):
        BStepConfig(trpo=TRPOConfig(max_kl=0.0))
    with pytest.raises(SettingError, match="algo must be one of emgail, infogail, gail"):
        MethodConfig(algo="ppo")


def test_values_at_the_edges_of_their_domains_are_accepted():
    config = RunConfig().with_settings(
        ["gamma=1", "gae_lambda=1", "trpo.cg_damping=0", "seed_batch=1", "snapshot_every=0"]
    )
    b_step = config.method.b_step
    assert (b_step.gamma, b_step.gae_lambda, b_step.trpo.cg_damping) == (1.0, 1.0, 0.0)
