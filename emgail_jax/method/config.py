"""Hyper-parameters of a run, by layer: what the compiled method takes (:class:`MethodConfig`,
one sub-config per step), what only the host reads (:class:`RunSchedule`), and the run's data
(Info/IntentionGAIL's lambda), with the paper's defaults (§5.3) and per-env rollout sizes.

Options are typed here, once (``enum`` members whose values are the command line's and
``summary.json``'s spellings, with the behaviour the method needs as properties), and every
field is checked against its domain whenever a layer is built. The user's namespace is flat
(``--set discriminator_steps=5``, ``summary.json``'s ``config``):
:mod:`emgail_jax.method.settings` maps each flat key to its place in the layers. Why the
defaults are what they are, with the measurements: docs/defaults.md.
"""

from __future__ import annotations

import dataclasses
import enum
import math
import numbers
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from emgail_jax.method import settings


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
    (:mod:`emgail_jax.method.discriminator`; AIRL's: :mod:`emgail_jax.variants.airl`)."""

    GAIL = "gail"  # D = sigmoid(f(s, a, i)), the paper's
    AIRL = "airl"  # D = exp f / (exp f + pi_i(a | s)), f = g_i(s) + gamma h_i(s') - h_i(s)

    @property
    def airl(self) -> bool:
        return self is DiscriminatorForm.AIRL


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
    re-optimised by a fresh agent (why these settings: docs/defaults.md, ``run --rewards``)."""

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
            # A reward smooth enough for a search from scratch to climb (docs/defaults.md,
            # ``discriminator_gradient_penalty``).
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


def _setting(domain: Domain, default=dataclasses.MISSING, **kwargs):
    """A field of a layer whose values are checked against ``domain`` on construction."""
    return field(default=default, metadata={"domain": domain}, **kwargs)


def _option(default: enum.Enum):
    """A field of a layer that takes one of the options of ``default``'s enum."""
    return field(default=default, metadata={"domain": _one_of(type(default))})


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
    for f in dataclasses.fields(node):
        domain = f.metadata.get("domain")
        if domain is None:  # a layer of its own, checked on its construction
            continue
        value = getattr(node, f.name)
        if not domain.holds(value):
            raise SettingError(settings.key_of((*prefix, f.name)), value, domain)
        if isinstance(f.default, enum.Enum):
            object.__setattr__(node, f.name, type(f.default)(value))


class _Layer:
    """A frozen config of one layer: checked on construction, and ``replace``-able."""

    PREFIX: tuple[str, ...] = ()

    def __post_init__(self):
        _settle(self, self.PREFIX)

    def replace(self, **changes):
        return dataclasses.replace(self, **changes)


@dataclass(frozen=True)
class TRPOConfig(_Layer):
    """The B-step's TRPO (:mod:`emgail_jax.method.trpo`)."""

    PREFIX = ("method", "b_step", "trpo")
    max_kl: float = _setting(POSITIVE, 0.01)
    cg_iterations: int = _setting(COUNT, 10)
    cg_damping: float = _setting(NON_NEGATIVE, 0.1)
    line_search_steps: int = _setting(COUNT, 10)
    line_search_decay: float = _setting(_numbers(lambda v: 0 < v < 1, "in (0, 1)"), 0.5)
    # Accept a step only if the surrogate improves by at least this fraction of the linear
    # prediction (and by more than zero).
    accept_ratio: float = _setting(_numbers(lambda v: 0 <= v <= 1, "in [0, 1]"), 0.1)


@dataclass(frozen=True)
class RolloutConfig(_Layer):
    """Samples per iteration: ``num_envs`` envs per intention, ``rollout_length`` steps each
    (None: the env's, :func:`rollout_defaults`); the evaluation runs one episode per env."""

    PREFIX = ("method", "rollout")
    num_envs: int | None = _setting(_or_default(COUNT), None)
    rollout_length: int | None = _setting(_or_default(COUNT), None)


@dataclass(frozen=True)
class NetworkConfig(_Layer):
    """The four networks' shape: hidden widths, how the intention enters, the policy's
    initial log-std, and the clip of the normalised observations."""

    PREFIX = ("method", "networks")
    hidden: tuple[int, ...] = _setting(WIDTHS, (64, 64))
    intention_input: IntentionInput = _option(IntentionInput.HEADS)
    init_log_std: float = _setting(FINITE, 0.0)
    obs_clip: float = _setting(POSITIVE, 5.0)


# E-steps a re-seeded intention is held to the demonstrations it took, by algorithm
# (docs/defaults.md, ``reseed_window``). EM-GAIL's re-seeded policy needs the time to reach its
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
    iteration N (``variants.tempering.evidence_temper``; 0: untempered, the default)."""

    PREFIX = ("method", "e_step")
    responsibilities: ResponsibilityMode = _option(ResponsibilityMode.TRAJECTORY)
    trajectory_temper_iterations: int = _setting(_integers(0), 0)
    prior: Prior = _option(Prior.UNIFORM)
    learning_rate: float = _setting(POSITIVE, 1e-3)
    steps: int = _setting(COUNT, 20)
    reseed: bool = _setting(BOOLEAN, True)
    reseed_patience: int = _setting(COUNT, 10)
    # None: the algorithm's, RESEED_WINDOWS.
    reseed_window: int | None = _setting(_or_default(COUNT), None)
    reseed_attempts: int = _setting(_integers(0), 3)

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
    weight of a zero-centred gradient penalty on the logit (0: none), the iterations of past
    policy samples replayed as further negatives (:mod:`emgail_jax.variants.replay`; 0: none),
    the standard deviation of the noise that moves a copy of every negative off the run's
    samples (:mod:`emgail_jax.variants.support`; 0: none), and the discriminator's form (GAIL's,
    or AIRL's: :mod:`emgail_jax.variants.airl`)."""

    PREFIX = ("method", "m_step")
    learning_rate: float = _setting(POSITIVE, 1e-3)
    steps: int = _setting(COUNT, 10)
    gradient_penalty: float = _setting(NON_NEGATIVE, 0.0)
    replay: int = _setting(_integers(0), 0)
    support_noise: float = _setting(NON_NEGATIVE, 0.0)
    form: DiscriminatorForm = _option(DiscriminatorForm.GAIL)


@dataclass(frozen=True)
class BStepConfig(_Layer):
    """The B-step (:mod:`emgail_jax.method.b_step`): GAE, TRPO and the value baseline's fit
    (``value_epochs`` epochs of ``value_minibatches`` Adam steps)."""

    PREFIX = ("method", "b_step")
    gamma: float = _setting(FRACTION, 0.995)
    gae_lambda: float = _setting(FRACTION, 0.97)
    trpo: TRPOConfig = field(default_factory=TRPOConfig)
    value_learning_rate: float = _setting(POSITIVE, 1e-3)
    value_epochs: int = _setting(COUNT, 20)
    value_minibatches: int = _setting(COUNT, 4)
    # V fitted to its targets standardised by their running mean and variance (off: the raw
    # returns, as the paper's code has it).
    value_target_scaling: bool = _setting(BOOLEAN, False)


@dataclass(frozen=True)
class RewardConfig(_Layer):
    """The B-step's reward: its form, which networks score it, and whether a termination
    leads to an absorbing state whose reward the discriminator learns (DAC, Kostrikov et al.
    2019; off: an episode's end is worth 0, as the paper has it)."""

    PREFIX = ("method", "reward")
    form: RewardForm = _option(RewardForm.GAIL)
    source: RewardFrom = _option(RewardFrom.UPDATED)
    absorbing_state: bool = _setting(BOOLEAN, False)


@dataclass(frozen=True)
class MethodConfig(_Layer):
    """Exactly what ``training.make_train`` compiles: two runs with equal method configs (and
    envs) share one program. ``choose_intentions``: K is chosen from the data
    (``--intentions auto``, :mod:`emgail_jax.method.choosing`)."""

    PREFIX = ("method",)
    algo: AlgorithmName = _option(AlgorithmName.EMGAIL)
    e_step: EStepConfig = field(default_factory=EStepConfig)
    m_step: MStepConfig = field(default_factory=MStepConfig)
    b_step: BStepConfig = field(default_factory=BStepConfig)
    networks: NetworkConfig = field(default_factory=NetworkConfig)
    reward: RewardConfig = field(default_factory=RewardConfig)
    rollout: RolloutConfig = field(default_factory=RolloutConfig)
    choose_intentions: bool = _setting(BOOLEAN, False)

    def __post_init__(self):
        super().__post_init__()
        if self.choose_intentions and not (
            self.e_step.prior.estimated and self.algo.learns_posterior
        ):
            raise ValueError(
                "choosing the number of intentions needs a posterior and the mixture prior: "
                "an algo other than gail, and prior mixture"
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
    iterations: int = _setting(COUNT, 400)
    eval_every: int = _setting(COUNT, 10)
    chunk_size: int = _setting(COUNT, 10)
    seed_batch: int | None = _setting(_or_default(COUNT), None)
    checkpoint_every: int = _setting(COUNT, 50)
    snapshot_every: int = _setting(_integers(0), 10)


@dataclass(frozen=True)
class RunConfig(_Layer):
    """Everything that shapes one run: the method, the host's schedule, and Info/IntentionGAIL's
    lambda, which the compiled program takes as data (``training.RunData``)."""

    method: MethodConfig = field(default_factory=MethodConfig)
    schedule: RunSchedule = field(default_factory=RunSchedule)
    info_weight: float = _setting(NON_NEGATIVE, 1.0)

    def resolved(self, env) -> RunConfig:
        return self.replace(method=self.method.resolved(env))

    def program_key(self) -> MethodConfig:
        """What identifies the compiled update (with the env): the method config."""
        return self.method

    def with_values(self, **values) -> RunConfig:
        """A copy with settings given as values by their flat keys (``algo="gail",
        discriminator_steps=5``, ``**{"trpo.max_kl": 0.02}``) or layered paths, applied at
        once: each layer is checked with all its new values. Every builder comes down to this
        one."""
        return _changed(self, settings.layered(values))

    def with_settings(self, texts: Sequence[str]) -> RunConfig:
        """A copy with ``KEY=VALUE`` settings applied (``run --set``), e.g.
        ``["discriminator_steps=5", "trpo.cg_damping=0", "method.m_step.steps=5"]``, each value
        typed like the one it replaces."""
        return self.with_values(**settings.parsed(texts, like=self))

    @classmethod
    def from_dict(cls, values: dict) -> RunConfig:
        """Inverse of :meth:`to_dict`: the ``config`` of a ``summary.json``, also one written
        before some settings existed or after some were deleted."""
        return cls().with_values(**settings.saved(values))

    def value(self, key: str):
        """The setting at flat key ``key`` (``"discriminator_steps"``)."""
        node = self
        for name in settings.path_of(key):
            node = getattr(node, name)
        return node

    def to_dict(self) -> dict:
        """The flat dict of every setting by its key, as ``summary.json`` stores it."""
        flat = {}
        for key in settings.SETTINGS:
            value = self.value(key)
            if dataclasses.is_dataclass(value):
                value = dataclasses.asdict(value)
            elif isinstance(value, enum.Enum):
                value = value.value
            flat[key] = value
        return flat


def _changed(node, changes: dict):
    """``node`` (a layer) with ``changes``, a nested dict of new values by field (a dict for
    a layer's own changes), each layer built once."""
    fields = {}
    for name, value in changes.items():
        if isinstance(value, dict):
            value = _changed(getattr(node, name), value)
        fields[name] = value
    return dataclasses.replace(node, **fields)


def rollout_defaults(env_name: str, episode_length: int) -> dict:
    """Samples per intention per iteration: the paper's 5 trajectories of one episode each for
    the driver and the 500-step robotics tasks; the 50-step reacher runs 50 episodes in parallel
    so that it too collects 2500 pairs per intention."""
    num_envs = 50 if env_name == "reacher" else 5
    return {"num_envs": num_envs, "rollout_length": episode_length}
