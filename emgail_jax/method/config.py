"""Hyper-parameters of a run, by layer: what the compiled method takes (:class:`MethodConfig`,
one sub-config per step), what only the host reads (:class:`RunSchedule`), and the run's data
(Info/IntentionGAIL's lambda), with the paper's defaults (§5.3) and per-env rollout sizes.

Options are typed here, once (``enum`` members whose values are the command line's and
``summary.json``'s spellings, with the behaviour the method needs as properties), and every
setting is checked against its domain (:data:`SETTINGS`) whenever a config is built. The
user's namespace is flat (``--set discriminator_steps=5``, ``summary.json``'s ``config``):
:data:`SETTINGS` maps each flat key to its place in the layers. Why the defaults are what they
are, with the measurements: docs/defaults.md.
"""

from __future__ import annotations

import ast
import dataclasses
import enum
import math
import numbers
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field


class AlgorithmName(enum.StrEnum):
    """``--algo``: which of the three algorithms a run trains."""

    EMGAIL = "emgail"
    INFOGAIL = "infogail"
    GAIL = "gail"

    @property
    def learns_posterior(self) -> bool:
        """Whether it trains P(i | s, a) (EM-GAIL's E-step, Info/IntentionGAIL's eq. 21). Its
        other choices, which need JAX: :data:`emgail_jax.method.algorithms.ALGORITHMS`."""
        return self is not AlgorithmName.GAIL


class RewardForm(enum.StrEnum):
    """The B-step reward of a discriminator logit f (``--set reward_form=...``;
    ``algorithms.imitation_reward`` computes it)."""

    GAIL = "gail"  # -log(1 - D) = softplus(f), the paper's
    LOGIT = "logit"  # log D - log(1 - D) = f, AIRL's form
    LOG_D = "log-d"  # log D = -softplus(-f), never above 0


class DiscriminatorForm(enum.StrEnum):
    """``--set discriminator_form=...``: what the M-step's discriminator is
    (:mod:`emgail_jax.method.discriminator`; AIRL's: :mod:`emgail_jax.method.airl`)."""

    GAIL = "gail"  # D = sigmoid(f(s, a, i)), the paper's
    AIRL = "airl"  # D = exp f / (exp f + pi_i(a | s)), f = g_i(s) + gamma h_i(s') - h_i(s)

    @property
    def airl(self) -> bool:
        return self is DiscriminatorForm.AIRL


@dataclass(frozen=True)
class TRPOConfig:
    """The B-step's TRPO (:mod:`emgail_jax.method.trpo`)."""

    max_kl: float = 0.01
    cg_iterations: int = 10
    cg_damping: float = 0.1
    line_search_steps: int = 10
    line_search_decay: float = 0.5
    # Accept a step only if the surrogate improves by at least this fraction of the linear
    # prediction (and by more than zero).
    accept_ratio: float = 0.1


class IntentionInput(enum.StrEnum):
    """How the intention enters the policy, the value and EM-GAIL's discriminator."""

    ONEHOT = "onehot"  # an input of one network (the paper's Table 2)
    HEADS = "heads"  # one network per intention (the paper's public code)

    @property
    def heads(self) -> bool:
        return self is IntentionInput.HEADS


class ResponsibilityMode(enum.StrEnum):
    """The E-step's responsibilities gamma of the expert pairs."""

    TRAJECTORY = "trajectory"  # the posterior of the pair's whole demonstration
    TRAJECTORY_CENTERED = "trajectory-centered"  # the same, log-evidence centred
    PAIR = "pair"  # P(i | s, a) of the pair alone (eq. 18)
    LABELS = "labels"  # the hidden labels: an oracle, for diagnosis only

    @property
    def per_demonstration(self) -> bool:
        """Whether a demonstration's pairs share one gamma (and trajectory labels exist)."""
        return self in (ResponsibilityMode.TRAJECTORY, ResponsibilityMode.TRAJECTORY_CENTERED)

    @property
    def centered(self) -> bool:
        return self is ResponsibilityMode.TRAJECTORY_CENTERED

    @property
    def oracle(self) -> bool:
        """Whether gamma is the hidden labels (demonstrations must carry them)."""
        return self is ResponsibilityMode.LABELS


class Prior(enum.StrEnum):
    """The E-step's prior over the intentions."""

    UNIFORM = "uniform"  # 1/K, the paper's
    MIXTURE = "mixture"  # weights re-estimated every E-step, for unequal shares

    @property
    def estimated(self) -> bool:
        """Whether the E-step weighs gamma by mixture weights it re-estimates."""
        return self is Prior.MIXTURE


class RewardFrom(enum.StrEnum):
    """Which discriminator (and Info/IntentionGAIL's posterior) scores the B-step's reward."""

    UPDATED = "updated"  # after this iteration's E- and M-step (Algorithm 1)
    PREVIOUS = "previous"  # before them (the paper's public code)

    def choose(self, *, updated, previous):
        """``updated`` or ``previous``, the networks this option scores the reward with."""
        return updated if self is RewardFrom.UPDATED else previous


class RewardRecipe(enum.StrEnum):
    """``run --rewards``: how the rewards are trained, as one choice over several settings.
    ``paper``: the paper's (the defaults). ``for-reuse``: rewards meant to be taken away and
    re-optimised by a fresh agent (docs/rewards-that-reoptimise.md, experiments 21 and 22)."""

    PAPER = "paper"
    FOR_REUSE = "for-reuse"

    def settings(self, terminates: bool) -> dict:
        """The flat settings of the recipe for an env whose episodes may end early
        (``terminates``) or not; each is still one ``--set`` away."""
        if self is RewardRecipe.PAPER:
            return {}
        return {
            # Below 0 wherever D < 1, so no place off the demonstrations is paid for.
            "reward_form": RewardForm.LOG_D,
            # Every place the run's policies went, not only the latest policy's, is learned fake.
            "discriminator_replay": 400,
            # And a normaliser's standard deviation around those places.
            "discriminator_support_noise": 1.0,
            # A reward smooth enough for a search from scratch to climb (experiment 22).
            "discriminator_gradient_penalty": 0.1,
            # Log D pays for falling early unless a fall leads somewhere the reward prices.
            "absorbing_state": terminates,
        }


def _values(options: type[enum.Enum]) -> tuple[str, ...]:
    return tuple(option.value for option in options)


NAMES = _values(AlgorithmName)
REWARD_FORMS = _values(RewardForm)
DISCRIMINATOR_FORMS = _values(DiscriminatorForm)
INTENTION_INPUTS = _values(IntentionInput)
RESPONSIBILITIES = _values(ResponsibilityMode)
REWARD_FROM = _values(RewardFrom)
PRIORS = _values(Prior)
REWARD_RECIPES = _values(RewardRecipe)


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


def _one_of(options: type[enum.Enum]) -> Domain:
    names = _values(options)
    return Domain(lambda v: isinstance(v, str) and v in names, f"one of {', '.join(names)}")


def _or_default(domain: Domain) -> Domain:
    return Domain(lambda v: v is None or domain.holds(v), f"{domain.text} (or None, the default)")


def _integers(minimum: int) -> Domain:
    text = "at least 1" if minimum == 1 else f"an integer >= {minimum}"
    return Domain(
        lambda v: isinstance(v, numbers.Integral) and not isinstance(v, bool) and v >= minimum,
        text,
    )


COUNT = _integers(1)
POSITIVE = _numbers(lambda v: v > 0, "a positive number")
NON_NEGATIVE = _numbers(lambda v: v >= 0, "a number >= 0")
FRACTION = _numbers(lambda v: 0 < v <= 1, "in (0, 1]")
FINITE = _numbers(lambda v: True, "a finite number")
WIDTHS = Domain(lambda v: all(COUNT.holds(w) for w in v), "a tuple of layer widths >= 1")
BOOLEAN = Domain(lambda v: isinstance(v, bool), "True or False")


@dataclass(frozen=True)
class Setting:
    """Where a flat key lives in the layers (attribute names from :class:`RunConfig` down),
    and its domain."""

    path: tuple[str, ...]
    domain: Domain | None = None  # None: a config of its own (trpo), checked field by field


def _at(*path: str, domain: Domain | None = None) -> Setting:
    return Setting(path, domain)


# Every hyper-parameter by its flat key (--set, summary.json), in summary.json's order: where it
# lives and its domain. trpo.FIELD keys reach into TRPOConfig.
SETTINGS: dict[str, Setting] = {
    "algo": _at("method", "algo", domain=_one_of(AlgorithmName)),
    "iterations": _at("schedule", "iterations", domain=COUNT),
    "num_envs": _at("method", "rollout", "num_envs", domain=_or_default(COUNT)),
    "rollout_length": _at("method", "rollout", "rollout_length", domain=_or_default(COUNT)),
    "eval_every": _at("schedule", "eval_every", domain=COUNT),
    "hidden": _at("method", "networks", "hidden", domain=WIDTHS),
    "intention_input": _at("method", "networks", "intention_input", domain=_one_of(IntentionInput)),
    "responsibilities": _at(
        "method", "e_step", "responsibilities", domain=_one_of(ResponsibilityMode)
    ),
    "trajectory_temper_iterations": _at(
        "method", "e_step", "trajectory_temper_iterations", domain=_integers(0)
    ),
    "prior": _at("method", "e_step", "prior", domain=_one_of(Prior)),
    "reseed": _at("method", "e_step", "reseed", domain=BOOLEAN),
    "reseed_patience": _at("method", "e_step", "reseed_patience", domain=COUNT),
    "reseed_window": _at("method", "e_step", "reseed_window", domain=_or_default(COUNT)),
    "reseed_attempts": _at("method", "e_step", "reseed_attempts", domain=_integers(0)),
    "choose_intentions": _at("method", "choose_intentions", domain=BOOLEAN),
    "init_log_std": _at("method", "networks", "init_log_std", domain=FINITE),
    "obs_clip": _at("method", "networks", "obs_clip", domain=POSITIVE),
    "gamma": _at("method", "b_step", "gamma", domain=FRACTION),
    "gae_lambda": _at("method", "b_step", "gae_lambda", domain=FRACTION),
    "trpo": _at("method", "b_step", "trpo"),
    "value_learning_rate": _at("method", "b_step", "value_learning_rate", domain=POSITIVE),
    "value_epochs": _at("method", "b_step", "value_epochs", domain=COUNT),
    "value_minibatches": _at("method", "b_step", "value_minibatches", domain=COUNT),
    "value_target_scaling": _at("method", "b_step", "value_target_scaling", domain=BOOLEAN),
    "discriminator_learning_rate": _at("method", "m_step", "learning_rate", domain=POSITIVE),
    "discriminator_steps": _at("method", "m_step", "steps", domain=COUNT),
    "discriminator_gradient_penalty": _at(
        "method", "m_step", "gradient_penalty", domain=NON_NEGATIVE
    ),
    "discriminator_gradient_penalty_from": _at(
        "method", "m_step", "gradient_penalty_from", domain=_integers(0)
    ),
    "discriminator_replay": _at("method", "m_step", "replay", domain=_integers(0)),
    "discriminator_support_noise": _at("method", "m_step", "support_noise", domain=NON_NEGATIVE),
    "discriminator_support_in_box": _at("method", "m_step", "support_in_box", domain=BOOLEAN),
    "discriminator_form": _at("method", "m_step", "form", domain=_one_of(DiscriminatorForm)),
    "posterior_learning_rate": _at("method", "e_step", "learning_rate", domain=POSITIVE),
    "posterior_steps": _at("method", "e_step", "steps", domain=COUNT),
    "reward_from": _at("method", "reward", "source", domain=_one_of(RewardFrom)),
    "reward_form": _at("method", "reward", "form", domain=_one_of(RewardForm)),
    "absorbing_state": _at("method", "reward", "absorbing_state", domain=BOOLEAN),
    "info_weight": _at("info_weight", domain=NON_NEGATIVE),
    "chunk_size": _at("schedule", "chunk_size", domain=COUNT),
    "seed_batch": _at("schedule", "seed_batch", domain=_or_default(COUNT)),
    "checkpoint_every": _at("schedule", "checkpoint_every", domain=COUNT),
    "snapshot_every": _at("schedule", "snapshot_every", domain=_integers(0)),
}

TRPO_DOMAINS = {
    "max_kl": POSITIVE,
    "cg_iterations": COUNT,
    "cg_damping": NON_NEGATIVE,
    "line_search_steps": COUNT,
    "line_search_decay": _numbers(lambda v: 0 < v < 1, "in (0, 1)"),
    "accept_ratio": _numbers(lambda v: 0 <= v <= 1, "in [0, 1]"),
}

# Every domain by its --set key (trpo's fields as trpo.FIELD).
DOMAINS: dict[str, Domain] = {
    **{key: s.domain for key, s in SETTINGS.items() if s.domain is not None},
    **{f"trpo.{name}": domain for name, domain in TRPO_DOMAINS.items()},
}


class SettingError(ValueError):
    """A hyper-parameter outside its domain; ``key`` names it as ``--set`` does."""

    def __init__(self, key: str, value, domain: Domain):
        self.key, self.value, self.domain = key, value, domain
        super().__init__(self.naming(key))

    def naming(self, name: str) -> str:
        """The message with the setting called ``name`` (e.g. its command-line option)."""
        return f"{name} must be {self.domain.text}; got {self.value!r}"


def _settle(node, prefix: tuple[str, ...]) -> None:
    """Checks the fields of ``node`` (the config at ``prefix`` in the layers) against their
    domains and turns option names into their enum members."""
    for key, setting in SETTINGS.items():
        if setting.path[:-1] != prefix or setting.domain is None:
            continue
        name = setting.path[-1]
        value = getattr(node, name)
        if not setting.domain.holds(value):
            raise SettingError(key, value, setting.domain)
        options = type(next(f for f in dataclasses.fields(node) if f.name == name).default)
        if issubclass(options, enum.Enum):
            object.__setattr__(node, name, options(value))


class _Layer:
    """A frozen config of one layer: checked on construction, and ``replace``-able."""

    PREFIX: tuple[str, ...] = ()

    def __post_init__(self):
        _settle(self, self.PREFIX)

    def replace(self, **changes):
        return dataclasses.replace(self, **changes)


@dataclass(frozen=True)
class RolloutConfig(_Layer):
    """Samples per iteration: ``num_envs`` envs per intention, ``rollout_length`` steps each
    (None: the env's, :func:`rollout_defaults`); the evaluation runs one episode per env."""

    PREFIX = ("method", "rollout")
    num_envs: int | None = None
    rollout_length: int | None = None


@dataclass(frozen=True)
class NetworkConfig(_Layer):
    """The four networks' shape: hidden widths, how the intention enters, the policy's
    initial log-std, and the clip of the normalised observations."""

    PREFIX = ("method", "networks")
    hidden: tuple[int, ...] = (64, 64)
    intention_input: IntentionInput = IntentionInput.HEADS
    init_log_std: float = 0.0
    obs_clip: float = 5.0


# E-steps a re-seeded intention is held to the demonstrations it took, by algorithm
# (docs/no-empty-intention.md). EM-GAIL's re-seeded policy needs the time to reach its
# demonstrations before its posterior judges the split again; Info/IntentionGAIL's shared
# discriminator lets a longer hold drift back onto the other path, and ended worse. GAIL has
# no posterior and never re-seeds.
RESEED_WINDOWS = {AlgorithmName.EMGAIL: 30, AlgorithmName.INFOGAIL: 10, AlgorithmName.GAIL: 10}


@dataclass(frozen=True)
class EStepConfig(_Layer):
    """The E-step (:mod:`emgail_jax.method.posterior`): the responsibilities, the prior, the
    posterior's full-batch Adam steps, and re-seeding of emptied intentions
    (:mod:`emgail_jax.method.reseeding`). ``trajectory_temper_iterations`` N > 0 tempers a
    trajectory E-step's evidence, from one pair's worth at iteration 0 to all of it at
    iteration N (``posterior.evidence_temper``; 0: untempered, the default)."""

    PREFIX = ("method", "e_step")
    responsibilities: ResponsibilityMode = ResponsibilityMode.TRAJECTORY
    trajectory_temper_iterations: int = 0
    prior: Prior = Prior.UNIFORM
    learning_rate: float = 1e-3
    steps: int = 20
    reseed: bool = True
    reseed_patience: int = 10
    reseed_window: int | None = None  # None: the algorithm's, RESEED_WINDOWS
    reseed_attempts: int = 3

    def __post_init__(self):
        super().__post_init__()
        if self.trajectory_temper_iterations and not self.responsibilities.per_demonstration:
            raise ValueError(
                "trajectory_temper_iterations tempers a trajectory E-step; responsibilities "
                f"{self.responsibilities.value} has none (use trajectory or trajectory-centered)"
            )


@dataclass(frozen=True)
class MStepConfig(_Layer):
    """The M-step (:mod:`emgail_jax.method.discriminator`): full-batch Adam steps, the
    weight of a zero-centred gradient penalty on the logit (0: none) and the iteration it
    starts at (0: the first; later lets the intentions separate before it), the iterations of
    past policy samples replayed as further negatives (:mod:`emgail_jax.method.replay`; 0:
    none), the standard deviation of the noise that moves a copy of every negative off the
    run's samples (:mod:`emgail_jax.method.support`; 0: none), whether those copies are
    clipped into the inputs' box as real inputs are, and the discriminator's form (GAIL's, or
    AIRL's: :mod:`emgail_jax.method.airl`)."""

    PREFIX = ("method", "m_step")
    learning_rate: float = 1e-3
    steps: int = 10
    gradient_penalty: float = 0.0
    gradient_penalty_from: int = 0
    replay: int = 0
    support_noise: float = 0.0
    support_in_box: bool = False
    form: DiscriminatorForm = DiscriminatorForm.GAIL


@dataclass(frozen=True)
class BStepConfig(_Layer):
    """The B-step (:mod:`emgail_jax.method.b_step`): GAE, TRPO and the value baseline's fit
    (``value_epochs`` epochs of ``value_minibatches`` Adam steps)."""

    PREFIX = ("method", "b_step")
    gamma: float = 0.995
    gae_lambda: float = 0.97
    trpo: TRPOConfig = field(default_factory=TRPOConfig)
    value_learning_rate: float = 1e-3
    value_epochs: int = 20
    value_minibatches: int = 4
    # V fitted to its targets standardised by their running mean and variance (off: the raw
    # returns, as the paper's code has it).
    value_target_scaling: bool = False

    def __post_init__(self):
        super().__post_init__()
        for name, domain in TRPO_DOMAINS.items():
            value = getattr(self.trpo, name)
            if not domain.holds(value):
                raise SettingError(f"trpo.{name}", value, domain)


@dataclass(frozen=True)
class RewardConfig(_Layer):
    """The B-step's reward: its form, which networks score it, and whether a termination
    leads to an absorbing state whose reward the discriminator learns (DAC, Kostrikov et al.
    2019; off: an episode's end is worth 0, as the paper has it)."""

    PREFIX = ("method", "reward")
    form: RewardForm = RewardForm.GAIL
    source: RewardFrom = RewardFrom.UPDATED
    absorbing_state: bool = False


@dataclass(frozen=True)
class MethodConfig(_Layer):
    """Exactly what ``training.make_train`` compiles: two runs with equal method configs (and
    envs) share one program. ``choose_intentions``: K is chosen from the data
    (``--intentions auto``, :mod:`emgail_jax.method.choosing`)."""

    PREFIX = ("method",)
    algo: AlgorithmName = AlgorithmName.EMGAIL
    e_step: EStepConfig = field(default_factory=EStepConfig)
    m_step: MStepConfig = field(default_factory=MStepConfig)
    b_step: BStepConfig = field(default_factory=BStepConfig)
    networks: NetworkConfig = field(default_factory=NetworkConfig)
    reward: RewardConfig = field(default_factory=RewardConfig)
    rollout: RolloutConfig = field(default_factory=RolloutConfig)
    choose_intentions: bool = False

    def __post_init__(self):
        super().__post_init__()
        if self.choose_intentions and not (
            self.e_step.prior.estimated and self.algo.learns_posterior
        ):
            raise ValueError(
                "choosing the number of intentions needs a posterior and the mixture prior: "
                "an algo other than gail, and prior mixture"
            )
        if self.m_step.support_in_box and not self.m_step.support_noise:
            raise ValueError(
                "discriminator_support_in_box clips the noisy copies of the negatives: "
                "give discriminator_support_noise=S too"
            )
        if self.m_step.gradient_penalty_from and not self.m_step.gradient_penalty:
            raise ValueError(
                "discriminator_gradient_penalty_from delays the gradient penalty: "
                "give discriminator_gradient_penalty=W too"
            )
        if self.m_step.form.airl:
            _check_airl(self)

    def resolved(self, env) -> MethodConfig:
        """Fills the env-dependent rollout sizes from ``env`` and the algorithm's re-seeding
        window."""
        defaults = rollout_defaults(env.name, env.episode_length)
        rollout = RolloutConfig(
            num_envs=self.rollout.num_envs or defaults["num_envs"],
            rollout_length=self.rollout.rollout_length or defaults["rollout_length"],
        )
        window = self.e_step.reseed_window or RESEED_WINDOWS[self.algo]
        return self.replace(rollout=rollout, e_step=self.e_step.replace(reseed_window=window))

    @property
    def reward_form(self) -> RewardForm:
        """The form of the B-step's reward of the discriminator logit: AIRL's discriminator
        rewards its logit f - log pi (log D - log(1 - D)), GAIL's as ``reward.form`` says."""
        return RewardForm.LOGIT if self.m_step.form.airl else self.reward.form

    @property
    def reseeds(self) -> bool:
        """Whether emptied intentions are re-seeded: with a posterior, unless turned off."""
        return self.e_step.reseed and self.algo.learns_posterior


def _check_airl(config: MethodConfig) -> None:
    """Refuses what AIRL's discriminator does not combine with (one line each)."""
    if config.algo is AlgorithmName.INFOGAIL:
        # Its D(s, a) has no condition, its policy one per intention: no one pi to divide by.
        raise ValueError("discriminator_form airl takes algo emgail or gail, not infogail")
    if config.reward.absorbing_state:
        raise ValueError(
            "discriminator_form airl ends an episode with h(s') = 0 at a termination; "
            "it does not take absorbing_state=true"
        )
    if config.reward.form is not RewardForm.GAIL:
        raise ValueError(
            "discriminator_form airl rewards its own logit f - log pi; reward_form applies to "
            "discriminator_form gail only"
        )
    if config.m_step.support_noise:
        raise ValueError(
            "discriminator_support_noise moves GAIL's (s, a) pairs, not AIRL's successors; "
            "it takes discriminator_form gail"
        )


@dataclass(frozen=True)
class RunSchedule(_Layer):
    """What only the host reads: the iterations in all, the evaluation cadence (every
    ``eval_every`` and each of the last 10), iterations per compiled call, seeds vmapped
    together on a device (None: 1 on CPU, all on accelerators; it changes the floating point,
    so a resumed run keeps it), and iterations between checkpoints and snapshots (0: none)."""

    PREFIX = ("schedule",)
    iterations: int = 400
    eval_every: int = 10
    chunk_size: int = 10
    seed_batch: int | None = None
    checkpoint_every: int = 50
    snapshot_every: int = 50


@dataclass(frozen=True)
class RunConfig(_Layer):
    """Everything that shapes one run: the method, the host's schedule, and Info/IntentionGAIL's
    lambda, which the compiled program takes as data (``training.RunData``)."""

    method: MethodConfig = field(default_factory=MethodConfig)
    schedule: RunSchedule = field(default_factory=RunSchedule)
    info_weight: float = 1.0

    def resolved(self, env) -> RunConfig:
        return self.replace(method=self.method.resolved(env))

    def program_key(self) -> MethodConfig:
        """What identifies the compiled update (with the env): the method config."""
        return self.method

    def with_settings(self, settings: Sequence[str]) -> RunConfig:
        """A copy with ``KEY=VALUE`` settings applied, e.g. ``["discriminator_steps=5",
        "trpo.cg_damping=0"]`` (``run --set``): any hyper-parameter by its flat key or its
        path in the layers (``method.m_step.steps=5``), typed like its default."""
        config = self
        for setting in settings:
            key, sep, text = setting.partition("=")
            key = key.strip()
            if not sep or not key:
                raise ValueError(f"a setting is KEY=VALUE, e.g. trpo.max_kl=0.02; got '{setting}'")
            config = _with_setting(config, _path_of(key), text.strip(), key)
        return config

    def with_values(self, **values) -> RunConfig:
        """A copy with settings given by their flat keys as values (``algo="gail",
        discriminator_steps=5``)."""
        config = self
        for key, value in values.items():
            if key not in SETTINGS:
                raise ValueError(f"unknown setting '{key}'; choose one of {', '.join(SETTINGS)}")
            config = _replaced(config, SETTINGS[key].path, value)
        return config

    def value(self, key: str):
        """The setting at flat key ``key`` (``"discriminator_steps"``)."""
        return _walk(self, SETTINGS[key].path)

    def to_dict(self) -> dict:
        """The flat dict of every setting by its key, as ``summary.json`` stores it."""
        flat = {}
        for key, setting in SETTINGS.items():
            value = _walk(self, setting.path)
            if dataclasses.is_dataclass(value):
                value = dataclasses.asdict(value)
            elif isinstance(value, enum.Enum):
                value = value.value
            flat[key] = value
        return flat

    @classmethod
    def from_dict(cls, values: dict) -> RunConfig:
        """Inverse of :meth:`to_dict` (e.g. the ``config`` of a ``summary.json``, also one
        written before some settings existed)."""
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
        unknown = sorted(set(values) - set(SETTINGS))
        if unknown:
            raise TypeError(f"unknown settings {', '.join(unknown)}")
        layers = {}
        for key, value in values.items():
            node = layers
            *parents, name = SETTINGS[key].path
            for parent in parents:
                node = node.setdefault(parent, {})
            node[name] = value
        return _build(cls, layers)


def _build(cls, layers: dict):
    """``cls`` from the nested dict ``layers`` of its fields (absent ones: defaults)."""
    kinds = {f.name: f for f in dataclasses.fields(cls)}
    built = {}
    for name, value in layers.items():
        layer = kinds[name].default_factory
        if isinstance(value, dict) and isinstance(layer, type) and issubclass(layer, _Layer):
            value = _build(layer, value)
        built[name] = value
    return cls(**built)


def _path_of(key: str) -> list[str]:
    """The layered path of ``--set`` key ``key``: a flat key (``discriminator_steps``,
    ``trpo.max_kl``) or a path itself (``method.m_step.steps``)."""
    head, *rest = key.split(".")
    if head in SETTINGS:
        return [*SETTINGS[head].path, *rest]
    if head in ("method", "schedule"):
        return key.split(".")
    raise ValueError(
        f"unknown setting '{key}'; choose one of {', '.join(SETTINGS)} "
        "(or a path such as method.m_step.steps)"
    )


def _walk(node, path: Sequence[str]):
    for name in path:
        node = getattr(node, name)
    return node


def _replaced(node, path: Sequence[str], value):
    """``node`` (a frozen dataclass) with the field at ``path`` set to ``value``."""
    name, *rest = path
    if rest:
        value = _replaced(getattr(node, name), rest, value)
    return dataclasses.replace(node, **{name: value})


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
    if isinstance(current, str):  # an option's name; its domain checks it
        return text
    if dataclasses.is_dataclass(current):
        raise ValueError(f"'{key}' has fields: set one of them, e.g. {key}.<field>=...")
    if isinstance(current, bool) and text.lower() in ("true", "false"):
        return text.lower() == "true"  # the shell's spelling as well as Python's
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
