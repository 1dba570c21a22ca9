"""One training iteration of EM-GAIL, Info/IntentionGAIL or GAIL as a pure function.

``make_train(config, env)`` returns ``init(key, data) -> TrainState`` and
``update(state, evaluating, data) -> (state, metrics)``. ``data`` (a :class:`RunData`: the
demonstrations, ERD's references, the env's data such as the driver's path curvatures, and
Info/IntentionGAIL's lambda) is an argument of the compiled program rather than constants in it,
so runs that differ only in their data share one program (and the persistent compilation cache).

One update is Algorithm 1 of the paper, for all K intentions at once:

1. rollout: B envs per intention, T steps, with the current policy;
2. E-step: the posterior learns P(i | s, a) on those samples; gamma = P on the expert pairs;
3. M-step: the discriminator learns expert (weighted by gamma) against policy samples;
4. B-step: the samples are relabelled with the pseudo-reward, GAE computes advantages, TRPO
   updates the policy, and the value baseline is refitted;
5. metrics: the clustering accuracy of the E-step and, when ``evaluating``, deterministic
   episodes (one per env of the rollout, from fresh starts) of the policy that made this
   iteration's rollout, scored with the true rewards: returns and the ERD with the best
   intention matching. Iteration n thus scores the policy after n - 1 updates.

The rollout and the evaluation episodes are phases of one loop whose body steps the env once:
the env step, the largest part of an MJX program, is compiled once rather than once for
training and once more for evaluation.

The caller ``jit``s ``vmap(update)`` over seeds (see :mod:`emgail_jax.runner`).
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
from emgail_jax import normalizer as obs_norm
from emgail_jax.algorithms import Algorithm, make_algorithm
from emgail_jax.bstep import PolicySamples, b_step
from emgail_jax.config import Config
from emgail_jax.demos import Demonstrations
from emgail_jax.discriminator import discriminator_update
from emgail_jax.metrics import cluster_accuracy, normalized_erd
from emgail_jax.networks import Discriminator, GaussianPolicy, Posterior, ValueNet
from emgail_jax.posterior import (
    TRAJECTORY_MODES,
    Responsibilities,
    expert_responsibilities,
    log_posterior,
    posterior_update,
)
from emgail_jax.rollout import (
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

    policy: Any
    value: Any
    value_opt: Any
    discriminator: Any
    discriminator_opt: Any
    posterior: Any  # None for GAIL
    posterior_opt: Any
    normalizer: obs_norm.RunningStats
    env_state: envs.State  # [K, B] auto-resetting training envs
    key: jax.Array
    iteration: jax.Array


@struct.dataclass
class ExpertData:
    """The demonstrations, plus the references ERD is normalised with."""

    observations: jax.Array  # [N, D] raw
    actions: jax.Array  # [N, A] executed (clipped to the env's range)
    episode: jax.Array  # [N] index of each pair's demonstration (episode)
    labels: jax.Array  # [N] hidden intention labels, -1 when unknown
    expert_returns: jax.Array  # [K] NaN when unknown
    random_returns: jax.Array  # [K]
    episodes: int = struct.field(pytree_node=False, default=1)  # demonstrations (episodes)
    has_labels: bool = struct.field(pytree_node=False, default=False)

    @classmethod
    def create(cls, demos: Demonstrations, random_returns: np.ndarray, k: int) -> ExpertData:
        n = len(demos)
        labels = demos.intentions if demos.intentions is not None else np.full(n, -1)
        returns = demos.expert_returns
        returns = np.full(k, np.nan) if returns is None else returns
        episode = np.maximum(np.cumsum(demos.episode_starts) - 1, 0).astype(np.int32)
        return cls(
            observations=np.asarray(demos.observations, np.float32),
            actions=np.asarray(demos.actions, np.float32),
            episode=episode,
            labels=np.asarray(labels, np.int32),
            expert_returns=np.asarray(returns, np.float32),
            random_returns=np.asarray(random_returns, np.float32),
            episodes=int(episode.max()) + 1,
            has_labels=demos.intentions is not None,
        )


@struct.dataclass
class RunData:
    """What the compiled program takes as arguments: everything that is data, not shape.

    Host (numpy) arrays here; the runner places one copy on every device before the first call.
    """

    expert: ExpertData
    env: Any  # env.data(): e.g. the driver's path curvatures; None for the MJX envs
    info_weight: jax.Array  # [] Info/IntentionGAIL's lambda (eq. 23)

    @classmethod
    def create(cls, expert: ExpertData, env: envs.Env, config: Config) -> RunData:
        return cls(expert, env.data(), np.float32(config.info_weight))


@dataclass(frozen=True)
class Networks:
    policy: GaussianPolicy
    value: ValueNet
    discriminator: Discriminator
    posterior: Posterior


def make_networks(config: Config, env: envs.Env) -> Networks:
    heads = config.intention_input == "heads"
    return Networks(
        policy=GaussianPolicy(env.action_size, config.hidden, config.init_log_std, heads),
        value=ValueNet(config.hidden, heads),
        discriminator=Discriminator(config.hidden, heads),
        posterior=Posterior(env.num_intentions, config.hidden),
    )


def policy_function(networks: Networks, algorithm: Algorithm, config: Config, k: int):
    """``(params, normalizer) -> policy(obs [K, B, D], key, explore)``: row k acts as intention
    k (GAIL's single policy ignores the row). ``explore`` (a possibly traced bool) adds the
    Gaussian noise; without it the policy takes its mean."""

    def make(params, normalizer):
        def policy(obs, key, explore):
            rows = jnp.broadcast_to(jnp.arange(k)[:, None], obs.shape[:2])
            condition = algorithm.policy_condition(rows, k)
            mean, log_std = networks.policy.apply(
                params,
                obs_norm.normalize(normalizer, obs, config.obs_clip),
                condition,
                intention_major=True,
            )
            noise = jax.random.normal(key, mean.shape)
            return mean + jnp.where(explore, jnp.exp(log_std) * noise, 0.0)

        return policy

    return make


def clustering_metrics(
    e_step: Responsibilities | None, expert: ExpertData, k: int, mode: str
) -> dict:
    """The clustering accuracy of eq. 29 (the posterior's argmax on every expert pair) and, when
    the E-step works on whole demonstrations, the accuracy of those trajectory labels too; NaN
    without a posterior (GAIL, which has no trajectory labels either) or without hidden labels."""
    names = ["eval/cluster_accuracy"]
    if mode in TRAJECTORY_MODES and e_step is not None:
        names.append("eval/trajectory_cluster_accuracy")
    if e_step is None or not expert.has_labels:
        return {name: jnp.float32(jnp.nan) for name in names}
    labels = (e_step.pair_labels, e_step.trajectory_labels)
    return {
        name: cluster_accuracy(predicted, expert.labels, k)
        for name, predicted in zip(names, labels, strict=False)
    }


def evaluation_metrics(returns: jax.Array, expert: ExpertData) -> dict:
    """ERD (eq. 28) of ``returns [K learned, K true]``, per true intention and matched."""
    k = returns.shape[-1]
    erd = normalized_erd(returns, expert.expert_returns, expert.random_returns)
    return {
        "eval/erd": erd.mean,
        "eval/erd_per_intention": erd.per_intention,  # [K] per true intention
        "eval/returns": returns[erd.matching, jnp.arange(k)],  # [K] per true intention
        "eval/matching": erd.matching,
    }


def no_evaluation(k: int) -> dict:
    """What :func:`evaluation_metrics` gives for an iteration without evaluation: NaN (matching
    -1), never stale values."""
    missing = jnp.full(k, jnp.nan, jnp.float32)
    return {
        "eval/erd": jnp.float32(jnp.nan),
        "eval/erd_per_intention": missing,
        "eval/returns": missing,
        "eval/matching": jnp.full(k, -1, jnp.int32),
    }


def evaluation_phases(config: Config, env: envs.Env) -> int:
    """Rollouts of ``rollout_length`` steps that cover one evaluation episode."""
    return math.ceil(env.episode_length / config.rollout_length)


def make_train(config: Config, env: envs.Env) -> Trainer:
    """Builds ``init(key, data) -> TrainState`` and
    ``update(state, evaluating, data) -> (state, metrics)`` (see the module docstring)."""
    config = config.resolved(env)
    k, b, t = env.num_intentions, config.num_envs, config.rollout_length
    networks = make_networks(config, env)
    value_opt = optax.adam(config.value_learning_rate)
    discriminator_opt = optax.adam(config.discriminator_learning_rate)
    posterior_opt = optax.adam(config.posterior_learning_rate)
    eval_phases = evaluation_phases(config, env)

    # Intention of every sample of a rollout in the intention-major layout [K, T * B], and
    # flattened to [N].
    intention_rows = np.broadcast_to(np.arange(k)[:, None], (k, t * b))
    sample_intention = intention_rows.reshape(-1)

    def algorithm_of(data: RunData) -> Algorithm:
        return make_algorithm(config.algo, data.info_weight, config.reward_form)

    def init(key: jax.Array, data: RunData) -> TrainState:
        algorithm = algorithm_of(data)
        train_env = envs.wrap_for_training(env.bind(data.env))
        policy_condition = algorithm.policy_condition(sample_intention[:1], k)
        discriminator_condition = algorithm.discriminator_condition(sample_intention[:1], k)
        keys = dict(
            zip(
                ("policy", "value", "disc", "post", "env", "next"),
                jax.random.split(key, 6),
                strict=True,
            )
        )
        obs = jnp.zeros((1, env.observation_size))
        action = jnp.zeros((1, env.action_size))
        policy = networks.policy.init(keys["policy"], obs, policy_condition)
        value = networks.value.init(keys["value"], obs, policy_condition, jnp.zeros(1))
        discriminator = networks.discriminator.init(
            keys["disc"], obs, action, discriminator_condition
        )
        posterior = (
            networks.posterior.init(keys["post"], obs, action)
            if algorithm.learns_posterior
            else None
        )
        return TrainState(
            policy=policy,
            value=value,
            value_opt=value_opt.init(value),
            discriminator=discriminator,
            discriminator_opt=discriminator_opt.init(discriminator),
            posterior=posterior,
            posterior_opt=posterior_opt.init(posterior) if posterior is not None else None,
            normalizer=obs_norm.RunningStats.create(env.observation_size),
            env_state=batch_reset(train_env, keys["env"], (k, b)),
            key=keys["next"],
            iteration=jnp.zeros((), jnp.int32),
        )

    def judged(state: TrainState, batch: LearningBatch, data: RunData) -> Judged:
        """The rollout and the demonstrations as the posterior and the discriminator see them:
        observations normalised with statistics that include this rollout, and the actions
        the env executed (clipped to its range), on both sides; TRPO keeps the raw samples."""
        normalizer = obs_norm.update(state.normalizer, batch.obs)
        normalize = lambda x: obs_norm.normalize(normalizer, x, config.obs_clip)
        return Judged(
            normalizer=normalizer,
            obs=normalize(intention_major(batch.obs)),
            executed=env.clip_action(intention_major(batch.action)),
            expert_obs=normalize(data.expert.observations),
            last_obs=normalize(batch.last_obs),
        )

    def e_step(state: TrainState, seen: Judged, data: RunData) -> EStep:
        """2. The posterior learns on the policy's labelled samples (eq. 18); gamma on the
        expert pairs. Without a posterior (GAIL): uniform gamma, zero log-posterior."""
        if not algorithm_of(data).learns_posterior:
            n = seen.expert_obs.shape[0]
            uniform = jnp.full((n, k), 1.0 / k)
            return EStep(None, None, None, uniform, jnp.zeros(intention_rows.shape), {})
        expert = data.expert
        flat = lambda x: x.reshape(k * t * b, -1)
        posterior, posterior_opt_state, metrics = posterior_update(
            networks.posterior.apply,
            posterior_opt,
            state.posterior,
            state.posterior_opt,
            flat(seen.obs),
            flat(seen.executed),
            sample_intention,
            config.posterior_steps,
        )
        responsibilities = expert_responsibilities(
            networks.posterior.apply,
            posterior,
            seen.expert_obs,
            expert.actions,
            expert.episode,
            expert.episodes,
            config.responsibilities,
            expert.labels if expert.has_labels else None,
        )
        rewarding = posterior if config.reward_from == "updated" else state.posterior
        own_log_posterior = jnp.take_along_axis(
            log_posterior(networks.posterior.apply, rewarding, seen.obs, seen.executed),
            intention_rows[..., None],
            -1,
        )[..., 0]
        return EStep(
            posterior,
            posterior_opt_state,
            responsibilities,
            responsibilities.gamma,
            own_log_posterior,
            metrics,
        )

    def m_step(state: TrainState, seen: Judged, gamma: jax.Array, data: RunData):
        """3. The discriminator learns the expert pairs, weighted over intentions by gamma
        (eq. 19), against the policy samples under their own intention."""
        algorithm = algorithm_of(data)
        return discriminator_update(
            networks.discriminator.apply,
            discriminator_opt,
            state.discriminator,
            state.discriminator_opt,
            config.discriminator_steps,
            expert_obs=seen.expert_obs,
            expert_actions=data.expert.actions,
            expert_weights=algorithm.expert_weights(gamma),
            conditions=algorithm.discriminator_conditions(k),
            policy_obs=seen.obs,
            policy_actions=seen.executed,
            policy_conditions=algorithm.discriminator_condition(intention_rows, k),
        )

    def improve(state, batch, seen, discriminator, own_log_posterior, data, key):
        """4. The B-step: TRPO on the pseudo-reward of every sample under its own intention."""
        algorithm = algorithm_of(data)
        logits = networks.discriminator.apply(
            discriminator,
            seen.obs,
            seen.executed,
            algorithm.discriminator_condition(intention_rows, k),
            intention_major=True,
        )
        reward = algorithm.pseudo_reward(logits, own_log_posterior)  # [K, T * B]
        last_intention = np.broadcast_to(np.arange(k)[:, None], (k, b))
        samples = PolicySamples(
            obs=time_major(seen.obs, t),
            action=batch.action,
            condition=time_major(algorithm.policy_condition(intention_rows, k), t),
            time=batch.time,
            done=batch.done,
            last_obs=seen.last_obs,
            last_condition=algorithm.policy_condition(last_intention, k),
            last_time=batch.last_time,
        )
        policy, value, value_opt_state, metrics = b_step(
            networks.policy.apply,
            networks.value.apply,
            value_opt,
            config,
            state.policy,
            state.value,
            state.value_opt,
            samples,
            time_major(reward, t),
            key,
        )
        return policy, value, value_opt_state, {"train/pseudo_reward": reward.mean(), **metrics}

    def learn(state: TrainState, batch: LearningBatch, data: RunData, key_value) -> tuple:
        """Steps 2-4 on the rollout ``batch``; returns the new learners and their metrics."""
        seen = judged(state, batch, data)
        e = e_step(state, seen, data)
        discriminator, discriminator_opt_state, m_metrics = m_step(state, seen, e.gamma, data)
        rewarding = discriminator if config.reward_from == "updated" else state.discriminator
        policy, value, value_opt_state, b_metrics = improve(
            state, batch, seen, rewarding, e.own_log_posterior, data, key_value
        )
        learned = state.replace(
            policy=policy,
            value=value,
            value_opt=value_opt_state,
            discriminator=discriminator,
            discriminator_opt=discriminator_opt_state,
            posterior=e.posterior,
            posterior_opt=e.posterior_opt,
            normalizer=seen.normalizer,
        )
        metrics = {
            **clustering_metrics(e.responsibilities, data.expert, k, config.responsibilities),
            **e.metrics,
            **m_metrics,
            **b_metrics,
        }
        return learned, metrics

    def collect(env_state: envs.State, policy, key, explore, data: RunData):
        """1. T steps of the [K, B] auto-resetting envs from ``env_state`` with ``policy``
        (see rollout.rollout). Returns ``(end_state, transitions [T, K, B, ...])``."""
        train_env = envs.wrap_for_training(env.bind(data.env))
        act = lambda obs, step_key: policy(obs, step_key, explore)
        return rollout(train_env, act, env_state, key, t)

    def acting(state: TrainState, data: RunData):
        """The policy of ``state`` as ``collect`` drives it."""
        return policy_function(networks, algorithm_of(data), config, k)(
            state.policy, state.normalizer
        )

    def update(state: TrainState, evaluating: jax.Array, data: RunData) -> tuple[TrainState, dict]:
        """One iteration; ``evaluating`` (a bool scalar, not batched over seeds, so that the
        evaluation phases are really skipped) says whether to run the evaluation episodes."""
        key_next, key_phases, key_value = jax.random.split(state.key, 3)
        policy = acting(state, data)

        def phase(index, carry):
            """Phase 0 rolls out for learning; phases 1.. continue deterministic episodes from
            fresh starts and add up their true returns."""
            train_state, batch, eval_state, totals, alive = carry
            training = index == 0
            start = tree_where(training, train_state, eval_state)
            key = jax.random.fold_in(key_phases, index)
            end, transitions = collect(start, policy, key, training, data)
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
            lambda: evaluation_metrics(totals.mean(1), data.expert),
            lambda: no_evaluation(k),
        )
        learned, metrics = learn(
            state, LearningBatch.of(batch, end, env.episode_length), data, key_value
        )
        new_state = learned.replace(env_state=end, key=key_next, iteration=state.iteration + 1)
        return new_state, {**evaluation, **metrics}

    steps = Steps(collect, acting, judged, e_step, m_step, improve, learn)
    return Trainer(init, update, steps)


class Steps(NamedTuple):
    """The pieces of one update, for callers that run them alone (the benchmark)."""

    collect: Callable
    acting: Callable
    judged: Callable
    e_step: Callable
    m_step: Callable
    improve: Callable
    learn: Callable


class Trainer(NamedTuple):
    """``init(key, data) -> TrainState``, ``update(state, evaluating, data) -> (state,
    metrics)``, and the update's pieces."""

    init: Callable
    update: Callable
    steps: Steps


@struct.dataclass
class Judged:
    """A rollout and the demonstrations as the E- and M-steps see them (normalised)."""

    normalizer: obs_norm.RunningStats  # including the rollout
    obs: jax.Array  # [K, T * B, D] the samples, grouped by intention
    executed: jax.Array  # [K, T * B, A] their actions as executed (clipped)
    expert_obs: jax.Array  # [N, D]
    last_obs: jax.Array  # [K, B, D] the states after the rollout


@struct.dataclass
class EStep:
    """What the E-step hands on: the trained posterior, gamma and the policy samples' own
    log-posterior (Info/IntentionGAIL's reward term)."""

    posterior: Any  # None without a posterior (GAIL)
    posterior_opt: Any
    responsibilities: Responsibilities | None
    gamma: jax.Array  # [N, K]
    own_log_posterior: jax.Array  # [K, T * B]
    metrics: dict


@struct.dataclass
class LearningBatch:
    """A rollout as the learning steps read it: the transitions, and the state after them (for
    the value baseline's bootstrap)."""

    obs: jax.Array  # [T, K, B, D] raw
    action: jax.Array  # [T, K, B, A] raw samples
    time: jax.Array  # [T, K, B]
    done: jax.Array  # [T, K, B]
    last_obs: jax.Array  # [K, B, D] raw
    last_time: jax.Array  # [K, B]

    @classmethod
    def of(cls, batch: Transitions, end: envs.State, episode_length: int) -> LearningBatch:
        return cls(
            obs=batch.obs,
            action=batch.action,
            time=batch.time,
            done=batch.done,
            last_obs=end.obs,
            last_time=end.info["steps"] / episode_length,
        )
