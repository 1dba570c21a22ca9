"""A reward consolidated at the end of a run: each seed's discriminator refitted on its
gamma-weighted demonstrations against the samples of every policy the run kept a snapshot of.

During training the discriminator only ever tells the expert from the *latest* policy, so
behaviour the policies left behind long ago (and any a fresh agent may find) can be paid more
than the demonstrations. Refitting against all the run's policies at once is one way to take
that away (the issue's "consolidated reward"); it changes nothing in training: it reads the
snapshots (``run --snapshot-every``) after the run.

A refitted reward is saved in the run directory, ``RUN/rewards/NAME/seed-S.msgpack`` (the
discriminator's parameters) beside ``reward.json`` (the refit's options), so that
``load_reward(RUN, refit=NAME)`` returns it and a later check (another RL seed, reward form or
changed env) reuses it rather than refitting.

The refit may also start from fresh discriminator weights rather than the final ones, and see
a noisy copy of every policy sample as a further negative: a reward learnt in one go against
the run's whole history, with the smoothing training may not afford (a penalty strong enough to
generalise the reward can cost the clustering; docs/rewards-that-reoptimise.md).
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass

import jax
import jax.numpy as jnp
import numpy as np

from emgail_jax.host import checkpoints, records
from emgail_jax.method import normalizer as obs_norm
from emgail_jax.method.batches import NormalizedBatch
from emgail_jax.method.discriminator import discriminator_loss, state_only
from emgail_jax.method.optim import Learner, minimize
from emgail_jax.method.ranking import ranking_loss
from emgail_jax.method.rollout import (
    batch_reset,
    intention_major,
    still_policy,
    terminations,
    uniform_random_policy,
)
from emgail_jax.method.skeleton import intention_rows
from emgail_jax.method.support import with_support_negatives
from emgail_jax.method.training import (
    RunData,
    make_optimizers,
    make_policy_stages,
    seed_state,
    training_env,
)


@dataclass(frozen=True)
class Refit:
    """How the discriminator is refitted: ``steps`` full-batch Adam steps (the run's optimiser
    and learning rate) with a zero-centred gradient penalty of weight ``gradient_penalty``,
    from the run's final weights or, ``fresh``, from new ones; ``support_noise`` > 0 adds a
    copy of every policy sample moved by Gaussian noise of that standard deviation (in the
    normalised observation's units and the action's own: the M-step's
    :mod:`~emgail_jax.method.support` negatives). Every step sees every sample (and one draw
    of the noisy copies) or, with ``batch`` > 0, that many samples per intention drawn anew
    from the snapshots' pool (and their noisy copies), as training's M-step sees one
    iteration's batch; the demonstrations are whole in every step. ``ranking`` > 0 adds that
    weight times :func:`~emgail_jax.method.ranking.ranking_loss`: the snapshots ranked by
    iteration and the demonstrations above them, ``RANKED_PAIRS`` pairs of ``RANKED_SAMPLES``
    samples per intention drawn anew in every step; below the oldest snapshot rank, lowest
    first, one rollout of uniformly random actions (``ranking_random``) and one of actions held
    still (``ranking_still``), each a ranking level only. ``agent_rounds`` > 0 refits that many
    times more, each time against fresh agents trained on the last refit too
    (:func:`emgail_jax.host.reward_check.consolidated`): every step's negatives are then ``batch``
    samples of the snapshots and ``batch`` of those agents' rollouts (a GAIL negative only, not
    a ranking level). ``state_only`` refits D(s, i), every action read as zeros
    (:func:`~emgail_jax.method.discriminator.state_only`), here and wherever the reward is read.
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
    agent_rounds: int = 0
    state_only: bool = False
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


def snapshot_policy_samples(run, seed: int, key: jax.Array, iterations=None):
    """``(obs [K, M, D] raw, executed [K, M, A], terminal [K, M])``: one training rollout
    (with exploration) of the policy of every snapshot of ``seed`` (``iterations``; default
    all up to the networks ``run`` holds), concatenated."""
    stages, collect = _training_rollout(run)
    of_snapshot = jax.jit(
        lambda state, key: collect(stages.acting(state.policy, state.normalizer, explore=True), key)
    )
    if iterations is None:
        last = run.snapshot or run.iteration
        iterations = [i for i in checkpoints.snapshot_iterations(run.run_dir) if i <= last]
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


def agents_policy(policy_of, states):
    """The policy of one training rollout of fresh agents ``states [K]``: agent k acts on
    intention k's row of the ``[K, B, D]`` observations with ``policy_of(state)``, which
    takes one agent's ``[1, B, D]`` as it trained on."""

    def policy(obs, key):
        keys = jax.random.split(key, obs.shape[0])
        act = lambda state, row, key: policy_of(state)(row[None], key)[0]
        return jax.vmap(act)(states, obs, keys)

    return policy


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
    fixed draw): the price of the absorbing state under ``--absorbing-reward random``. A fall
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
    run, seed: int, refit: Refit, key: jax.Array, agents=None, samples=None
) -> tuple[dict, dict]:
    """``(reward parameters, metrics)``: :meth:`SavedRun.reward_parameters` of ``seed`` with
    its discriminator refitted as ``refit`` says on the expert pairs weighted by the final
    responsibilities against the policy samples of every snapshot and, if given, ``agents``
    (``(obs [K, M', D] raw, executed [K, M', A], terminal [K, M'])``: fresh agents' rollouts,
    as many negatives per step as the snapshots'); ``samples`` are the snapshots' (default
    :func:`snapshot_policy_samples` of ``seed`` and ``key``, collected here). The metrics are
    those of the M-step's loss before (on the first step's batch) and after (on every
    sample). A refit with absorbing states needs ``run`` opened
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
    algorithm, config, k = run.algorithm, run.config, run.num_intentions
    if refit.absorbing:
        _check_absorbing(run, refit)
    pairs = run.demonstration_pairs
    obs, executed, terminal = (
        snapshot_policy_samples(run, seed, key) if samples is None else samples
    )
    normalize = lambda x: obs_norm.normalize(state.normalizer, x, config.method.networks.obs_clip)
    pool = NormalizedBatch(
        normalizer=state.normalizer,
        obs=normalize(obs),
        executed=executed,
        expert_obs=normalize(pairs.observations),
        expert_actions=pairs.actions,
    )
    if refit.absorbing:
        episode_length = run.problem.env.episode_length
        pool = pool.replace(
            terminal=terminal, expert_terminal=pairs.terminations(episode_length)
        ).check()
    met_agents = None
    if agents is not None:
        met_agents = (normalize(agents[0]), agents[1], agents[2] if refit.absorbing else None)
    # ([K, F, M, D], [K, F, M, A]): the ranking's levels below every snapshot, lowest first.
    below = [
        sampled(run, level_key)
        for wanted, sampled, level_key in (
            (refit.ranking_random, random_action_samples, key_random),
            (refit.ranking_still, still_action_samples, key_still),
        )
        if wanted
    ]
    floor = None
    if below:
        # A ranking level is a behaviour, not a negative: its terminations bring no absorbing pair.
        obs_below, actions_below, _ = (np.stack(levels, 1) for levels in zip(*below, strict=True))
        floor = (normalize(obs_below), actions_below)

    def ranked_levels(pool: NormalizedBatch, floor):
        """``(obs [K, L, M, D], actions [K, L, M, A])``: the ranking's levels below the
        demonstrations, lowest first (``floor``, if any, then the snapshots)."""
        by_snapshot = lambda x: x.reshape(k, snapshots, -1, x.shape[-1])
        obs, actions = by_snapshot(pool.obs), by_snapshot(pool.executed)
        if floor is None:
            return obs, actions
        return jnp.concatenate([floor[0], obs], 1), jnp.concatenate([floor[1], actions], 1)

    if algorithm.learns_posterior:
        gamma = np.asarray(run.responsibilities(seed).gamma)
    else:
        gamma = np.ones((pairs.observations.shape[0], k))

    def with_noise(seen: NormalizedBatch, key: jax.Array) -> NormalizedBatch:
        if not refit.support_noise:
            return seen
        return with_support_negatives(seen, key, refit.support_noise)

    def loss_inputs(seen: NormalizedBatch) -> dict:
        absorbed = {}
        if seen.terminal is not None:
            absorbed = dict(
                expert_absorbed=seen.expert_terminal @ algorithm.expert_weights(gamma),
                policy_absorbed=seen.terminal.sum(1),
            )
        return dict(
            expert_obs=seen.expert_obs,
            expert_actions=seen.expert_actions,
            expert_weights=algorithm.expert_weights(gamma),
            conditions=algorithm.discriminator_conditions(k),
            policy_obs=seen.obs,
            policy_actions=seen.executed,
            policy_conditions=algorithm.discriminator_condition(seen.own_intention(), k),
            gradient_penalty=refit.gradient_penalty,
            **absorbed,
        )

    def drawn(pool: NormalizedBatch, agents, key: jax.Array) -> NormalizedBatch:
        """``refit.batch`` samples of each intention, drawn uniformly from the pool, and as
        many from ``agents`` (if any) after them."""
        key_draw, key_moved = jax.random.split(key)
        take = lambda x, rows: None if x is None else x[:, rows]
        rows = jax.random.randint(key_draw, (refit.batch,), 0, pool.obs.shape[1])
        seen = pool.replace(
            obs=take(pool.obs, rows),
            executed=take(pool.executed, rows),
            terminal=take(pool.terminal, rows),
        )
        if agents is not None:
            key_agents = jax.random.fold_in(key, 1)
            rows = jax.random.randint(key_agents, (refit.batch,), 0, agents[0].shape[1])
            seen = seen.with_more_samples(*(take(x, rows) for x in agents))
        return with_noise(seen, key_moved)

    apply = run.networks.discriminator.apply
    if refit.state_only:
        apply = state_only(apply)
    optimizer = make_optimizers(config.method).discriminator
    rollout = config.method.rollout
    snapshots = obs.shape[1] // (rollout.num_envs * rollout.rollout_length)

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
    # loss after the refit is measured in the same program, compiled once.
    @jax.jit
    def refitted(
        learner: Learner, pool: NormalizedBatch, floor, agents
    ) -> tuple[Learner, dict, dict]:
        whole = pool if agents is None else pool.with_more_samples(*agents)
        whole = with_noise(whole, key_noise)
        levels = ranked_levels(pool, floor) if refit.ranking else None
        if refit.batch or refit.ranking:
            # Every step draws anew: its batch, its ranked pairs, or both.
            seen = lambda key: drawn(pool, agents, key) if refit.batch else whole
            step = lambda learner, key: fit(learner, 1, seen(key), levels, key)
            keys = jax.random.split(key_draws, refit.steps)
            learner, metrics = jax.lax.scan(step, learner, keys)
            before = jax.tree.map(lambda m: m[0], metrics)
        else:
            learner, before = fit(learner, refit.steps, whole, levels, key_draws)
        _, after = fit(learner, 1, whole, levels, key_draws)
        return learner, before, after

    start = state.discriminator
    if refit.fresh:
        start = Learner.create(new_discriminator_weights(run, key_init), optimizer)
    trained, before, after = refitted(start, pool, floor, met_agents)
    metrics = {"before": jax.device_get(before), "after": jax.device_get(after)}
    return {**parameters, "discriminator": trained.params}, metrics


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


def rewards_directory(run_dir: str) -> str:
    return os.path.join(os.path.abspath(run_dir), "rewards")


def saved_refits(run_dir: str) -> list[str]:
    """The names of the refitted rewards saved in ``run_dir``, in order."""
    root = rewards_directory(run_dir)
    if not os.path.isdir(root):
        return []
    names = os.listdir(root)
    return sorted(n for n in names if os.path.exists(os.path.join(root, n, "reward.json")))


def _seed_path(run_dir: str, name: str, number: int) -> str:
    """The file of the run's seed ``number`` (as ``run --seed`` numbered it)."""
    return os.path.join(rewards_directory(run_dir), name, f"seed-{number}.msgpack")


def save_refitted(
    run_dir: str, name: str, number: int, discriminator, description: dict, losses: dict
) -> None:
    """Writes the refitted discriminator parameters of the run's seed ``number`` (as ``run
    --seed`` numbered it) as the saved reward ``name``, with
    ``description`` (``reward.json``: :func:`refit_description`) and
    the refit's ``losses`` (``seed-S.json``); each file renamed into place once written."""
    directory = os.path.join(rewards_directory(run_dir), name)
    os.makedirs(directory, exist_ok=True)
    path = _seed_path(run_dir, name, number)
    checkpoints.write_tree(path, jax.device_get(discriminator))
    records.write_json(path.removesuffix(".msgpack") + ".json", losses)
    records.write_json(os.path.join(directory, "reward.json"), description)


def read_losses(run_dir: str, name: str, number: int) -> dict:
    """The refit's losses of the run's seed ``number`` saved with the reward ``name`` (empty
    if none)."""
    path = _seed_path(run_dir, name, number).removesuffix(".msgpack") + ".json"
    if not os.path.exists(path):
        return {}
    with open(path) as f:
        return json.load(f)


def refit_description(refit: Refit, snapshot: int | None, iteration: int) -> dict:
    """What ``reward.json`` says of a saved refit: its options, the snapshot whose networks
    (observation statistics, posterior) the reward reads beside the refit (None: the final
    ones), and the iteration of those networks, so that a run resumed since is not read with
    the refit of its earlier networks."""
    return {"refit": asdict(refit), "snapshot": snapshot, "iteration": iteration}


def read_description(run_dir: str, name: str) -> dict:
    """The ``reward.json`` of the saved reward ``name``, its refit's options completed with the
    defaults of those added since it was saved.

    Raises:
      CheckpointError: ``run_dir`` saved no reward of that name (the message lists those it did).
    """
    path = os.path.join(rewards_directory(run_dir), name, "reward.json")
    if not os.path.exists(path):
        saved = ", ".join(saved_refits(run_dir)) or "none; reoptimize --consolidate saves one"
        raise checkpoints.CheckpointError(
            f"'{run_dir}' saved no refitted reward '{name}' (saved: {saved})"
        )
    with open(path) as f:
        description = json.load(f)
    # Refits saved before the iteration was recorded: a snapshot's is its iteration, the final
    # networks' is unknown (None).
    iteration = description.get("iteration", description["snapshot"])
    return {**description, "refit": asdict(Refit(**description["refit"])), "iteration": iteration}


def check_refitted_from(run, name: str) -> None:
    """Raises CheckpointError unless the saved reward ``name`` was refitted from the networks
    ``run`` holds (a run resumed since has others)."""
    refitted_from = read_description(run.run_dir, name)["iteration"]
    networks = run.snapshot or run.iteration
    if refitted_from != networks:
        of = "an unrecorded iteration" if refitted_from is None else f"iteration {refitted_from}"
        raise checkpoints.CheckpointError(
            f"the saved reward '{name}' of '{run.run_dir}' was refitted from the networks of "
            f"{of}, not those of iteration {networks}: delete "
            f"{os.path.join(rewards_directory(run.run_dir), name)} to refit it"
        )


def saved_parameters(run, name: str, seed: int) -> dict | None:
    """:meth:`SavedRun.reward_parameters` of ``seed`` with the discriminator of the saved
    refitted reward ``name``; None when that seed was not refitted under that name.

    Raises:
      CheckpointError: a file that cannot be read or does not fit the run's discriminator,
        or one refitted from the networks of another iteration than ``run``'s.
    """
    path = _seed_path(run.run_dir, name, run.seed_number(seed))
    if not os.path.exists(path):
        return None
    check_refitted_from(run, name)
    # The network's shapes, not the run's own weights: a refit with absorbing states reads
    # one input more than a run trained without them.
    shapes = jax.eval_shape(lambda key: new_discriminator_weights(run, key), jax.random.PRNGKey(0))
    template = jax.tree.map(lambda x: np.zeros(x.shape, x.dtype), shapes)
    saved = checkpoints.read_tree(path, template, "the reward")
    return {**run.reward_parameters(seed), "discriminator": saved}
