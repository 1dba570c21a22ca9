"""One training iteration of EM-GAIL, Info/IntentionGAIL or GAIL as a pure function.

``make_train(config, env)`` returns ``init(key, data) -> TrainState`` and
``update(state, evaluating, data) -> (state, metrics)``. ``data`` (a :class:`RunData`: the
demonstrations, ERD's references, the env's data such as the driver's path curvatures, and
Info/IntentionGAIL's lambda) is an argument of the compiled program rather than constants in it,
so runs that differ only in their data share one program (and the persistent compilation cache).

One update is Algorithm 1 of the paper, for all K intentions at once (``update`` reads as it):

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
from emgail_jax.method.b_step import BStep, PolicySamples, make_b_step
from emgail_jax.method.batches import DemonstrationPairs, LearningBatch, NormalizedBatch
from emgail_jax.method.choosing import holds_demonstrations
from emgail_jax.method.config import MethodConfig, ResponsibilityMode
from emgail_jax.method.discriminator import expert_logits, learned_reward, make_m_step
from emgail_jax.method.metrics import cluster_accuracy, normalized_erd
from emgail_jax.method.networks import (
    Discriminator,
    GaussianPolicy,
    Posterior,
    ValueNet,
    policy_action,
)
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
    rollout,
    time_major,
    tree_where,
)


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
    discriminator: Discriminator
    posterior: Posterior


def make_networks(config: MethodConfig, env: envs.Env) -> Networks:
    shape = config.networks
    heads = shape.intention_input.heads
    return Networks(
        policy=GaussianPolicy(env.action_size, shape.hidden, shape.init_log_std, heads),
        value=ValueNet(shape.hidden, heads),
        discriminator=Discriminator(shape.hidden, heads),
        posterior=Posterior(env.num_intentions, shape.hidden),
    )


def policy_function(networks: Networks, algorithm: Algorithm, config: MethodConfig, k: int):
    """``(params, normalizer) -> policy(obs [K, B, D], key, explore)``: row k acts as intention
    k (GAIL's single policy ignores the row). ``explore`` (a possibly traced bool) adds the
    Gaussian noise; without it the policy takes its mean."""

    def make(params, normalizer):
        def policy(obs, key, explore):
            rows = jnp.broadcast_to(jnp.arange(k)[:, None], obs.shape[:2])
            condition = algorithm.policy_condition(rows, k)
            return policy_action(
                networks.policy,
                params,
                normalizer,
                obs,
                condition,
                obs_clip=config.networks.obs_clip,
                key=key,
                explore=explore,
                intention_major=True,
            )

        return policy

    return make


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
    networks: Networks, config: MethodConfig, state: TrainState, demos: DemonstrationPairs
) -> Responsibilities:
    """The E-step's responsibilities of ``demos`` under one seed's ``state`` (its posterior,
    observation statistics and mixture weights), computed as training computes them."""
    expert_obs = obs_norm.normalize(state.normalizer, demos.observations, config.networks.obs_clip)
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
    return make_algorithm(config.algo, data.info_weight, config.reward.form)


def own_intentions(k: int, m: int) -> np.ndarray:
    """``[K, M]``: the intention of every sample in the intention-major layout (row i is i)."""
    return np.broadcast_to(np.arange(k)[:, None], (k, m))


class Optimizers(NamedTuple):
    value: optax.GradientTransformation
    discriminator: optax.GradientTransformation
    posterior: optax.GradientTransformation


def make_optimizers(config: MethodConfig) -> Optimizers:
    return Optimizers(
        value=optax.adam(config.b_step.value_learning_rate),
        discriminator=optax.adam(config.m_step.learning_rate),
        posterior=optax.adam(config.e_step.learning_rate),
    )


def make_init(config: MethodConfig, env: envs.Env, networks: Networks, optimizers: Optimizers):
    """``init(key, data) -> TrainState``: fresh networks and ``[K, B]`` reset training envs."""
    k, b = env.num_intentions, config.rollout.num_envs

    def init(key: jax.Array, data: RunData) -> TrainState:
        algorithm = algorithm_of(config, data)
        train_env = envs.wrap_for_training(env.bind(data.env))
        first = own_intentions(k, 1)[:1, 0]
        policy_condition = algorithm.policy_condition(first, k)
        discriminator_condition = algorithm.discriminator_condition(first, k)
        keys = dict(
            zip(
                ("policy", "value", "disc", "post", "env", "next"),
                jax.random.split(key, 6),
                strict=True,
            )
        )
        obs = jnp.zeros((1, env.observation_size))
        action = jnp.zeros((1, env.action_size))
        value = networks.value.init(keys["value"], obs, policy_condition, jnp.zeros(1))
        discriminator = networks.discriminator.init(
            keys["disc"], obs, action, discriminator_condition
        )
        posterior = (
            Learner.create(networks.posterior.init(keys["post"], obs, action), optimizers.posterior)
            if algorithm.learns_posterior
            else None
        )
        return TrainState(
            policy=networks.policy.init(keys["policy"], obs, policy_condition),
            value=Learner.create(value, optimizers.value),
            discriminator=Learner.create(discriminator, optimizers.discriminator),
            posterior=posterior,
            normalizer=obs_norm.RunningStats.create(env.observation_size),
            intention_weights=jnp.full(k, 1.0 / k),
            env_state=batch_reset(train_env, keys["env"], (k, b)),
            key=keys["next"],
            iteration=jnp.zeros((), jnp.int32),
            reseeding=Reseeding.create(k, data.demos.episodes) if config.reseeds else None,
        )

    return init


def lesson_of(memory: Reseeding, demos: DemonstrationPairs) -> Lesson:
    """The demonstrations a re-seeding split, as the posterior learns them."""
    return Lesson(
        active=memory.left > 0,
        intentions=memory.taught_intentions()[demos.episode],
        weights=memory.split[demos.episode].astype(jnp.float32),
    )


class Collector(NamedTuple):
    """Step 1 of an update (and the evaluation episodes), and its pieces for the benchmark."""

    collect: Callable  # (env_state, policy, key, explore, data) -> (end, transitions)
    acting: Callable  # (state, data) -> policy(obs, key, explore)
    collect_and_evaluate: Callable  # (state, evaluating, data, key) -> (end, batch, metrics)


def make_collector(config: MethodConfig, env: envs.Env, networks: Networks) -> Collector:
    k, b, t = env.num_intentions, config.rollout.num_envs, config.rollout.rollout_length
    eval_phases = evaluation_phases(config, env)

    def collect(env_state: envs.State, policy, key, explore, data: RunData):
        """T steps of the [K, B] auto-resetting envs from ``env_state`` with ``policy``
        (see rollout.rollout). Returns ``(end_state, transitions [T, K, B, ...])``."""
        train_env = envs.wrap_for_training(env.bind(data.env))
        act = lambda obs, step_key: policy(obs, step_key, explore)
        return rollout(train_env, act, env_state, key, t)

    def acting(state: TrainState, data: RunData):
        """The policy of ``state`` as ``collect`` drives it."""
        return policy_function(networks, algorithm_of(config, data), config, k)(
            state.policy, state.normalizer
        )

    def collect_and_evaluate(state: TrainState, evaluating, data: RunData, key, in_use=None):
        """1. The rollout for learning and, when ``evaluating`` (5.), the deterministic
        evaluation episodes: phases of one loop whose body steps the env once. Returns
        ``(end_state, rollout, evaluation metrics)``, the ERD matched to the learned intentions
        ``in_use`` (None: all)."""
        policy = acting(state, data)

        def phase(index, carry):
            """Phase 0 rolls out for learning; phases 1.. continue deterministic episodes from
            fresh starts and add up their true returns."""
            train_state, batch, eval_state, totals, alive = carry
            training = index == 0
            start = tree_where(training, train_state, eval_state)
            key_phase = jax.random.fold_in(key, index)
            end, transitions = collect(start, policy, key_phase, training, data)
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
            Transitions.zeros(t, k, b, env.observation_size, env.action_size),
            state.env_state,
            jnp.zeros((k, b, k)),
            jnp.ones((k, b)),
        )
        phases = 1 + eval_phases * evaluating.astype(jnp.int32)
        end, batch, _, totals, _ = jax.lax.fori_loop(0, phases, phase, carry)
        evaluation = jax.lax.cond(
            evaluating,
            lambda: evaluation_metrics(totals.mean(1), data.demos, in_use),
            lambda: no_evaluation(
                data.demos.true_intentions, None if in_use is None else in_use.shape[0]
            ),
        )
        return end, LearningBatch.of(batch, end, env.episode_length), evaluation

    return Collector(collect, acting, collect_and_evaluate)


def make_improve(config: MethodConfig, env: envs.Env, networks: Networks, b_step: Callable):
    """``improve(state, batch, seen, *, discriminator, own_log_posterior, algorithm, key) ->
    BStep``: step 4, TRPO on the learned reward of every sample under its own intention."""
    k, b, t = env.num_intentions, config.rollout.num_envs, config.rollout.rollout_length
    own_intention = own_intentions(k, t * b)

    def improve(state, batch, seen, *, discriminator, own_log_posterior, algorithm, key) -> BStep:
        reward = learned_reward(
            networks.discriminator.apply,
            discriminator.params,
            algorithm,
            k,
            obs=seen.obs,
            executed=seen.executed,
            intention=own_intention,
            own_log_posterior=own_log_posterior,
            intention_major=True,
        )  # [K, T * B]
        samples = PolicySamples.of(
            batch,
            lambda x: obs_norm.normalize(seen.normalizer, x, config.networks.obs_clip),
            time_major(algorithm.policy_condition(own_intention, k), t),
            algorithm.policy_condition(own_intentions(k, b), k),
        )
        improved = b_step(state.policy, state.value, samples, time_major(reward, t), key)
        return improved.replace(metrics={"train/pseudo_reward": reward.mean(), **improved.metrics})

    return improve


def make_train(config: MethodConfig, env: envs.Env) -> Trainer:
    """Builds ``init(key, data) -> TrainState`` and
    ``update(state, evaluating, data) -> (state, metrics)`` (see the module docstring)."""
    config = config.resolved(env)
    k = env.num_intentions
    networks = make_networks(config, env)
    optimizers = make_optimizers(config)
    init = make_init(config, env, networks, optimizers)
    collector = make_collector(config, env, networks)
    e_step = make_e_step(
        networks.posterior.apply,
        optimizers.posterior,
        config.e_step,
        reward_from=config.reward.source,
    )
    m_step = make_m_step(networks.discriminator.apply, optimizers.discriminator, config.m_step)
    b_step = make_b_step(
        networks.policy.apply, networks.value.apply, optimizers.value, config.b_step
    )
    improve = make_improve(config, env, networks, b_step)

    def normalized(state: TrainState, batch: LearningBatch, data: RunData) -> NormalizedBatch:
        """The rollout and the demonstrations as the posterior and the discriminator see them;
        TRPO keeps the raw samples."""
        normalizer = obs_norm.update(state.normalizer, batch.obs)
        normalize = lambda x: obs_norm.normalize(normalizer, x, config.networks.obs_clip)
        return NormalizedBatch(
            normalizer=normalizer,
            obs=normalize(intention_major(batch.obs)),
            executed=env.clip_action(intention_major(batch.action)),
            expert_obs=normalize(data.demos.observations),
            expert_actions=data.demos.actions,
        ).check()

    def kept_intentions(state: TrainState, data: RunData) -> jax.Array | None:
        """``[K]`` the learned intentions holding demonstrations when K is chosen from the data,
        from the weights the iteration starts with (the policies evaluated are the state's);
        None when K is given. The seeds' consensus decides the run's K at the end."""
        if not config.choose_intentions:
            return None
        return holds_demonstrations(state.intention_weights, data.demos.episodes)

    e_config = config.e_step
    rule = ReseedingRule(e_config.reseed_patience, e_config.reseed_window, e_config.reseed_attempts)

    def reseed(
        memory: Reseeding,
        e: EStep,
        discriminator: Learner,
        seen: NormalizedBatch,
        demos: DemonstrationPairs,
        algorithm: Algorithm,
    ) -> tuple[Reseeding, EStep]:
        """The E-step's gamma (and mixture weights) with an emptied intention re-seeded
        (:mod:`emgail_jax.method.reseeding`); the demonstrations it takes are those the
        discriminator of their intention (before this M-step) tells best from its policy."""

        def scores(holder: jax.Array) -> jax.Array:
            logits = expert_logits(
                networks.discriminator.apply,
                discriminator.params,
                seen.expert_obs,
                seen.expert_actions,
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

    def update(state: TrainState, evaluating: jax.Array, data: RunData) -> tuple[TrainState, dict]:
        """One iteration of Algorithm 1; ``evaluating`` (a bool scalar, not batched over seeds,
        so that the evaluation phases are really skipped) says whether to run the evaluation
        episodes."""
        key_next, key_phases, key_value = jax.random.split(state.key, 3)
        algorithm = algorithm_of(config, data)
        in_use = kept_intentions(state, data)
        end, batch, evaluation = collector.collect_and_evaluate(
            state, evaluating, data, key_phases, in_use
        )
        seen = normalized(state, batch, data)
        reseeding = state.reseeding
        # EM-GAIL's M-step sees a re-seeding in gamma; Info/IntentionGAIL's D(s, a) ignores
        # gamma, so its posterior learns the held demonstrations instead.
        teaches = reseeding is not None and not algorithm.conditional_discriminator
        lesson = lesson_of(reseeding, data.demos) if teaches else None
        e = e_step(state.posterior, seen, data.demos, state.intention_weights, lesson)
        if reseeding is not None:
            reseeding, e = reseed(reseeding, e, state.discriminator, seen, data.demos, algorithm)
        m = m_step(state.discriminator, seen, e.gamma, algorithm)
        rewarding = config.reward.source.choose(
            updated=m.discriminator, previous=state.discriminator
        )
        b = improve(
            state,
            batch,
            seen,
            discriminator=rewarding,
            own_log_posterior=e.own_log_posterior,
            algorithm=algorithm,
            key=key_value,
        )
        new_state = TrainState(
            policy=b.policy,
            value=b.value,
            discriminator=m.discriminator,
            posterior=e.posterior,
            normalizer=seen.normalizer,
            intention_weights=e.weights,
            env_state=end,
            key=key_next,
            iteration=state.iteration + 1,
            reseeding=reseeding,
        )
        clustering = clustering_metrics(
            e.responsibilities, data.demos, k, config.e_step.responsibilities, in_use
        )
        metrics = {**evaluation, **clustering, **e.metrics, **m.metrics, **b.metrics}
        if in_use is not None:
            metrics["posterior/intentions_in_use"] = in_use.sum()
        return new_state, metrics

    steps = Steps(collector, normalized, e_step, m_step, improve)
    return Trainer(init, update, steps)


class Steps(NamedTuple):
    """The pieces of one update, for callers that run them alone (the benchmark)."""

    collector: Collector
    normalized: Callable
    e_step: Callable
    m_step: Callable
    improve: Callable


class Trainer(NamedTuple):
    """``init(key, data) -> TrainState``, ``update(state, evaluating, data) -> (state,
    metrics)``, and the update's pieces."""

    init: Callable
    update: Callable
    steps: Steps
