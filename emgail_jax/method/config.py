"""Hyper-parameters of a run, with the paper's defaults (§5.3) and per-env rollout sizes."""

from __future__ import annotations

import ast
import dataclasses
import math
import numbers
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from emgail_jax.method.algorithms import NAMES, REWARD_FORMS
from emgail_jax.method.trpo import TRPOConfig

INTENTION_INPUTS = ("onehot", "heads")
RESPONSIBILITIES = ("trajectory", "trajectory-centered", "pair", "labels")
REWARD_FROM = ("updated", "previous")
PRIORS = ("uniform", "mixture")


@dataclass(frozen=True)
class Domain:
    """The values a hyper-parameter may take: ``contains(value)``, and what it says to a user
    ("at least 1")."""

    contains: Callable[[object], bool]
    text: str

    def holds(self, value) -> bool:
        try:
            return bool(self.contains(value))
        except TypeError:  # a value of another type (None, a string for a number)
            return False


def _numbers(test: Callable[[float], bool], text: str) -> Domain:
    return Domain(lambda v: not isinstance(v, (bool, str)) and math.isfinite(v) and test(v), text)


def _one_of(choices: Sequence[str]) -> Domain:
    return Domain(lambda v: v in choices, f"one of {', '.join(choices)}")


def _or_default(domain: Domain) -> Domain:
    return Domain(lambda v: v is None or domain.holds(v), f"{domain.text} (or None, the default)")


COUNT = Domain(
    lambda v: isinstance(v, numbers.Integral) and not isinstance(v, bool) and v >= 1, "at least 1"
)
POSITIVE = _numbers(lambda v: v > 0, "a positive number")
NON_NEGATIVE = _numbers(lambda v: v >= 0, "a number >= 0")
FRACTION = _numbers(lambda v: 0 < v <= 1, "in (0, 1]")
FINITE = _numbers(lambda v: True, "a finite number")
WIDTHS = Domain(lambda v: all(COUNT.holds(w) for w in v), "a tuple of layer widths >= 1")
BOOLEAN = Domain(lambda v: isinstance(v, bool), "True or False")

# Every hyper-parameter's domain, by its --set key; Config checks them all on construction.
DOMAINS = {
    "algo": _one_of(NAMES),
    "iterations": COUNT,
    "num_envs": _or_default(COUNT),
    "rollout_length": _or_default(COUNT),
    "eval_every": COUNT,
    "hidden": WIDTHS,
    "intention_input": _one_of(INTENTION_INPUTS),
    "responsibilities": _one_of(RESPONSIBILITIES),
    "prior": _one_of(PRIORS),
    "reseed": BOOLEAN,
    "reseed_patience": COUNT,
    "reseed_window": COUNT,
    "reseed_attempts": Domain(
        lambda v: isinstance(v, numbers.Integral) and not isinstance(v, bool) and v >= 0,
        "an integer >= 0",
    ),
    "choose_intentions": BOOLEAN,
    "init_log_std": FINITE,
    "obs_clip": POSITIVE,
    "gamma": FRACTION,
    "gae_lambda": FRACTION,
    "trpo.max_kl": POSITIVE,
    "trpo.cg_iterations": COUNT,
    "trpo.cg_damping": NON_NEGATIVE,
    "trpo.line_search_steps": COUNT,
    "trpo.line_search_decay": _numbers(lambda v: 0 < v < 1, "in (0, 1)"),
    "trpo.accept_ratio": _numbers(lambda v: 0 <= v <= 1, "in [0, 1]"),
    "value_learning_rate": POSITIVE,
    "value_epochs": COUNT,
    "value_minibatches": COUNT,
    "discriminator_learning_rate": POSITIVE,
    "discriminator_steps": COUNT,
    "discriminator_gradient_penalty": NON_NEGATIVE,
    "posterior_learning_rate": POSITIVE,
    "posterior_steps": COUNT,
    "reward_from": _one_of(REWARD_FROM),
    "reward_form": _one_of(REWARD_FORMS),
    "info_weight": NON_NEGATIVE,
    "chunk_size": COUNT,
    "seed_batch": _or_default(COUNT),
}


class SettingError(ValueError):
    """A hyper-parameter outside its domain; ``key`` names it as ``--set`` does."""

    def __init__(self, key: str, value, domain: Domain):
        self.key, self.value, self.domain = key, value, domain
        super().__init__(self.naming(key))

    def naming(self, name: str) -> str:
        """The message with the setting called ``name`` (e.g. its command-line option)."""
        return f"{name} must be {self.domain.text}; got {self.value!r}"


@dataclass(frozen=True)
class Config:
    """Everything that shapes one training run. Frozen: it is static inside ``jit``."""

    algo: str = "emgail"
    iterations: int = 400
    # Rollouts: `num_envs` envs per intention, `rollout_length` steps each per iteration.
    # None takes the env's default (DRIVER_DEFAULTS / ROBOTICS_DEFAULTS below).
    num_envs: int | None = None
    rollout_length: int | None = None
    # Evaluation: deterministic episodes of every learned intention, one per env of the rollout
    # (`num_envs`, 5 by default; the reacher's 50), every `eval_every` iterations and in each of
    # the last 10, which the final metrics average; the clustering accuracy is measured every
    # iteration.
    eval_every: int = 10
    hidden: tuple[int, ...] = (64, 64)
    # How the intention enters the policy, value and EM-GAIL's discriminator: "heads" (one
    # network per intention, as the paper's public code) or "onehot" (an input of one network,
    # as the paper's Table 2 counts); see emgail_jax.method.networks. Why heads: docs/defaults.md.
    intention_input: str = "heads"
    # The E-step's responsibilities: "trajectory" (each pair takes the posterior of its whole
    # demonstration; emgail_jax.method.posterior.trajectory_responsibilities), "trajectory-centered"
    # (the same, each intention's log-evidence centred over the demonstrations), "pair" (the
    # paper's eq. 18) or "labels" (the hidden labels: an oracle, for diagnosis only). Trajectory
    # is a departure from the paper, made because the per-pair E-step lets hopper-3 and
    # reacher-4 collapse onto one intention: docs/defaults.md.
    responsibilities: str = "trajectory"
    # The E-step's prior over the intentions: "uniform" (1/K, the paper's) or "mixture" (weights
    # w_i estimated as EM does for a mixture: each intention's mean responsibility over the
    # demonstration pairs, updated every E-step), for demonstrations in unequal shares.
    prior: str = "uniform"
    # Re-seeding an emptied intention (emgail_jax.method.reseeding, docs/no-empty-intention.md):
    # one that holds less than half a demonstration's share for `reseed_patience` E-steps takes
    # the worse-explained half of the largest intention's demonstrations for `reseed_window`
    # E-steps, at most `reseed_attempts` times per intention. Off for runs written before it.
    reseed: bool = True
    reseed_patience: int = 10
    reseed_window: int = 10
    reseed_attempts: int = 3
    # Whether K is chosen from the data (`--intentions auto`): training starts with the most
    # intentions allowed, keeps those whose mixture weight holds demonstrations, and at the end
    # those the seeds agree on (emgail_jax.method.choosing): docs/choosing-k.md.
    choose_intentions: bool = False
    # The policy's initial log-std, 0 as in the paper's public code: a wide start lets the E-step
    # separate the intentions before the policies commit (docs/defaults.md).
    init_log_std: float = 0.0
    obs_clip: float = 5.0
    # B-step (TRPO on the pseudo-reward) and its value baseline.
    gamma: float = 0.995
    gae_lambda: float = 0.97
    trpo: TRPOConfig = field(default_factory=TRPOConfig)
    value_learning_rate: float = 1e-3
    # Epochs of the value baseline's fit per iteration (each `value_minibatches` Adam steps); the
    # paper gives none, and fewer cannot follow halfcheetah's values (docs/defaults.md).
    value_epochs: int = 20
    value_minibatches: int = 4
    # E-step and M-step: full-batch Adam steps per iteration (paper: Adam, lr 1e-3; the number
    # of steps is not given, ours are measured on the driver: docs/defaults.md).
    discriminator_learning_rate: float = 1e-3
    discriminator_steps: int = 10
    # Weight of a zero-centred gradient penalty on the discriminator's logit, on the expert
    # pairs and the policy samples alike (Lipschitz control for a reward that re-optimises,
    # docs/rewards-that-reoptimise.md); 0, the default, computes none.
    discriminator_gradient_penalty: float = 0.0
    posterior_learning_rate: float = 1e-3
    posterior_steps: int = 20
    # Which discriminator (and, for Info/IntentionGAIL, posterior) scores the B-step's reward:
    # "updated", after this iteration's E- and M-step (Algorithm 1), or "previous", before them,
    # as the paper's public code does (it computes the reward during the rollout), so that the
    # reward comes from networks that have not yet been fitted to the samples they score.
    reward_from: str = "updated"
    # The B-step reward of a discriminator logit f: "gail", -log(1 - D) = softplus(f), the
    # paper's, or "logit", f itself (AIRL's form), which pays nothing for merely staying alive.
    reward_form: str = "gail"
    # Info/IntentionGAIL's lambda (eq. 23): 1 weighs log P(i|s,a) like the discriminator term
    # (docs/defaults.md).
    info_weight: float = 1.0
    # Iterations compiled into one call; host work (logs, progress) happens between chunks.
    chunk_size: int = 10
    # Seeds vmapped together on one device; None: one at a time on CPU, all on accelerators
    # (emgail_jax.host.seed_runner.default_seed_batch). Part of the config because it changes the
    # floating-point results slightly, and a resumed run must continue them exactly.
    seed_batch: int | None = None

    def __post_init__(self):
        for key, domain in DOMAINS.items():
            value = self
            for name in key.split("."):
                value = getattr(value, name)
            if not domain.holds(value):
                raise SettingError(key, value, domain)
        if self.choose_intentions and (self.prior != "mixture" or self.algo == "gail"):
            raise ValueError(
                "choosing the number of intentions needs a posterior and the mixture prior: "
                "an algo other than gail, and prior mixture"
            )

    def replace(self, **changes) -> Config:
        return dataclasses.replace(self, **changes)

    def with_settings(self, settings: Sequence[str]) -> Config:
        """A copy with ``KEY=VALUE`` settings applied, e.g. ``["discriminator_steps=5",
        "trpo.cg_damping=0"]`` (``run --set``): any hyper-parameter, typed like its default."""
        config = self
        for setting in settings:
            key, sep, text = setting.partition("=")
            if not sep or not key.strip():
                raise ValueError(f"a setting is KEY=VALUE, e.g. trpo.max_kl=0.02; got '{setting}'")
            config = _with_setting(config, key.strip().split("."), text.strip(), key.strip())
        return config

    def resolved(self, env) -> Config:
        """Fills the env-dependent defaults from ``env``."""
        defaults = rollout_defaults(env.name, env.episode_length)
        return self.replace(
            num_envs=self.num_envs or defaults["num_envs"],
            rollout_length=self.rollout_length or defaults["rollout_length"],
        )

    def program_key(self) -> Config:
        """This config with the fields that do not shape the compiled update cleared: the host's
        schedule (iterations, evaluation cadence, chunks) and what is passed as data (the info
        weight, see ``training.RunData``)."""
        return self.replace(iterations=1, eval_every=1, chunk_size=1, info_weight=0.0)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, values: dict) -> Config:
        """Inverse of :meth:`to_dict` (e.g. the ``config`` of a ``summary.json``)."""
        values = dict(values)
        # Runs written before the option existed fed the intention as a one-hot input.
        values.setdefault("intention_input", "onehot")
        values.setdefault("seed_batch", None)
        values.setdefault("responsibilities", "pair")
        values.setdefault("eval_every", 1)
        values.setdefault("reward_from", "updated")
        values.setdefault("reward_form", "gail")
        values.setdefault("reseed", False)
        values.pop("eval_episodes", None)  # runs written before evaluation used num_envs
        values["hidden"] = tuple(values["hidden"])
        values["trpo"] = TRPOConfig(**values["trpo"])
        return cls(**values)


def _with_setting(node, path: list[str], text: str, key: str):
    """``node`` (a frozen dataclass) with the field at ``path`` parsed from ``text``."""
    names = [f.name for f in dataclasses.fields(node)]
    if path[0] not in names:
        raise ValueError(f"unknown setting '{key}'; choose one of {', '.join(names)}")
    current = getattr(node, path[0])
    if len(path) > 1:
        if not dataclasses.is_dataclass(current):
            raise ValueError(f"'{'.'.join(path[:1])}' of '{key}' has no fields")
        value = _with_setting(current, path[1:], text, key)
    else:
        value = _parse_setting(text, current, key)
    return dataclasses.replace(node, **{path[0]: value})


def _parse_setting(text: str, current, key: str):
    """``text`` as a value of the type of ``current`` (the default it replaces)."""
    if isinstance(current, str):
        return text
    if dataclasses.is_dataclass(current):
        raise ValueError(f"'{key}' has fields: set one of them, e.g. {key}.<field>=...")
    try:
        value = ast.literal_eval(text)
    except (ValueError, SyntaxError):
        raise ValueError(f"'{key}={text}': '{text}' is not a number, tuple or boolean") from None
    if isinstance(current, bool) or current is None:
        return value
    if isinstance(current, tuple):
        return tuple(value) if isinstance(value, (list, tuple)) else (value,)
    if (
        isinstance(current, float)
        and isinstance(value, (int, float))
        and not isinstance(value, bool)
    ):
        return float(value)
    if isinstance(current, int) and isinstance(value, int) and not isinstance(value, bool):
        return value
    raise ValueError(f"'{key}' takes a value like its default {current!r}; got '{text}'")


def rollout_defaults(env_name: str, episode_length: int) -> dict:
    """Samples per intention per iteration: the paper's 5 trajectories of one episode each for
    the driver and the 500-step robotics tasks; the 50-step reacher runs 50 episodes in parallel
    so that it too collects 2500 pairs per intention."""
    num_envs = 50 if env_name == "reacher" else 5
    return {"num_envs": num_envs, "rollout_length": episode_length}
