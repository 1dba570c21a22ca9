"""One training iteration of EM-GAIL, Info/IntentionGAIL or GAIL as a pure function.

``make_train(config, env, expert)`` returns ``init(key) -> TrainState`` and
``update(state) -> (state, metrics)``. One update is Algorithm 1 of the paper, for all K
intentions at once:

1. rollout: B envs per intention, T steps, with the current policy;
2. E-step: the posterior learns P(i | s, a) on those samples; gamma = P on the expert pairs;
3. M-step: the discriminator learns expert (weighted by gamma) against policy samples;
4. B-step: the samples are relabelled with the pseudo-reward, GAE computes advantages, TRPO
   updates the policy, and the value baseline is refitted;
5. metrics: deterministic episodes of every learned intention give the true returns, the ERD
   with the best intention matching, and the clustering accuracy of gamma.

The caller ``jit``s ``vmap(update)`` over seeds (see :mod:`emgail_jax.runner`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

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
from emgail_jax.networks import (
    Discriminator,
    GaussianPolicy,
    Posterior,
    ValueNet,
    action_distribution,
)
from emgail_jax.posterior import (
    Responsibilities,
    expert_responsibilities,
    log_posterior,
    posterior_update,
)
from emgail_jax.rollout import (
    batch_reset,
    episode_returns,
    intention_major,
    rollout,
    time_major,
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
    """The demonstrations, plus the references ERD is normalised with.

    Host (numpy) arrays on purpose: closed over by the update step, they compile in as
    constants. Device arrays would be passed to every device from the one that holds them,
    which deadlocks XLA:CPU when the seeds are sharded over several host devices.
    """

    observations: jax.Array  # [N, D] raw
    actions: jax.Array  # [N, A]
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
    """``(params, normalizer, deterministic) -> policy(obs [K, B, D], key)``: row k acts as
    intention k (GAIL's single policy ignores the row)."""

    def make(params, normalizer, deterministic: bool):
        def policy(obs, key):
            rows = jnp.broadcast_to(jnp.arange(k)[:, None], obs.shape[:2])
            condition = algorithm.policy_condition(rows, k)
            mean, log_std = networks.policy.apply(
                params,
                obs_norm.normalize(normalizer, obs, config.obs_clip),
                condition,
                intention_major=True,
            )
            if deterministic:
                return mean
            return action_distribution(mean, log_std).sample(seed=key)

        return policy

    return make


def clustering_metrics(
    e_step: Responsibilities | None, expert: ExpertData, k: int, mode: str
) -> dict:
    """The clustering accuracy of eq. 29 (the posterior's argmax on every expert pair) and, when
    the E-step works on whole demonstrations, the accuracy of those trajectory labels too; NaN
    without a posterior (GAIL) or without hidden labels."""
    names = ["eval/cluster_accuracy"]
    if mode == "trajectory":
        names.append("eval/trajectory_cluster_accuracy")
    if e_step is None or not expert.has_labels:
        return {name: jnp.float32(jnp.nan) for name in names}
    labels = (e_step.pair_labels, e_step.trajectory_labels)
    return {
        name: cluster_accuracy(predicted, expert.labels, k)
        for name, predicted in zip(names, labels, strict=False)
    }


def make_train(config: Config, env: envs.Env, expert: ExpertData):
    """Builds ``init(key) -> TrainState`` and ``update(state) -> (state, metrics)``."""
    config = config.resolved(env)
    algorithm = make_algorithm(config.algo, config.info_weight)
    k, b, t = env.num_intentions, config.num_envs, config.rollout_length
    train_env = envs.wrap_for_training(env)
    eval_env = envs.EpisodeWrapper(env)
    networks = make_networks(config, env)
    make_policy = policy_function(networks, algorithm, config, k)
    value_opt = optax.adam(config.value_learning_rate)
    discriminator_opt = optax.adam(config.discriminator_learning_rate)
    posterior_opt = optax.adam(config.posterior_learning_rate)

    # Intention of every sample of a rollout in the intention-major layout [K, T * B], and
    # flattened to [N] (host constants, see ExpertData).
    intention_rows = np.broadcast_to(np.arange(k)[:, None], (k, t * b))
    sample_intention = intention_rows.reshape(-1)

    def init(key: jax.Array) -> TrainState:
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

    def evaluate(policy, normalizer, key) -> dict:
        """Deterministic episodes of every learned intention, scored against the experts."""
        greedy = make_policy(policy, normalizer, deterministic=True)
        returns = episode_returns(eval_env, greedy, key, k, config.eval_episodes)  # [K, K]
        erd = normalized_erd(returns, expert.expert_returns, expert.random_returns)
        return {
            "eval/erd": erd.mean,
            "eval/erd_per_intention": erd.per_intention,  # [K] per true intention
            "eval/returns": returns[erd.matching, jnp.arange(k)],  # [K] per true intention
            "eval/matching": erd.matching,
        }

    def skip_evaluation(*_) -> dict:
        """What :func:`evaluate` returns when no episodes run: NaN (and matching -1)."""
        missing = jnp.full(k, jnp.nan, jnp.float32)
        return {
            "eval/erd": jnp.float32(jnp.nan),
            "eval/erd_per_intention": missing,
            "eval/returns": missing,
            "eval/matching": jnp.full(k, -1, jnp.int32),
        }

    def update(state: TrainState, evaluating: jax.Array) -> tuple[TrainState, dict]:
        """One iteration; ``evaluating`` (a bool scalar, not batched over seeds, so that the
        evaluation is really skipped) says whether to run the evaluation episodes."""
        key_next, key_rollout, key_value, key_eval = jax.random.split(state.key, 4)
        policy_condition = algorithm.policy_condition(intention_rows, k)  # [K, T * B, C]
        discriminator_condition = algorithm.discriminator_condition(intention_rows, k)

        # 1. Rollout of every intention with the current policy.
        behaviour = make_policy(state.policy, state.normalizer, deterministic=False)
        env_state, batch = rollout(train_env, behaviour, state.env_state, key_rollout, t)
        normalizer = obs_norm.update(state.normalizer, batch.obs)
        normalize = lambda x: obs_norm.normalize(normalizer, x, config.obs_clip)
        obs = normalize(intention_major(batch.obs))  # [K, T * B, D]
        # The posterior and the discriminator judge the action the env executed (clipped to
        # its range), as they do the demonstrations'; TRPO keeps the raw sample.
        executed = env.clip_action(intention_major(batch.action))  # [K, T * B, A]
        flat_obs, flat_executed = obs.reshape(k * t * b, -1), executed.reshape(k * t * b, -1)
        expert_obs = normalize(expert.observations)

        # 2. E-step: posterior on the policy's labelled samples, gamma on the expert pairs.
        if algorithm.learns_posterior:
            posterior, posterior_opt_state, posterior_metrics = posterior_update(
                networks.posterior.apply,
                posterior_opt,
                state.posterior,
                state.posterior_opt,
                flat_obs,
                flat_executed,
                sample_intention,
                config.posterior_steps,
            )
            e_step = expert_responsibilities(
                networks.posterior.apply,
                posterior,
                expert_obs,
                expert.actions,
                expert.episode,
                expert.episodes,
                config.responsibilities,
            )
            gamma = e_step.gamma
            own_log_posterior = jnp.take_along_axis(
                log_posterior(networks.posterior.apply, posterior, obs, executed),
                intention_rows[..., None],
                -1,
            )[..., 0]
        else:
            posterior, posterior_opt_state, posterior_metrics = None, None, {}
            e_step = None
            gamma = jnp.full((expert_obs.shape[0], k), 1.0 / k)
            own_log_posterior = jnp.zeros(intention_rows.shape)

        # 3. M-step: discriminator, expert pairs weighted over intentions by gamma.
        discriminator, discriminator_opt_state, discriminator_metrics = discriminator_update(
            networks.discriminator.apply,
            discriminator_opt,
            state.discriminator,
            state.discriminator_opt,
            config.discriminator_steps,
            expert_obs=expert_obs,
            expert_actions=expert.actions,
            expert_weights=algorithm.expert_weights(gamma),
            conditions=algorithm.discriminator_conditions(k),
            policy_obs=obs,
            policy_actions=executed,
            policy_conditions=discriminator_condition,
        )

        # 4. B-step: TRPO on the pseudo-reward of every sample under its own intention.
        logits = networks.discriminator.apply(
            discriminator, obs, executed, discriminator_condition, intention_major=True
        )
        reward = algorithm.pseudo_reward(logits, own_log_posterior)  # [K, T * B]
        last_intention = np.broadcast_to(np.arange(k)[:, None], (k, b))
        samples = PolicySamples(
            obs=time_major(obs, t),
            action=batch.action,
            condition=time_major(policy_condition, t),
            time=batch.time,
            done=batch.done,
            last_obs=normalize(env_state.obs),
            last_condition=algorithm.policy_condition(last_intention, k),
            last_time=env_state.info["steps"] / env.episode_length,
        )
        policy, value, value_opt_state, b_metrics = b_step(
            networks.policy.apply,
            networks.value.apply,
            value_opt,
            config,
            state.policy,
            state.value,
            state.value_opt,
            samples,
            time_major(reward, t),
            key_value,
        )

        # 5. Metrics: the clustering every iteration (cheap), the evaluation episodes when asked.
        eval_metrics = jax.lax.cond(
            evaluating, evaluate, skip_evaluation, policy, normalizer, key_eval
        )
        metrics = {
            **eval_metrics,
            **clustering_metrics(e_step, expert, k, config.responsibilities),
            "train/pseudo_reward": reward.mean(),
            **posterior_metrics,
            **discriminator_metrics,
            **b_metrics,
        }
        new_state = TrainState(
            policy=policy,
            value=value,
            value_opt=value_opt_state,
            discriminator=discriminator,
            discriminator_opt=discriminator_opt_state,
            posterior=posterior,
            posterior_opt=posterior_opt_state,
            normalizer=normalizer,
            env_state=env_state,
            key=key_next,
            iteration=state.iteration + 1,
        )
        return new_state, metrics

    return init, update
