"""The refit: each seed's discriminator fitted again, after the run, on its gamma-weighted
demonstrations against the samples of every policy the run kept a snapshot of.

During training the discriminator only ever tells the expert from the *latest* policy, so
behaviour the policies left behind long ago (and any a fresh agent may find) can be paid more
than the demonstrations. Refitting against all the run's policies at once is one way to take
that away; it changes nothing in training: it reads the snapshots (``run --snapshot-every``)
after the run. Where a refit is saved and read again: :mod:`emgail_jax.reward.saved`.

The refit may also start from fresh discriminator weights rather than the final ones, and see
a noisy copy of every policy sample as a further negative: a reward learnt in one go against
the run's whole history, with the smoothing training may not afford (a penalty strong enough to
generalise the reward can cost the clustering; docs/reward.md, "The refit").
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from emgail_jax.host import checkpoints
from emgail_jax.method import normalizer as obs_norm
from emgail_jax.method.batches import NormalizedBatch
from emgail_jax.method.discriminator import Read, discriminator_loss, loss_batch
from emgail_jax.method.optim import Learner, minimize
from emgail_jax.method.rollout import (
    batch_reset,
    intention_major,
    still_policy,
    terminations,
    uniform_random_policy,
)
from emgail_jax.method.skeleton import intention_rows
from emgail_jax.method.training import (
    RunData,
    make_optimizers,
    make_policy_stages,
    seed_state,
    training_env,
)
from emgail_jax.reward.ranking import ranking_loss
from emgail_jax.variants.assembly import VariantLoss
from emgail_jax.variants.extras import attached, extras_of
from emgail_jax.variants.support import with_support_negatives


@dataclass(frozen=True)
class Refit:
    """How the discriminator is refitted: ``steps`` full-batch Adam steps (the run's optimiser
    and learning rate) with a zero-centred gradient penalty of weight ``gradient_penalty``,
    from the run's final weights or, ``fresh``, from new ones; ``support_noise`` > 0 adds a
    copy of every policy sample moved by Gaussian noise of that standard deviation (in the
    normalised observation's units and the action's own: the M-step's
    :mod:`~emgail_jax.variants.support` negatives). Every step sees every sample (and one draw
    of the noisy copies) or, with ``batch`` > 0, that many samples per intention drawn anew
    from the snapshots' pool (and their noisy copies), as training's M-step sees one
    iteration's batch; the demonstrations are whole in every step. ``ranking`` > 0 adds that
    weight times :func:`~emgail_jax.reward.ranking.ranking_loss`: the snapshots ranked by
    iteration and the demonstrations above them, ``RANKED_PAIRS`` pairs of ``RANKED_SAMPLES``
    samples per intention drawn anew in every step; below the oldest snapshot rank, lowest
    first, one rollout of uniformly random actions (``ranking_random``) and one of actions held
    still (``ranking_still``), each a ranking level only.
    ``absorbing`` refits with termination as an absorbing state (DAC,
    :mod:`~emgail_jax.method.discriminator`): every sample whose transition ended its episode
    early brings one absorbing negative, and a fresh agent's fall is paid the absorbing state's
    learned reward for every step left; the network then reads one input more, so the refit
    starts ``fresh`` unless the run trained with absorbing states."""

    steps: int
    gradient_penalty: float = 0.0
    fresh: bool = False
    support_noise: float = 0.0
    batch: int = 0
    ranking: float = 0.0
    ranking_random: bool = False
    ranking_still: bool = False
    absorbing: bool = False


# Enough pairs that every step sees most snapshots, few enough samples that each side's mean
# still tells two neighbouring snapshots apart now and then.
RANKED_PAIRS = 64
RANKED_SAMPLES = 32


def _training_rollout(run):
    """``(stages, collect)``: the run's policy stages and ``collect(policy, key) -> (obs
    [K, M, D] raw, executed [K, M, A], terminal [K, M])``, one training rollout (``num_envs``
    x ``rollout_length`` steps per intention, from fresh starts) of ``policy``; ``terminal``
    is 1.0 where a transition ended its episode before the time limit."""
    config, env = run.config, run.problem.env
    k, b = env.num_intentions, config.method.rollout.num_envs
    stages = make_policy_stages(config.method, env, run.networks)
    data = RunData.create(run.demonstration_pairs, env, config.info_weight)
    train_env = training_env(env, data)

    def collect(policy, key):
        key_reset, key_rollout = jax.random.split(key)
        start = batch_reset(train_env, key_reset, (k, b))
        _, transitions = stages.collect(train_env, policy, start, key_rollout)
        return (
            intention_major(transitions.obs),
            env.clip_action(intention_major(transitions.action)),
            intention_major(terminations(transitions, env.episode_length)),
        )

    return stages, collect


def snapshots_used(run) -> list[int]:
    """The iterations of the snapshots a refit of ``run`` learns from: every one up to the
    networks ``run`` holds."""
    last = run.snapshot or run.iteration
    return [i for i in checkpoints.snapshot_iterations(run.run_dir) if i <= last]


def snapshot_policy_samples(run, seed: int, key: jax.Array, iterations=None):
    """``(obs [K, M, D] raw, executed [K, M, A], terminal [K, M])``: one training rollout
    (with exploration) of the policy of every snapshot of ``seed`` (``iterations``; default
    all up to the networks ``run`` holds), concatenated."""
    stages, collect = _training_rollout(run)
    of_snapshot = jax.jit(
        lambda state, key: collect(stages.acting(state.policy, state.normalizer, explore=True), key)
    )
    if iterations is None:
        iterations = snapshots_used(run)
    if not iterations:
        raise checkpoints.CheckpointError(
            f"'{run.run_dir}' kept no snapshots to consolidate from (run --snapshot-every)"
        )
    rollouts = []
    for iteration, snapshot_key in zip(
        iterations, jax.random.split(key, len(iterations)), strict=True
    ):
        state = seed_state(checkpoints.restore_snapshot(run.run_dir, iteration, run.state), seed)
        rollouts.append(jax.device_get(of_snapshot(state, snapshot_key)))
    return tuple(np.concatenate(parts, 1) for parts in zip(*rollouts, strict=True))


def fixed_policy_samples(run, policy, key: jax.Array):
    """``(obs [K, M, D] raw, executed [K, M, A], terminal [K, M])``: one training rollout per
    intention of ``policy`` (acting on raw observations), of the shape of one snapshot's in
    :func:`snapshot_policy_samples`."""
    _, collect = _training_rollout(run)
    return jax.device_get(jax.jit(collect, static_argnums=0)(policy, key))


def random_action_samples(run, key: jax.Array):
    """:func:`fixed_policy_samples` of uniformly random actions."""
    return fixed_policy_samples(run, uniform_random_policy(run.problem.env), key)


# One fixed draw, so that a reward's absorbing price is the same wherever it is read.
ABSORBING_PRICE_KEY = 20260


def random_actions_reward(run, parameters: dict, reward_function) -> np.ndarray:
    """``[K]``: the reward ``reward_function(parameters, obs, action, intention)`` pays per
    step, intention by intention, to uniformly random actions over one training rollout (a
    fixed draw): the price of the absorbing state under ``--set absorbing_reward=random``. A fall
    then costs what acting at random for the rest of the episode would earn, rather than the
    absorbing state's own learned reward, which the refit drives as low as its penalty lets
    it, no demonstration ever reaching that state."""
    obs, actions, _ = random_action_samples(run, jax.random.key(ABSORBING_PRICE_KEY))
    rows = lambda i: jnp.full(obs.shape[1], i)
    paid = [reward_function(parameters, obs[i], actions[i], rows(i)) for i in range(len(obs))]
    return np.array([float(jnp.mean(p)) for p in paid])


def priced_absorbing_reward(parameters: dict, intention: jax.Array) -> jax.Array:
    """The absorbing reward of parameters that carry their ``absorbing_price [K]``."""
    return jnp.take(parameters["absorbing_price"], intention)


def still_action_samples(run, key: jax.Array):
    """:func:`fixed_policy_samples` of actions held at the middle of the box."""
    return fixed_policy_samples(run, still_policy(run.problem.env), key)


def consolidated_parameters(
    run, seed: int, refit: Refit, key: jax.Array, samples=None, *, on_steps=None
) -> tuple[dict, dict]:
    """``(reward parameters, metrics)``: :meth:`SavedRun.reward_parameters` of ``seed`` with
    its discriminator refitted as ``refit`` says on the expert pairs weighted by the final
    responsibilities against the policy samples of every snapshot; ``samples`` are the
    snapshots' (default :func:`snapshot_policy_samples` of ``seed`` and ``key``, collected
    here). The metrics are those of the M-step's loss before (on the first step's batch) and
    after (on every sample). ``on_steps(steps, metrics)``, if given, is called as the refit
    goes, after every part of its steps (:data:`PROGRESS_PARTS`), with the metrics of that
    part's first step. A refit with absorbing states needs ``run`` opened
    :meth:`~emgail_jax.host.saved_run.SavedRun.with_absorbing_states`.

    Raises:
      ValueError: an absorbing refit of a run whose network reads no absorbing input, or one
        from the run's own weights that were not trained with absorbing states.
    """
    # The samples keep ``key`` itself, so a refit without the newer options draws what it did.
    key_init, key_noise, key_draws, key_random, key_still = (
        jax.random.fold_in(key, i) for i in (1, 2, 3, 4, 5)
    )
    parameters = run.reward_parameters(seed)
    state = run.seed_state(seed)
    if refit.absorbing:
        _check_absorbing(run, refit)
    samples = snapshot_policy_samples(run, seed, key) if samples is None else samples
    clip = run.config.method.networks.obs_clip
    normalize = lambda x: obs_norm.normalize(state.normalizer, x, clip)
    pool = _refit_pool(run, refit, state.normalizer, normalize, samples)
    floor = _ranking_floor(run, refit, normalize, key_random, key_still)
    optimizer = make_optimizers(run.config.method).discriminator
    gamma = _responsibilities(run, seed)
    refitted = _refit_program(run, refit, gamma, optimizer, (key_noise, key_draws))
    start = state.discriminator
    if refit.fresh:
        start = Learner.create(new_discriminator_weights(run, key_init), optimizer)
    trained, before, after = refitted(start, pool, floor, on_steps)
    metrics = {"before": jax.device_get(before), "after": jax.device_get(after)}
    return {**parameters, "discriminator": trained.params}, metrics


def _refit_pool(run, refit: Refit, normalizer, normalize, samples) -> NormalizedBatch:
    """The snapshots' ``samples`` and the demonstration pairs as the refit sees them, with
    their terminations where it learns an absorbing state."""
    pairs = run.demonstration_pairs
    obs, executed, terminal = samples
    pool = NormalizedBatch(
        normalizer=normalizer,
        obs=normalize(obs),
        executed=executed,
        expert_obs=normalize(pairs.observations),
        expert_actions=pairs.actions,
    )
    if refit.absorbing:
        episode_length = run.problem.env.episode_length
        pool = attached(
            pool, terminal=terminal, expert_terminal=pairs.terminations(episode_length)
        ).check()
    return pool


def _ranking_floor(run, refit: Refit, normalize, key_random, key_still):
    """``(obs [K, F, M, D], actions [K, F, M, A])``: the ranking's levels below every
    snapshot, lowest first (random actions, then actions held still, as ``refit`` asks);
    None without them."""
    below = [
        sampled(run, level_key)
        for wanted, sampled, level_key in (
            (refit.ranking_random, random_action_samples, key_random),
            (refit.ranking_still, still_action_samples, key_still),
        )
        if wanted
    ]
    if not below:
        return None
    # A ranking level is a behaviour, not a negative: its terminations bring no absorbing pair.
    obs_below, actions_below, _ = (np.stack(levels, 1) for levels in zip(*below, strict=True))
    return normalize(obs_below), actions_below


def _responsibilities(run, seed: int) -> np.ndarray:
    """``[N, K]`` how much each demonstration pair belongs to each intention (every pair alike
    without a posterior)."""
    if run.algorithm.learns_posterior:
        return np.asarray(run.responsibilities(seed).gamma)
    return np.ones((run.demonstration_pairs.observations.shape[0], run.num_intentions))


def _refit_program(run, refit: Refit, gamma: np.ndarray, optimizer, keys):
    """The refit ``(learner, pool, floor, on_steps) -> (learner, metrics before, metrics
    after)`` of the M-step's loss (and the ranking's, if asked) over the ``pool`` of samples,
    the demonstrations weighted by ``gamma [N, K]``, its steps in one jitted program or, with
    ``on_steps``, in parts (:func:`step_parts`); ``keys``: the noisy copies' and the draws'."""
    algorithm, k = run.algorithm, run.num_intentions
    key_noise, key_draws = keys
    rollout = run.config.method.rollout

    def ranked_levels(pool: NormalizedBatch, floor):
        """``(obs [K, L, M, D], actions [K, L, M, A])``: the ranking's levels below the
        demonstrations, lowest first (``floor``, if any, then the snapshots)."""
        snapshots = pool.obs.shape[1] // (rollout.num_envs * rollout.rollout_length)
        by_snapshot = lambda x: x.reshape(k, snapshots, -1, x.shape[-1])
        obs, actions = by_snapshot(pool.obs), by_snapshot(pool.executed)
        if floor is None:
            return obs, actions
        return jnp.concatenate([floor[0], obs], 1), jnp.concatenate([floor[1], actions], 1)

    def with_noise(seen: NormalizedBatch, key: jax.Array) -> NormalizedBatch:
        if not refit.support_noise:
            return seen
        return with_support_negatives(seen, key, refit.support_noise)

    def loss_inputs(seen: NormalizedBatch) -> dict:
        absorbing = extras_of(seen).terminal is not None
        hook = VariantLoss(absorbing, refit.gradient_penalty)(seen, Read.of(seen), gamma, algorithm)
        return loss_batch(seen, gamma, algorithm, hook=hook)

    def drawn(pool: NormalizedBatch, key: jax.Array) -> NormalizedBatch:
        """``refit.batch`` samples of each intention, drawn uniformly from the pool."""
        key_draw, key_moved = jax.random.split(key)
        take = lambda x, rows: None if x is None else x[:, rows]
        rows = jax.random.randint(key_draw, (refit.batch,), 0, pool.obs.shape[1])
        seen = pool.replace(obs=take(pool.obs, rows), executed=take(pool.executed, rows))
        if pool.extra is not None:
            seen = attached(seen, terminal=take(extras_of(pool).terminal, rows))
        return with_noise(seen, key_moved)

    apply = run.networks.discriminator.apply

    def loss(params, seen: NormalizedBatch, levels, key: jax.Array):
        value, metrics = discriminator_loss(apply, params, **loss_inputs(seen))
        if not refit.ranking:
            return value, metrics
        ranked, ranked_metrics = ranking_loss(
            apply,
            params,
            key,
            policy_obs=levels[0],
            policy_actions=levels[1],
            expert_obs=seen.expert_obs,
            expert_actions=seen.expert_actions,
            expert_weights=gamma,
            condition_of=lambda intentions: algorithm.discriminator_condition(intentions, k),
            pairs=RANKED_PAIRS,
            samples=RANKED_SAMPLES,
        )
        return value + refit.ranking * ranked, {**metrics, **ranked_metrics}

    fit = lambda learner, steps, seen, levels, key: minimize(
        lambda p: loss(p, seen, levels, key), optimizer, learner, steps
    )

    # The pool is an argument, not a constant the compiler would fold into the program; the
    # loss after the refit is measured in the program of the last steps. With progress to
    # show, the steps run in parts (two programs), to the numbers of one program of them all.
    @functools.partial(jax.jit, static_argnums=4)
    def part(learner: Learner, pool: NormalizedBatch, floor, keys, last: bool):
        """``(learner, metrics, after)``: ``len(keys)`` steps (``keys [n]`` their draws), the
        metrics of the first, and if ``last`` those after them on every sample."""
        whole = with_noise(pool, key_noise)
        levels = ranked_levels(pool, floor) if refit.ranking else None
        if refit.batch or refit.ranking:
            # Every step draws anew: its batch, its ranked pairs, or both.
            seen = lambda key: drawn(pool, key) if refit.batch else whole
            step = lambda learner, key: fit(learner, 1, seen(key), levels, key)
            learner, metrics = jax.lax.scan(step, learner, keys)
            first = jax.tree.map(lambda m: m[0], metrics)
        else:
            learner, first = fit(learner, keys.shape[0], whole, levels, key_draws)
        after = fit(learner, 1, whole, levels, key_draws)[1] if last else None
        return learner, first, after

    def refitted(learner: Learner, pool: NormalizedBatch, floor, on_steps=None):
        keys = jax.random.split(key_draws, refit.steps)
        parts = step_parts(refit.steps, 1 if on_steps is None else PROGRESS_PARTS)
        before = None
        for first, length in parts:
            last = first + length == refit.steps
            learner, metrics, after = part(learner, pool, floor, keys[first : first + length], last)
            before = metrics if before is None else before
            if on_steps is not None:
                on_steps(length, metrics)
        return learner, before, after

    return refitted


# The parts a refit's steps run in when it shows its progress: enough to show it, few enough
# that the host's calls between them cost nothing beside the steps.
PROGRESS_PARTS = 10


def step_parts(steps: int, parts: int) -> list[tuple[int, int]]:
    """``(first, length)`` of each part of ``steps`` steps: ``parts`` parts of one length,
    the last shorter where they do not divide ``steps``."""
    length = -(-steps // parts)
    return [(first, min(length, steps - first)) for first in range(0, steps, length)]


def new_discriminator_weights(run, key: jax.Array) -> dict:
    """Weights of the run's discriminator network drawn anew from ``key``."""
    pairs, k = run.demonstration_pairs, run.num_intentions
    condition = run.algorithm.discriminator_condition(intention_rows((1,)), k)
    return run.networks.discriminator.init(
        key, pairs.observations[:1], pairs.actions[:1], condition
    )


def _check_absorbing(run, refit: Refit) -> None:
    if not run.config.method.reward.absorbing_state:
        raise ValueError(
            "a refit with absorbing states reads the run opened with_absorbing_states()"
        )
    if not (refit.fresh or run.trained_with_absorbing_states):
        raise ValueError(
            "the run's discriminator was trained without absorbing states: refit it fresh"
        )
