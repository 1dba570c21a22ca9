"""A finished (or interrupted) run, reopened from its directory: what was learned, reusable.

>>> import emgail_jax
>>> policy = emgail_jax.load_policy("runs/driver-emgail")   # pi(s, i), jittable
>>> run = emgail_jax.SavedRun.open("runs/driver-emgail")
>>> action = policy(obs, 1)
>>> r = run.reward(0)(obs, action, 1)                        # R_i(s, a) of seed 0, jittable

Intentions are the *learned* ones, numbered as the learner numbered them; ``evaluate`` prints
which true intention each one matches. ``across_seeds`` averages every run seed's reward, each
seed's intentions renamed to the asked seed's by the demonstrations they hold
(:meth:`SavedRun.aligned_intentions`; no hidden labels read). The reward to take away, a
refit included: :func:`emgail_jax.reward.load.load_reward`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
from scipy.optimize import linear_sum_assignment

from emgail_jax.host import checkpoints
from emgail_jax.host.final_results import FinalResults
from emgail_jax.host.problem import Problem, problem_of
from emgail_jax.host.results_pipeline import final_responsibilities, kept_intentions
from emgail_jax.host.run_spec import RunError, RunSpec, read_summary
from emgail_jax.host.seed_runner import Runner
from emgail_jax.method import normalizer as obs_norm
from emgail_jax.method.algorithms import Algorithm, make_algorithm
from emgail_jax.method.batches import DemonstrationPairs
from emgail_jax.method.choosing import demonstrations_held
from emgail_jax.method.config import RunConfig
from emgail_jax.method.discriminator import learned_reward
from emgail_jax.method.networks import policy_action
from emgail_jax.method.posterior import (
    Responsibilities,
    own_log_posterior,
)
from emgail_jax.method.training import (
    Networks,
    RunData,
    TrainState,
    clustering_metrics,
    make_networks,
    responsibilities_of,
    seed_state,
)
from emgail_jax.variants import hooks_for, make_train
from emgail_jax.variants.absorbing import absorbing_reward


@dataclasses.dataclass
class SavedRun:
    run_dir: str
    summary: dict
    spec: RunSpec
    problem: Problem
    config: RunConfig  # resolved for the env
    algorithm: Algorithm
    networks: Networks
    state: TrainState  # every seed, leading axis
    history: dict[str, np.ndarray]
    iteration: int
    # The demonstrations as training sees them (no ERD references).
    demonstration_pairs: DemonstrationPairs
    _kept: np.ndarray | None = None  # [seeds, K] the intentions kept, once computed
    snapshot: int | None = None  # the iteration whose learned networks ``state`` holds

    @classmethod
    def open(cls, run_dir: str, snapshot: int | None = None) -> SavedRun:
        """Reads ``summary.json`` and the newest checkpoint, and with ``snapshot`` the learned
        networks of that iteration's snapshot in place of the checkpoint's.

        Raises ``RunError``/``CheckpointError`` (and the env's and demonstrations' errors) with
        one-line messages.
        """
        summary = read_summary(run_dir)
        spec = RunSpec.from_summary(summary)
        problem = problem_of(spec)
        env = problem.env
        config = spec.config.resolved(env)
        # Only `init`'s shapes are needed; ERD's references do not enter them.
        k_true = problem.true_intentions
        pairs = DemonstrationPairs.create(problem.demos, np.full(k_true, np.nan), k_true)
        init, update = make_train(config.method, env)
        runner = Runner(init, update, spec.seeds, RunData.create(pairs, env, config.info_weight))
        target = runner.abstract_state(jax.random.PRNGKey(spec.first_seed))
        state, history, iteration = checkpoints.restore(run_dir, target)
        if snapshot is not None:
            state = checkpoints.restore_snapshot(run_dir, snapshot, state)
        return cls(
            run_dir=run_dir,
            summary=summary,
            spec=spec,
            problem=problem,
            config=config,
            algorithm=make_algorithm(
                config.method.algo, config.info_weight, config.method.reward_form
            ),
            networks=make_networks(config.method, env, hooks_for(config.method)),
            state=state,
            history=history,
            iteration=iteration,
            demonstration_pairs=pairs,
            snapshot=snapshot,
        )

    @property
    def num_intentions(self) -> int:
        return self.problem.env.num_intentions

    def intentions_in_use(self, seed: int = 0) -> np.ndarray | None:
        """``[K]`` bool, the learned intentions ``seed`` keeps when K is chosen from the data
        (``--intentions auto``), decided by all the run's seeds together as training decided
        at its end (:func:`~emgail_jax.host.results_pipeline.kept_intentions`): the run's final
        results say, and for a snapshot (or a summary without them) they are decided anew
        from its state; None when K was given."""
        if not self.config.method.choose_intentions:
            return None
        self.seed_state(seed)  # checks the seed
        if self._kept is None:
            self._kept = self._stored_kept()
        if self._kept is None:
            pairs = self.demonstration_pairs
            responsibilities = final_responsibilities(
                self.networks, self.config.method, self.state, pairs
            )
            self._kept = kept_intentions(responsibilities, self.state.intention_weights, pairs)
        return self._kept[seed]

    def _stored_kept(self) -> np.ndarray | None:
        """``[S, K]`` the intentions kept as the run's final results hold them, when ``state``
        is the final state they were decided on."""
        final = FinalResults.from_summary(self.summary)
        at_end = self.snapshot is None and self.summary.get("iterations_done") == self.iteration
        if final is None or final.intentions_kept is None or not at_end:
            return None
        return np.asarray(final.intentions_kept, bool)

    def seed_number(self, seed: int) -> int:
        """The number ``run --seed`` gave the run's ``seed``-th seed: what every table, file
        and command line calls it (the methods here take the position, 0 .. seeds-1)."""
        return self.spec.first_seed + seed

    def seed_index(self, number: int | None) -> int:
        """The position of the run's seed ``number`` (None: its first seed).

        Raises:
          RunError: the run has no seed of that number (the message says which it has).
        """
        first, count = self.spec.first_seed, self.spec.seeds
        if number is None:
            return 0
        if not first <= number < first + count:
            raise RunError(f"the run has seeds {first}..{first + count - 1}; got seed {number}")
        return number - first

    def seed_state(self, seed: int = 0) -> TrainState:
        """The train state of the run's ``seed``-th seed (0 .. seeds-1)."""
        if not 0 <= seed < self.spec.seeds:
            raise RunError(f"the run has seeds 0..{self.spec.seeds - 1}; got seed {seed}")
        return seed_state(self.state, seed)

    def policy(self, seed: int = 0) -> Callable[[jax.Array, jax.Array], jax.Array]:
        """Deterministic ``pi(obs [..., D], intention [...]) -> action [..., A]`` (raw obs)."""
        state = self.seed_state(seed)
        env, k = self.problem.env, self.num_intentions
        network, algorithm, clip = (
            self.networks.policy,
            self.algorithm,
            self.config.method.networks.obs_clip,
        )

        def policy(obs, intention):
            obs = jnp.asarray(obs, jnp.float32)
            intention = jnp.broadcast_to(jnp.asarray(intention, jnp.int32), obs.shape[:-1])
            condition = algorithm.policy_condition(intention, k)
            mean = policy_action(
                network, state.policy, state.normalizer, obs, condition, obs_clip=clip
            )
            return jnp.clip(mean, env.action_low, env.action_high)

        return policy

    def episodes(self, seed: int, count: int, key: jax.Array, traces: bool = False):
        """Deterministic episodes of every learned intention of ``seed`` in the problem's env:
        ``(returns [K, count, K], alive [T, K, count], trace)`` as
        :func:`~emgail_jax.method.rollout.episodes` gives them."""
        import envs
        from emgail_jax.method.rollout import episodes

        env = envs.EpisodeWrapper(self.problem.env)
        k = self.num_intentions
        policy = self.policy(seed)
        rows = jnp.arange(k)[:, None]
        act = lambda state, _: policy(state.obs, rows)
        run = jax.jit(lambda key: episodes(env, act, key, k, count, traces))
        return jax.device_get(run(key))

    def with_reward_form(self, form: str) -> SavedRun:
        """This run with its discriminator read as the reward ``form`` (``REWARD_FORMS``)."""
        method, weight = self.config.method, self.config.info_weight
        return dataclasses.replace(self, algorithm=make_algorithm(method.algo, weight, form))

    @property
    def trained_with_absorbing_states(self) -> bool:
        """Whether the run's own discriminator learnt termination as an absorbing state."""
        return self.spec.config.method.reward.absorbing_state

    def with_absorbing_states(self) -> SavedRun:
        """This run with a discriminator network that reads the absorbing-state indicator
        (DAC) and a reward that pays its absorbing state
        (:meth:`absorbing_reward_function`): how a refit with absorbing states
        (``--set consolidate_absorbing=true``) is made and read. The run's own discriminator
        weights fit it only if the run trained with absorbing states."""
        if self.config.method.reward.absorbing_state:
            return self
        config = self.config.with_values(absorbing_state=True)
        networks = make_networks(config.method, self.problem.env, hooks_for(config.method))
        return dataclasses.replace(self, config=config, networks=networks)

    def reward(
        self, seed: int = 0, across_seeds: bool = False
    ) -> Callable[[jax.Array, jax.Array, jax.Array], jax.Array]:
        """The learned pseudo-reward ``R_i(obs [..., D], action [..., A], i [...]) -> [...]``:
        -log(1 - D(s, a, i)) for EM-GAIL (eq. 20), plus lambda log P(i | s, a) for
        Info/IntentionGAIL (eq. 23), -log(1 - D(s, a)) for GAIL. The action is clipped to the
        env's range first: the discriminator learned on executed actions. A run trained with
        AIRL's discriminator (``discriminator_form=airl``) gives its state-only reward
        g_i(s) (g(s) for GAIL), the action unread: the reward AIRL claims transfers, not the
        f - log pi its own policies were trained on (which needs s' and the policy).
        ``across_seeds``: the mean of every seed's reward, in ``seed``'s intentions
        (:func:`across_seeds_reward`)."""
        if across_seeds:
            parameters = self.across_seeds_parameters(seed)
            reward = across_seeds_reward(self.reward_function())
        else:
            parameters = self.reward_parameters(seed)
            reward = self.reward_function()
        return lambda obs, action, intention: reward(parameters, obs, action, intention)

    def reward_parameters(self, seed: int = 0) -> dict:
        """What :meth:`reward_function` reads of ``seed``: its discriminator's and posterior's
        parameters and its observation statistics."""
        state = self.seed_state(seed)
        posterior = state.posterior.params if self.algorithm.learns_posterior else None
        return {
            "discriminator": state.discriminator.params,
            "posterior": posterior,
            "normalizer": state.normalizer,
        }

    def aligned_intentions(self, seed: int = 0) -> np.ndarray:
        """``[S, K]``: row t names, for each learned intention i of ``seed``, seed t's
        intention that holds the same demonstrations (the assignment maximising the overlap
        of their responsibilities, gamma_seed^T gamma_t); no hidden labels are read. The
        identity rows without a posterior (GAIL's one reward for every intention)."""
        k, seeds = self.num_intentions, self.spec.seeds
        if not self.algorithm.learns_posterior:
            return np.tile(np.arange(k), (seeds, 1))
        own = np.asarray(self.responsibilities(seed).gamma)  # [N, K]
        rows = []
        for other in range(seeds):
            overlap = own.T @ np.asarray(self.responsibilities(other).gamma)  # [K own, K other]
            mine, theirs = linear_sum_assignment(overlap, maximize=True)
            rows.append(theirs[np.argsort(mine)])
        return np.stack(rows)

    def across_seeds_parameters(self, seed: int = 0) -> dict:
        """What :func:`across_seeds_reward` reads for ``seed``: every seed's
        :meth:`reward_parameters` stacked ``[S, ...]``, and :meth:`aligned_intentions`."""
        every = [self.reward_parameters(other) for other in range(self.spec.seeds)]
        return {
            "seeds": stacked(every),
            "intentions": self.aligned_intentions(seed),
        }

    def reward_function(self) -> Callable:
        """:meth:`reward` as ``R(parameters, obs, action, intention)``, the parameters
        (:meth:`reward_parameters` of a seed) an argument, so that one compiled program
        serves every seed's reward."""
        k, algorithm, clip = (
            self.num_intentions,
            self.algorithm,
            self.config.method.networks.obs_clip,
        )
        networks, env = self.networks, self.problem.env
        if self.config.method.m_step.form.airl:
            return self._airl_reward_function()

        def reward(parameters, obs, action, intention):
            obs = jnp.asarray(obs, jnp.float32)
            action = env.clip_action(jnp.asarray(action, jnp.float32))
            intention = jnp.broadcast_to(jnp.asarray(intention, jnp.int32), obs.shape[:-1])
            normalized = obs_norm.normalize(parameters["normalizer"], obs, clip)
            own = (
                own_log_posterior(
                    networks.posterior.apply, parameters["posterior"], normalized, action, intention
                )
                if algorithm.learns_posterior
                else jnp.zeros(intention.shape)
            )
            return learned_reward(
                networks.discriminator.apply,
                parameters["discriminator"],
                algorithm,
                k,
                obs=normalized,
                executed=action,
                intention=intention,
                own_log_posterior=own,
            )

        return reward

    def _airl_reward_function(self) -> Callable:
        """:meth:`reward_function` of an AIRL run: g_i(s) of the normalised observation."""
        k, algorithm = self.num_intentions, self.algorithm
        network, clip = self.networks.discriminator, self.config.method.networks.obs_clip

        def reward(parameters, obs, action, intention):
            obs = jnp.asarray(obs, jnp.float32)
            intention = jnp.broadcast_to(jnp.asarray(intention, jnp.int32), obs.shape[:-1])
            normalized = obs_norm.normalize(parameters["normalizer"], obs, clip)
            condition = algorithm.discriminator_condition(intention, k)
            return network.apply(
                parameters["discriminator"], normalized, condition, method="reward"
            )

        return reward

    def absorbing_reward_function(self) -> Callable | None:
        """For a run trained with absorbing states, the learned reward of the absorbing state
        a termination leads to as ``R_abs(parameters, intention)`` (the parameters as
        :meth:`reward_function`'s); None otherwise: an episode's end is worth 0."""
        if not self.config.method.reward.absorbing_state:
            return None
        k, algorithm, env = self.num_intentions, self.algorithm, self.problem.env
        apply = self.networks.discriminator.apply

        def reward(parameters, intention):
            sizes = (env.observation_size, env.action_size)
            every = absorbing_reward(apply, parameters["discriminator"], algorithm, k, *sizes)
            return jnp.take(every, intention)

        return reward

    def responsibilities(self, seed: int = 0) -> Responsibilities:
        """The E-step's responsibilities of the run's demonstrations under the posterior of
        ``seed`` (gamma ``[N, K]`` and the pair and trajectory labels), computed as training
        computes them, in the run's ``responsibilities`` mode."""
        if not self.algorithm.learns_posterior:
            raise RunError(f"{self.config.method.algo} learns no posterior")
        state = self.seed_state(seed)
        method = self.config.method
        result = responsibilities_of(
            self.networks, method, state, self.demonstration_pairs, hooks_for(method)
        )
        return jax.device_get(result)

    def demonstrations_held(self, seed: int = 0) -> np.ndarray:
        """``[K]`` how many demonstrations each learned intention of ``seed`` holds (the one
        with the most responsibility over a demonstration's pairs holds it): an intention
        holding none is a collapse to fewer intentions (docs/defaults.md, `reseed`)."""
        pairs = self.demonstration_pairs
        gamma = np.asarray(self.responsibilities(seed).gamma)
        return demonstrations_held(gamma, pairs.episode, pairs.episodes)

    def clustering(self, seed: int = 0) -> dict[str, float]:
        """The clustering accuracies training logs (eq. 29, and in trajectory mode the
        trajectory labels' too) of ``seed``'s current posterior; empty without hidden labels
        or a posterior."""
        if not (self.algorithm.learns_posterior and self.demonstration_pairs.has_labels):
            return {}
        metrics = clustering_metrics(
            self.responsibilities(seed),
            self.demonstration_pairs,
            self.num_intentions,
            self.config.method.e_step.responsibilities,
            self.intentions_in_use(seed),
        )
        return {name.removeprefix("eval/"): float(value) for name, value in metrics.items()}


def load_policy(run_dir: str, seed: int | None = None):
    """The learned policy of a run: jittable ``pi(obs, intention) -> action``; ``seed`` as
    ``run --seed`` numbered it (None: the run's first)."""
    run = SavedRun.open(run_dir)
    return run.policy(run.seed_index(seed))


def stacked(trees: list):
    """The pytrees ``trees`` (of equal structure) as one, a new leading axis on every leaf."""
    return jax.tree.map(lambda *x: np.stack(x), *trees)


def across_seeds_reward(function: Callable) -> Callable:
    """``function(parameters, *inputs, intention)`` (a reward, or the absorbing state's) as
    the mean over the run's seeds: ``parameters`` are :meth:`SavedRun.across_seeds_parameters`,
    seed t's reward read under its own name for each intention. Seeds that trained apart reach
    off the demonstrations in different ways, so the mean pays less where one seed's reward
    alone pays by accident."""

    def mean_reward(parameters, *inputs):
        *rest, intention = inputs
        intention = jnp.asarray(intention, jnp.int32)

        def one_seed(seed_parameters, names):
            return function(seed_parameters, *rest, jnp.take(names, intention))

        every = jax.vmap(one_seed)(parameters["seeds"], parameters["intentions"])
        return every.mean(0)

    return mean_reward
