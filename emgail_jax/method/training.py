"""One training iteration of EM-GAIL, Info/IntentionGAIL or GAIL as a pure function.

``make_train(config, env)`` returns ``init(key, data) -> TrainState`` and
``update(state, evaluating, data) -> (state, metrics)``. ``data`` (a :class:`RunData`: the
demonstrations, ERD's references, the env's data such as the driver's path curvatures, and
Info/IntentionGAIL's lambda) is an argument of the compiled program rather than constants in it,
so runs that differ only in their data share one program (and the persistent compilation cache).

One update is Algorithm 1 of the paper, for all K intentions at once: the trainer skeleton of
:mod:`emgail_jax.method.skeleton` (the rollout, the normalisation, the B-step), whose reward
stage is steps 2-3 and the learned reward (:class:`LearnedRewardStage`, which reads as them):

1. rollout: B envs per intention, T steps, with the current policy;
2. E-step (:mod:`emgail_jax.method.posterior`): the posterior learns P(i | s, a) on those samples;
   gamma = P on the expert pairs;
3. M-step (:mod:`emgail_jax.method.discriminator`): the discriminator learns expert (weighted by
   gamma) against policy samples;
4. B-step (:mod:`emgail_jax.method.b_step`): the samples are relabelled with the learned reward, GAE
   computes advantages, TRPO updates the policy, and the value baseline is refitted;
5. metrics: the clustering accuracy of the E-step and, when ``evaluating``, deterministic
   episodes (one per env of the rollout, from fresh starts) of the policy that made this
   iteration's rollout, scored with the true rewards: returns and the ERD with the best
   intention matching. Iteration n thus scores the policy after n - 1 updates.

The rollout and the evaluation episodes are phases of one loop whose body steps the env once:
the env step, the largest part of an MJX program, is compiled once rather than once for
training and once more for evaluation.

Research variants change the update at the named places of :mod:`emgail_jax.method.hooks`;
``make_train(config, env, hooks)`` takes them (default: the paper's method), and
:mod:`emgail_jax.variants` builds those a config asks for.

The caller ``jit``s ``vmap(update)`` over seeds (see :mod:`emgail_jax.host.seed_runner`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import struct

import envs
from emgail_jax.method import normalizer as obs_norm
from emgail_jax.method.algorithms import Algorithm, make_algorithm
from emgail_jax.method.batches import DemonstrationPairs, NormalizedBatch
from emgail_jax.method.choosing import holds_demonstrations
from emgail_jax.method.config import MethodConfig, ResponsibilityMode
from emgail_jax.method.discriminator import MStep, expert_scores, learned_reward, make_m_step
from emgail_jax.method.hooks import PAPER, Hooks, Sampling
from emgail_jax.method.metrics import cluster_accuracy, normalized_erd
from emgail_jax.method.networks import GaussianPolicy, Posterior, ValueNet
from emgail_jax.method.optim import Learner
from emgail_jax.method.posterior import (
    EStep,
    Lesson,
    Responsibilities,
    expert_responsibilities,
    make_e_step,
    mixture_weights,
)
from emgail_jax.method.reseeding import (
    Reseeding,
    ReseedingRule,
    count_down,
    demonstration_responsibilities,
    demonstration_scores,
    held_responsibilities,
    reseeding_step,
)
from emgail_jax.method.rollout import (
    Transitions,
    batch_reset,
    episode_totals,
    fresh_starts,
    intention_major,
    time_major,
    tree_where,
)
from emgail_jax.method.skeleton import PolicyStages, Rewarded, intention_rows, make_update


@struct.dataclass
class TrainState:
    """Everything one seed's training carries from one iteration to the next."""

    policy: Any  # the policy's parameters (TRPO keeps no optimiser state)
    value: Learner
    discriminator: Learner
    posterior: Learner | None  # None for GAIL
    normalizer: obs_norm.RunningStats
    intention_weights: jax.Array  # [K] the E-step's mixture prior (1/K under the uniform prior)
    env_state: envs.State  # [K, B] auto-resetting training envs
    key: jax.Array
    iteration: jax.Array
    # The re-seeding of emptied intentions; None without a posterior or with `--reseed off`
    # (a state of the layout runs had before the option).
    reseeding: Reseeding | None = None
    # The carry of a variant's further negatives for the M-step (:mod:`~.hooks`); None without.
    negatives: Any = None

    def network_parameters(self) -> dict[str, Any]:
        """The parameters of each of the four networks (None for GAIL's posterior)."""
        return {
            "policy": self.policy,
            "value": self.value.params,
            "discriminator": self.discriminator.params,
            "posterior": None if self.posterior is None else self.posterior.params,
        }


@struct.dataclass
class RunData:
    """What the compiled program takes as arguments: everything that is data, not shape.

    Host (numpy) arrays here; the runner places one copy on every device before the first call.
    """

    demos: DemonstrationPairs
    env: Any  # env.data(): e.g. the driver's path curvatures; None for the MJX envs
    info_weight: jax.Array  # [] Info/IntentionGAIL's lambda (eq. 23)

    @classmethod
    def create(cls, demos: DemonstrationPairs, env: envs.Env, info_weight: float) -> RunData:
        return cls(demos, env.data(), np.float32(info_weight))


@dataclass(frozen=True)
class Networks:
    policy: GaussianPolicy
    value: ValueNet
    discriminator: Any  # the hooks' form's network
    posterior: Posterior


def make_networks(config: MethodConfig, env: envs.Env, hooks: Hooks = PAPER) -> Networks:
    shape = config.networks
    heads = shape.intention_input.heads
    return Networks(
        policy=GaussianPolicy(env.action_size, shape.hidden, shape.init_log_std, heads),
        value=ValueNet(shape.hidden, heads),
        discriminator=hooks.form.network(config),
        posterior=Posterior(env.num_intentions, shape.hidden),
    )


def make_policy_stages(config: MethodConfig, env: envs.Env, networks: Networks) -> PolicyStages:
    """The skeleton's policy side for ``networks``: row k of the ``[K, B]`` layout acts as
    intention k (GAIL's single policy ignores the row)."""
    # Only the policy's conditioning is read, which no algorithm's data changes.
    algorithm = make_algorithm(config.algo, reward_form=config.reward_form)
    condition = lambda intentions: algorithm.policy_condition(intentions, env.num_intentions)
    return PolicyStages.create(networks.policy, networks.value, condition, config, env)


def training_env(env: envs.Env, data: RunData) -> envs.Env:
    """The auto-resetting training env of the run's ``data`` (e.g. the driver's paths)."""
    return envs.wrap_for_training(env.bind(data.env))


def clustering_metrics(
    e_step: Responsibilities | None,
    demos: DemonstrationPairs,
    k: int,
    mode: ResponsibilityMode,
    in_use: jax.Array | None = None,
) -> dict:
    """The clustering accuracy of eq. 29 (the posterior's argmax on every expert pair) and, when
    the E-step works on whole demonstrations, the accuracy of those trajectory labels too; NaN
    without a posterior (GAIL, which has no trajectory labels either) or without hidden labels.
    ``k`` learned intentions, of which ``in_use [K]`` (None: all) are kept: each pair and
    demonstration is then labelled with its most likely kept intention."""
    names = ["eval/cluster_accuracy"]
    if mode.per_demonstration and e_step is not None:
        names.append("eval/trajectory_cluster_accuracy")
    if e_step is None or not demos.has_labels:
        return {name: jnp.float32(jnp.nan) for name in names}
    if in_use is not None:
        e_step = e_step.kept_only(in_use)
    labels = (e_step.pair_labels, e_step.trajectory_labels)
    return {
        name: cluster_accuracy(predicted, demos.labels, k, demos.true_intentions, in_use)
        for name, predicted in zip(names, labels, strict=False)
    }


def responsibilities_of(
    networks: Networks,
    config: MethodConfig,
    state: TrainState,
    demos: DemonstrationPairs,
    hooks: Hooks = PAPER,
) -> Responsibilities:
    """The E-step's responsibilities of ``demos`` under one seed's ``state`` (its posterior,
    observation statistics and mixture weights), computed as training computes them (with
    ``hooks``' evidence weights)."""
    expert_obs = obs_norm.normalize(state.normalizer, demos.observations, config.networks.obs_clip)
    # A state after n updates holds the posterior the E-step of update n - 1 trained, which
    # weighed the evidence as that update did.
    evidence = hooks.evidence
    evidence_weight = None if evidence is None else evidence(state.iteration - 1, demos)
    return expert_responsibilities(
        networks.posterior.apply,
        state.posterior.params,
        expert_obs,
        demos.actions,
        episode=demos.episode,
        episodes=demos.episodes,
        mode=config.e_step.responsibilities,
        labels=demos.labels if demos.has_labels else None,
        weights=state.intention_weights if config.e_step.prior.estimated else None,
        evidence_weight=evidence_weight,
    )


def seed_state(states: TrainState, seed: int) -> TrainState:
    """One seed's state out of every seed's ``states`` (leading axis: seed)."""
    return jax.tree.map(lambda x: x[seed], states)


def evaluation_metrics(
    returns: jax.Array, demos: DemonstrationPairs, in_use: jax.Array | None = None
) -> dict:
    """ERD (eq. 28) of ``returns [K learned, K env]``, per true intention and matched (to the
    learned intentions ``in_use [K learned]``, None: all). When K is chosen from the data, also
    every learned intention's returns, flattened ``[K learned * K true]``: the run's K is
    decided at its end, and its final ERD matched again then (``train``)."""
    k = demos.true_intentions
    erd = normalized_erd(returns, demos.expert_returns, demos.random_returns, in_use)
    metrics = {
        "eval/erd": erd.mean,
        "eval/erd_per_intention": erd.per_intention,  # [K true]
        "eval/returns": returns[erd.matching, jnp.arange(k)],  # [K true]
        "eval/matching": erd.matching,
    }
    if in_use is not None:
        metrics["eval/learned_returns"] = returns[:, :k].reshape(-1)
    return metrics


def no_evaluation(k: int, learned: int | None = None) -> dict:
    """What :func:`evaluation_metrics` gives for an iteration without evaluation (``k`` true
    intentions; ``learned`` ones when K is chosen from the data): NaN (matching -1), never
    stale values."""
    missing = jnp.full(k, jnp.nan, jnp.float32)
    metrics = {
        "eval/erd": jnp.float32(jnp.nan),
        "eval/erd_per_intention": missing,
        "eval/returns": missing,
        "eval/matching": jnp.full(k, -1, jnp.int32),
    }
    if learned is not None:
        metrics["eval/learned_returns"] = jnp.full(learned * k, jnp.nan, jnp.float32)
    return metrics


def evaluation_phases(config: MethodConfig, env: envs.Env) -> int:
    """Rollouts of ``rollout_length`` steps that cover one evaluation episode."""
    return math.ceil(env.episode_length / config.rollout.rollout_length)


def algorithm_of(config: MethodConfig, data: RunData) -> Algorithm:
    """The run's algorithm, with Info/IntentionGAIL's lambda from the run's data."""
    return make_algorithm(config.algo, data.info_weight, config.reward_form)


class Optimizers(NamedTuple):
    discriminator: optax.GradientTransformation
    posterior: optax.GradientTransformation


def make_optimizers(config: MethodConfig) -> Optimizers:
    return Optimizers(
        discriminator=optax.adam(config.m_step.learning_rate),
        posterior=optax.adam(config.e_step.learning_rate),
    )


def make_init(
    config: MethodConfig, env: envs.Env, networks: Networks, optimizers: Optimizers, hooks: Hooks
):
    """``init(key, data) -> TrainState``: fresh networks and ``[K, B]`` reset training envs."""
    k, b = env.num_intentions, config.rollout.num_envs
    stages = make_policy_stages(config, env, networks)

    def init(key: jax.Array, data: RunData) -> TrainState:
        algorithm = algorithm_of(config, data)
        discriminator_condition = algorithm.discriminator_condition(intention_rows((1,)), k)
        keys = dict(
            zip(
                ("policy", "value", "disc", "post", "env", "next"),
                jax.random.split(key, 6),
                strict=True,
            )
        )
        obs = jnp.zeros((1, env.observation_size))
        action = jnp.zeros((1, env.action_size))
        policy, value = stages.init(keys["policy"], keys["value"])
        read = hooks.form.init_input(obs, action)
        discriminator = networks.discriminator.init(
            keys["disc"], obs, read, discriminator_condition
        )
        posterior = (
            Learner.create(networks.posterior.init(keys["post"], obs, action), optimizers.posterior)
            if algorithm.learns_posterior
            else None
        )
        return TrainState(
            policy=policy,
            value=value,
            discriminator=Learner.create(discriminator, optimizers.discriminator),
            posterior=posterior,
            normalizer=obs_norm.RunningStats.create(env.observation_size),
            intention_weights=jnp.full(k, 1.0 / k),
            env_state=batch_reset(training_env(env, data), keys["env"], (k, b)),
            key=keys["next"],
            iteration=jnp.zeros((), jnp.int32),
            reseeding=(Reseeding.create(k, data.demos.episodes) if config.reseeds else None),
            negatives=hooks.negatives.init(config, env, key),
        )

    return init


def lesson_of(memory: Reseeding, demos: DemonstrationPairs) -> Lesson:
    """The demonstrations a re-seeding split, as the posterior learns them."""
    return Lesson(
        active=memory.left > 0,
        intentions=memory.taught_intentions()[demos.episode],
        weights=memory.split[demos.episode].astype(jnp.float32),
    )


def make_collect(config: MethodConfig, env: envs.Env, stages: PolicyStages):
    """``collect(state, key, evaluating, data) -> (end_state, transitions, evaluation
    metrics)``: the skeleton's step 1 and, when ``evaluating`` (5.), the deterministic
    evaluation episodes, phases of one loop whose body steps the env once. ``evaluating`` is a
    bool scalar, not batched over seeds, so that the evaluation phases are really skipped; the
    ERD is matched to the learned intentions in use (:func:`kept_intentions`)."""
    k, b, t = env.num_intentions, config.rollout.num_envs, config.rollout.rollout_length
    eval_phases = evaluation_phases(config, env)

    def collect(state: TrainState, key, evaluating, data: RunData):
        train_env = training_env(env, data)

        def phase(index, carry):
            """Phase 0 rolls out for learning; phases 1.. continue deterministic episodes from
            fresh starts and add up their true returns."""
            train_state, batch, eval_state, totals, alive = carry
            training = index == 0
            start = tree_where(training, train_state, eval_state)
            policy = stages.acting(state.policy, state.normalizer, explore=training)
            end, transitions = stages.collect(
                train_env, policy, start, jax.random.fold_in(key, index)
            )
            more, still_alive = episode_totals(transitions, alive)
            return (
                tree_where(training, end, train_state),
                tree_where(training, transitions, batch),
                tree_where(training, fresh_starts(end), end),
                jnp.where(training, totals, totals + more),
                jnp.where(training, alive, still_alive),
            )

        carry = (
            state.env_state,
            Transitions.zeros(
                t, k, b, env.observation_size, env.action_size, stages.records_next_obs
            ),
            state.env_state,
            jnp.zeros((k, b, k)),
            jnp.ones((k, b)),
        )
        phases = 1 + eval_phases * evaluating.astype(jnp.int32)
        end, batch, _, totals, _ = jax.lax.fori_loop(0, phases, phase, carry)
        in_use = kept_intentions(config, state, data)
        evaluation = jax.lax.cond(
            evaluating,
            lambda: evaluation_metrics(totals.mean(1), data.demos, in_use),
            lambda: no_evaluation(
                data.demos.true_intentions, None if in_use is None else in_use.shape[0]
            ),
        )
        return end, batch, evaluation

    return collect


def kept_intentions(config: MethodConfig, state: TrainState, data: RunData) -> jax.Array | None:
    """``[K]`` the learned intentions holding demonstrations when K is chosen from the data,
    from the weights the iteration starts with (the policies evaluated are the state's); None
    when K is given. The seeds' consensus decides the run's K at the end."""
    if not config.choose_intentions:
        return None
    return holds_demonstrations(state.intention_weights, data.demos.episodes)


def normalized_batch(
    normalizer: obs_norm.RunningStats,
    transitions: Transitions,
    demos: DemonstrationPairs,
    env: envs.Env,
    obs_clip: float,
) -> NormalizedBatch:
    """The rollout and the demonstrations as the posterior and the discriminator see them, with
    ``normalizer`` (the rollout's statistics included); TRPO keeps the raw samples."""
    normalize = lambda x: obs_norm.normalize(normalizer, x, obs_clip)
    return NormalizedBatch(
        normalizer=normalizer,
        obs=normalize(intention_major(transitions.obs)),
        executed=env.clip_action(intention_major(transitions.action)),
        expert_obs=normalize(demos.observations),
        expert_actions=demos.actions,
    ).check()


def make_reseed(config: MethodConfig, networks: Networks, k: int, hooks: Hooks = PAPER):
    """``reseed(memory, e, discriminator, seen, demos, algorithm) -> (memory, e)``: the
    E-step's gamma (and mixture weights) with an emptied intention re-seeded
    (:mod:`emgail_jax.method.reseeding`); the demonstrations it takes are those the
    discriminator of their intention (before this M-step) tells best from its policy."""
    e_config = config.e_step
    rule = ReseedingRule(e_config.reseed_patience, e_config.reseed_window, e_config.reseed_attempts)

    def reseed(memory: Reseeding, e: EStep, discriminator: Learner, seen, demos, algorithm):
        def scores(holder: jax.Array) -> jax.Array:
            logits = expert_scores(
                networks.discriminator.apply,
                discriminator.params,
                seen.expert_obs,
                hooks.form.read(seen),
                algorithm.discriminator_conditions(k),
            )  # [N, C]
            column = holder[demos.episode] if algorithm.conditional_discriminator else 0
            column = jnp.broadcast_to(column, demos.episode.shape)
            pair = jnp.take_along_axis(logits, column[:, None], -1)[:, 0]
            return demonstration_scores(pair, demos.episode, demos.episodes)

        per_demonstration = lambda gamma: demonstration_responsibilities(
            gamma, demos.episode, demos.episodes
        )
        held = held_responsibilities(e.gamma, memory, demos.episode)
        memory = reseeding_step(memory, per_demonstration(held), scores, rule)
        gamma = held_responsibilities(e.gamma, memory, demos.episode)
        metrics = {
            **e.metrics,
            "reseed/demonstrations": per_demonstration(e.gamma).sum(0),
            "reseed/reseedings": memory.reseedings.sum(),
            "reseed/target": memory.target,
        }
        weights = e.weights
        if config.e_step.prior.estimated:
            weights = mixture_weights(gamma)
            metrics["posterior/intention_weights"] = weights
        return count_down(memory), e.replace(gamma=gamma, weights=weights, metrics=metrics)

    return reseed


@dataclass(frozen=True)
class LearnedRewardStage:
    """The IRL loop's reward stage of the skeleton: steps 2-3 of Algorithm 1 (the E-step, the
    re-seeding of emptied intentions, the M-step) and the learned reward of every sample under
    its own intention, on which step 4 improves the policy; variants through ``hooks``."""

    config: MethodConfig
    env: envs.Env
    networks: Networks
    hooks: Hooks
    e_step: Callable  # (posterior, seen, demos, weights, lesson=None, iteration=None) -> EStep
    m_step: Callable  # (discriminator, batch, gamma, algorithm, read=None, hook=None) -> MStep
    reseed: Callable  # see make_reseed

    @classmethod
    def create(
        cls,
        config: MethodConfig,
        env: envs.Env,
        networks: Networks,
        optimizers: Optimizers,
        hooks: Hooks = PAPER,
    ):
        m_step = make_m_step(networks.discriminator.apply, optimizers.discriminator, config.m_step)
        e_step = make_e_step(
            networks.posterior.apply,
            optimizers.posterior,
            config.e_step,
            reward_from=config.reward.source,
            evidence=hooks.evidence,
        )
        reseed = make_reseed(config, networks, env.num_intentions, hooks)
        return cls(config, env, networks, hooks, e_step, m_step, reseed)

    def pseudo_reward(self, discriminator, algorithm, seen, own_log_posterior) -> jax.Array:
        """``[K, M]`` the B-step's reward of every sample of ``seen`` under its own intention
        (eq. 20 / 23), from the ``discriminator`` (a :class:`Learner`)."""
        k, m = seen.obs.shape[:2]
        read = self.hooks.form.read(seen)
        return learned_reward(
            self.networks.discriminator.apply,
            discriminator.params,
            algorithm,
            k,
            obs=seen.obs,
            executed=read.samples,
            intention=intention_rows((k, m)),
            own_log_posterior=own_log_posterior,
            intention_major=True,
            log_policy=read.offsets,
        )

    def observed(self, state: TrainState, transitions, normalizer, data, algorithm):
        """``(seen, sampling)``: the rollout and the demonstrations normalised, with what the
        hooks' form reads of them, and what the hooks may read of the iteration."""
        obs_clip = self.config.networks.obs_clip
        sampling = Sampling(
            transitions=transitions,
            demos=data.demos,
            env=self.env,
            normalize=lambda x: obs_norm.normalize(normalizer, x, obs_clip),
            policy=(self.networks.policy.apply, state.policy),
            algorithm=algorithm,
            key=state.key,
        )
        seen = normalized_batch(normalizer, transitions, data.demos, self.env, obs_clip)
        return self.hooks.form.observed(seen, sampling), sampling

    def expectation(self, state: TrainState, seen, demos, algorithm) -> tuple[EStep, Any]:
        """``(e, reseeding)``: the E-step, and the re-seeding of an emptied intention."""
        reseeding = state.reseeding
        # EM-GAIL's M-step sees a re-seeding in gamma; Info/IntentionGAIL's D(s, a) ignores
        # gamma, so its posterior learns the held demonstrations instead.
        teaches = reseeding is not None and not algorithm.conditional_discriminator
        lesson = lesson_of(reseeding, demos) if teaches else None
        e = self.e_step(
            state.posterior, seen, demos, state.intention_weights, lesson, state.iteration
        )
        if reseeding is not None:
            reseeding, e = self.reseed(reseeding, e, state.discriminator, seen, demos, algorithm)
        return e, reseeding

    def maximization(self, discriminator, negatives, gamma, algorithm) -> MStep:
        """The M-step on ``negatives`` (the hooks' form reads them, their loss hook adds)."""
        read = self.hooks.form.read(negatives)
        loss = self.hooks.loss
        hook = None if loss is None else loss(negatives, read, gamma, algorithm)
        return self.m_step(discriminator, negatives, gamma, algorithm, read, hook)

    def __call__(self, state: TrainState, transitions, normalizer, evaluating, data) -> Rewarded:
        config, demos = self.config, data.demos
        algorithm = algorithm_of(config, data)
        seen, sampling = self.observed(state, transitions, normalizer, data, algorithm)
        e, reseeding = self.expectation(state, seen, demos, algorithm)
        carry, negatives = self.hooks.negatives(state.negatives, seen, sampling)
        m = self.maximization(state.discriminator, negatives, e.gamma, algorithm)
        rewarding = config.reward.source.choose(
            updated=m.discriminator, previous=state.discriminator
        )
        reward = self.pseudo_reward(rewarding, algorithm, seen, e.own_log_posterior)
        in_use = kept_intentions(config, state, data)
        k = self.env.num_intentions
        clustering = clustering_metrics(
            e.responsibilities, demos, k, config.e_step.responsibilities, in_use
        )
        end_reward, end_metrics = self.hooks.termination.reward(
            self.networks.discriminator.apply, rewarding.params, algorithm, self.env
        )
        metrics = {
            **clustering,
            **e.metrics,
            **m.metrics,
            "train/pseudo_reward": reward.mean(),
            **end_metrics,
        }
        if in_use is not None:
            metrics["posterior/intentions_in_use"] = in_use.sum()
        learned = dict(
            discriminator=m.discriminator,
            posterior=e.posterior,
            intention_weights=e.weights,
            reseeding=reseeding,
            negatives=carry,
        )
        reward = time_major(reward, transitions.obs.shape[0])
        return Rewarded(reward, learned, metrics, end_reward)


def make_train(config: MethodConfig, env: envs.Env, hooks: Hooks = PAPER) -> Trainer:
    """Builds ``init(key, data) -> TrainState`` and
    ``update(state, evaluating, data) -> (state, metrics)`` (see the module docstring): the
    trainer skeleton (:mod:`~emgail_jax.method.skeleton`) with the E-step, the M-step and the
    learned reward as its reward stage; research variants through ``hooks`` (the paper's
    method by default; a config's: ``emgail_jax.variants.make_train``)."""
    config = config.resolved(env)
    networks = make_networks(config, env, hooks)
    optimizers = make_optimizers(config)
    stages = make_policy_stages(config, env, networks)
    collect = make_collect(config, env, stages)
    reward = LearnedRewardStage.create(config, env, networks, optimizers, hooks)
    update = make_update(stages, collect, reward)
    return Trainer(make_init(config, env, networks, optimizers, hooks), update)


class Trainer(NamedTuple):
    """``init(key, data) -> TrainState`` and ``update(state, evaluating, data) -> (state,
    metrics)``."""

    init: Callable
    update: Callable
