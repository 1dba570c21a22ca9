"""The refit's and the check's settings, by the keys ``--set KEY=VALUE`` gives them, typed and
checked once here; and ``--refit``'s recipe, the settings of the refit that re-optimises best
where it was measured (docs/reward.md, "The refit")."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
from collections.abc import Callable

from emgail_jax.host.run_spec import RunError
from emgail_jax.method.config import REWARD_FORMS
from emgail_jax.reward.refit import Refit

ABSORBING_REWARDS = ("learned", "random")
# The rewards a check reads, made before it: the run's saved one (RUN/reward/, written by
# python -m emgail_jax.refit) or the paper's, the run's own discriminators.
REWARD_SOURCES = ("saved", "paper")


@dataclasses.dataclass(frozen=True)
class Setting:
    """One ``--set`` key: its type, its value when not given (None: the recipe's or the run's),
    what it takes (``valid``, said as ``takes``) and what it does."""

    kind: type
    default: object
    takes: str
    help: str
    valid: Callable[[object], bool] = lambda value: True


_at_least = lambda low: lambda value: value >= low
_one_of = lambda names: lambda value: value in names

# The refit's settings (python -m emgail_jax.refit, and reoptimize's refit before its check).
REFIT_SETTINGS = {
    "consolidate": Setting(int, None, "a number of steps >= 0", "the refit's steps (0: none)",
                           _at_least(0)),
    "consolidate_penalty": Setting(float, None, "a weight >= 0", "its gradient penalty",
                                   _at_least(0)),
    "consolidate_fresh": Setting(bool, None, "true or false",
                                 "from new discriminator weights, not the run's final ones"),
    "consolidate_noise": Setting(float, None, "a standard deviation >= 0",
                                 "a copy of every policy sample moved by noise of this size is "
                                 "a further negative", _at_least(0)),
    "consolidate_batch": Setting(int, None, "a number of samples >= 0",
                                 "samples per intention each step draws (0: all)", _at_least(0)),
    "consolidate_ranking": Setting(float, None, "a weight >= 0",
                                   "rank the snapshots by iteration, the demonstrations above "
                                   "them (emgail_jax.reward.ranking)", _at_least(0)),
    "consolidate_ranking_random": Setting(bool, False, "true or false",
                                          "random actions rank below the oldest snapshot"),
    "consolidate_ranking_still": Setting(bool, False, "true or false",
                                         "actions held still rank below the oldest snapshot"),
    "consolidate_absorbing": Setting(bool, None, "true or false",
                                     "termination as an absorbing state (DAC) in the refit"),
}  # fmt: skip

# The check's settings beside the refit's (python -m emgail_jax.reoptimize).
CHECK_SETTINGS = {
    **REFIT_SETTINGS,
    "gamma": Setting(float, None, "a number in (0, 1]", "the fresh agents' discount",
                     lambda value: 0 < value <= 1),
    "gae_lambda": Setting(float, None, "a number in [0, 1]", "their GAE lambda",
                          lambda value: 0 <= value <= 1),
    "value_target_scaling": Setting(bool, None, "true or false",
                                    "their value baselines fit standardised targets"),
    "reward_form": Setting(str, None, "one of " + ", ".join(REWARD_FORMS),
                           "the reward the discriminator defines", _one_of(REWARD_FORMS)),
    "absorbing_reward": Setting(str, None, "learned or random",
                                "what a fall is paid per step left: the absorbing state's "
                                "learned reward, or what random actions earn",
                                _one_of(ABSORBING_REWARDS)),
    "reward": Setting(str, None, "saved or paper",
                      "the reward checked: the run's saved one (RUN/reward/, python -m "
                      "emgail_jax.refit), the default where there is one, or the paper's, the "
                      "run's own discriminators", _one_of(REWARD_SOURCES)),
    "across_seeds": Setting(bool, False, "true or false",
                            "train on the mean of every run seed's reward"),
    "reference_draws": Setting(int, 3, "a number >= 1",
                               "with --env-set, ERD's 0 is the best of N true-reward draws",
                               _at_least(1)),
}  # fmt: skip


# What RUN/reward/ records as its recipe: the refit's settings and how the refit is read.
SAVED_SETTINGS = {
    **REFIT_SETTINGS,
    **{key: CHECK_SETTINGS[key] for key in ("reward_form", "absorbing_reward")},
}


def add_settings_option(parser: argparse.ArgumentParser, table: dict[str, Setting], what: str):
    """A command's repeatable ``--set KEY=VALUE`` of the keys of ``table``."""
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        dest="set",
        help=f"{what} (repeatable): "
        + "; ".join(f"{key}: {setting.help}" for key, setting in table.items()),
    )


def parsed_command_line(parser: argparse.ArgumentParser, argv, table: dict[str, Setting]):
    """``argv`` parsed by ``parser``, with every key of ``table`` at its ``--set`` value or its
    default; exits 2 with one line on a setting it does not take (``parser.error``)."""
    args = parser.parse_args(argv)
    try:
        settings = parsed_settings(args.set, table)
    except ValueError as error:
        parser.error(str(error))
    return argparse.Namespace(**vars(args), **settings)


def parsed_settings(texts: list[str], table: dict[str, Setting]) -> dict:
    """Every key of ``table`` at its value in ``texts`` (``KEY=VALUE``, the last one given
    wins) or its default.

    Raises:
      ValueError: an unknown key (the message lists the keys) or a value the key does not take.
    """
    values = {key: setting.default for key, setting in table.items()}
    for text in texts:
        key, sep, given = (part.strip() for part in text.partition("="))
        if key not in table:
            raise ValueError(f"--set: unknown key '{key}'; the keys: {', '.join(table)}")
        if not sep:
            raise ValueError(f"--set takes KEY=VALUE, e.g. {key}=...; got '{text}'")
        values[key] = _value(key, given, table[key])
    return values


def _value(key: str, text: str, setting: Setting):
    """``text`` as a value of ``setting``, checked."""
    value = None
    if setting.kind is bool:
        value = {"true": True, "false": False}.get(text.lower())
    elif setting.kind is str:
        value = text
    else:
        with contextlib.suppress(ValueError):
            value = setting.kind(text)
    if value is None or not setting.valid(value):
        raise ValueError(f"--set {key}={text}: {key} takes {setting.takes}")
    return value


# `--refit`: from new weights against every snapshot's policy and noisy copies of its samples
# (docs/reward.md, "The refit").
REFIT = {
    "consolidate": 4000,
    "consolidate_penalty": 10.0,
    "consolidate_fresh": True,
    "consolidate_noise": 1.0,
    "consolidate_batch": 5000,
}


# What `--refit` adds on the locomotion envs where the plain refit's agents stay near random
# actions: the snapshots ranked by iteration, read as the logit, and hopper's falls priced by an
# absorbing state at what random actions earn, not at its learned reward, whose price for a
# fall kept agents standing (docs/reward.md, "The refit"). The fresh agents' budget is the
# env's declaration (envs.Env.rl_budget).
REFIT_BY_ENV: dict[str, dict] = {
    "hopper": {
        "consolidate_ranking": 10.0,
        "consolidate_absorbing": True,
        "reward_form": "logit",
        "absorbing_reward": "random",
    },
    "halfcheetah": {
        "consolidate_ranking": 30.0,
        "reward_form": "logit",
    },
}


# The refit's options that are off unless given or in the env's recipe.
OFF_UNLESS_GIVEN = {"consolidate_ranking": 0.0, "consolidate_absorbing": False}


def spelled(settings: dict) -> str:
    """``settings`` as ``--set`` takes them, ``KEY=VALUE`` after one another."""
    as_text = lambda value: f"{value:g}" if isinstance(value, float) else str(value).lower()
    return " ".join(f"{key}={as_text(value)}" for key, value in settings.items())


def refit_extras(env: str) -> str:
    """``--refit``'s settings on ``env`` beyond :data:`REFIT`, spelled as ``--set`` takes them."""
    return spelled(REFIT_BY_ENV.get(env, {}))


def with_refit_recipe(args: argparse.Namespace, env: str | None = None) -> argparse.Namespace:
    """``args`` with every refit setting it left unset at the :data:`REFIT` recipe's value
    (and ``env``'s :data:`REFIT_BY_ENV`) if ``args.refit``, and at none otherwise. The reward
    form, where neither the recipe nor the command line names one, is
    :func:`refit_reward_form`'s."""
    args = argparse.Namespace(**vars(args))
    recipe = {**REFIT, **REFIT_BY_ENV.get(env, {})} if args.refit else {}
    unset = {**{option: type(value)(0) for option, value in REFIT.items()}, **OFF_UNLESS_GIVEN}
    for option, off in unset.items():
        if getattr(args, option) is None:
            setattr(args, option, recipe.get(option, off))
    if not args.consolidate_absorbing:  # the recipe prices no absorbing state it was told to drop
        recipe.pop("absorbing_reward", None)
    for option in ("reward_form", "absorbing_reward"):
        if getattr(args, option, None) is None:
            setattr(args, option, recipe.get(option))
    return args


def refit_reward_form(args: argparse.Namespace, terminates: bool) -> str | None:
    """The reward form the fresh agents read: ``reward_form`` if given; with ``--refit``, log
    D (below 0 wherever D < 1, so nothing off the demonstrations is paid) unless episodes end
    early without an absorbing state, where log D pays for falling and the run's own form
    stays (see docs/defaults.md, `reward_form`); otherwise None, the run's."""
    from emgail_jax.method.config import RewardForm

    pays_falling = terminates and not args.consolidate_absorbing
    if args.reward_form is not None or not args.refit or pays_falling:
        return args.reward_form
    return RewardForm.LOG_D.value


def check_refit_settings(args: argparse.Namespace) -> None:
    """Raises RunError where the refit's settings do not go together."""
    given = [key for key in REFIT_SETTINGS if key != "consolidate" and getattr(args, key)]
    if given and not args.consolidate:
        raise RunError(f"--set {given[0]} goes with a refit: give --refit or consolidate=STEPS")
    for level in ("random", "still"):
        if getattr(args, f"consolidate_ranking_{level}") and not args.consolidate_ranking:
            raise RunError(f"consolidate_ranking_{level} goes with consolidate_ranking=WEIGHT")


# Each refit setting: its Refit field, and how the name of a saved refit spells it when it is
# on (in this order).
_REFIT_FIELDS = (
    ("consolidate", "steps", "consolidated-{}"),
    ("consolidate_penalty", "gradient_penalty", "penalty-{:g}"),
    ("consolidate_fresh", "fresh", "fresh"),
    ("consolidate_noise", "support_noise", "noise-{:g}"),
    ("consolidate_batch", "batch", "batch-{}"),
    ("consolidate_ranking", "ranking", "ranking-{:g}"),
    ("consolidate_ranking_random", "ranking_random", "random"),
    ("consolidate_ranking_still", "ranking_still", "still"),
    ("consolidate_absorbing", "absorbing", "absorbing"),
)


def refit_parts(args) -> list[str]:
    """The snapshot and the refit's settings: with ``consolidate``, the name of the refitted
    reward it saves (``RUN/rewards/NAME``), whatever reward form reads it."""
    parts = [] if args.snapshot is None else [f"snapshot-{args.snapshot}"]
    if not args.consolidate:
        return parts
    given = [(form, getattr(args, key)) for key, _, form in _REFIT_FIELDS]
    return parts + [form.format(value) for form, value in given if value]


def refit_of(args) -> Refit:
    """The :class:`~emgail_jax.reward.refit.Refit` the ``consolidate*`` settings ask for."""
    return Refit(**{field: getattr(args, key) for key, field, _ in _REFIT_FIELDS})
