"""The one path from what a run leaves to its final results.

:func:`final_results` turns a run's metric history ``[S, L, ...]``, every seed's final train
state and its timings into a :class:`~emgail_jax.host.final_results.FinalResults`: the means
over the last :data:`~emgail_jax.host.schedule.FINAL_WINDOW` evaluations, and from the final
state's E-step (one compiled call for all seeds) the demonstrations each learned intention
holds and, when K is chosen from the data, the intentions the seeds together keep, with the
ERD of the last evaluations matched to them and the accuracies of the kept intentions. What
the compiled update logged is read, not computed again: only the seeds' consensus on K, which
no single seed's update can reach, is new on the host.
"""

from __future__ import annotations

import dataclasses

import jax
import numpy as np

from emgail_jax.host.final_results import FinalResults
from emgail_jax.host.history import final_means
from emgail_jax.host.schedule import last_measured
from emgail_jax.method.choosing import chosen_intentions, demonstrations_held
from emgail_jax.method.config import ResponsibilityMode
from emgail_jax.method.metrics import normalized_erd
from emgail_jax.method.posterior import Responsibilities
from emgail_jax.method.training import (
    clustering_metrics,
    evaluation_phases,
    make_networks,
    responsibilities_of,
)
from emgail_jax.variants import hooks_for


def final_results(
    history: dict[str, np.ndarray],
    *,
    problem,
    config,
    states,
    demos,
    timings: dict,
) -> FinalResults:
    """A run's final results from its ``history`` (``{name: [S, L, ...]}``), every seed's
    final train ``states`` (host arrays, leading axis seed; unused for GAIL), the
    demonstrations as training saw them (``demos``, a ``DemonstrationPairs``), the resolved
    ``config`` and the run's ``timings`` (``compile_time_s``, ``train_time_s``,
    ``iterations``)."""
    method = config.method
    means = final_means(history)
    no_accuracy = not method.algo.learns_posterior or problem.demos.intentions is None
    no_erd = problem.demos.expert_returns is None
    accuracy = lambda name: None if no_accuracy else means[name]
    trajectory = "eval/trajectory_cluster_accuracy" in means
    results = FinalResults(
        erd=None if no_erd else means["eval/erd"],
        erd_per_intention=None if no_erd else means["eval/erd_per_intention"],
        cluster_accuracy=accuracy("eval/cluster_accuracy"),
        returns=means["eval/returns"],
        expert_returns=problem.demos.expert_returns,
        random_returns=problem.random_returns,
        compile_time_s=timings["compile_time_s"],
        train_time_s=timings["train_time_s"],
        iteration_time_s=timings["train_time_s"] / max(timings["iterations"], 1),
        env_steps=env_steps(history, problem.env, method),
        intention_weights=means.get("posterior/intention_weights"),
        intentions_held=_rounded(means.get("posterior/intentions_in_use")),
        reseedings=_last(history.get("reseed/reseedings")),
        trajectory_cluster_accuracy=accuracy("eval/trajectory_cluster_accuracy")
        if trajectory
        else None,
        trajectory_labels=trajectory,
    )
    if not method.algo.learns_posterior:  # no E-step to read
        return results
    networks = make_networks(method, problem.env, hooks_for(method))
    responsibilities = final_responsibilities(networks, method, states, demos)
    gamma = np.asarray(responsibilities.gamma)  # [S, N, K]
    held = np.stack([demonstrations_held(g, demos.episode, demos.episodes) for g in gamma])
    results = dataclasses.replace(results, demonstrations_held=held)
    if not method.choose_intentions:
        return results
    kept = kept_intentions(responsibilities, states.intention_weights, demos)
    chosen = {"intentions_kept": kept, "intentions_chosen": kept.sum(1)}
    if problem.demos.expert_returns is not None:
        chosen.update(matched_again(history, kept, demos))
    if demos.has_labels:
        chosen.update(
            kept_clustering(responsibilities, kept, demos, method.e_step.responsibilities)
        )
    return dataclasses.replace(results, **chosen)


def kept_intentions(responsibilities: Responsibilities, weights, demos) -> np.ndarray:
    """``[S, M]`` bool: the intentions each seed keeps when K is chosen from the data, decided
    by the seeds together from their final E-step (``responsibilities``, leaves ``[S, ...]``)
    and mixture ``weights [S, M]``
    (:func:`~emgail_jax.method.choosing.chosen_intentions`)."""
    gamma = np.asarray(responsibilities.gamma)
    return chosen_intentions(gamma, np.asarray(weights), demos.episode, demos.episodes)


def env_steps(history: dict[str, np.ndarray], env, config) -> int:
    """Env steps of every seed's rollouts and evaluation episodes over the ``history``
    (``config``: the run's resolved method config)."""
    returns = history["eval/returns"]
    seeds, iterations = returns.shape[:2]
    evaluated = int(np.sum(~np.isnan(returns[0, :, 0])))
    per_rollout = config.rollout.num_envs * config.rollout.rollout_length  # per intention
    eval_steps = per_rollout * evaluation_phases(config, env)  # per intention and evaluation
    return env.num_intentions * (per_rollout * iterations + eval_steps * evaluated) * seeds


def final_responsibilities(networks, config, states, demos) -> Responsibilities:
    """The E-step's responsibilities of ``demos`` under every seed's final state (``states``,
    leading axis seed) and the method ``config``, as training computes them: one compiled call
    vmapped over the seeds; every leaf ``[S, ...]``."""
    hooks = hooks_for(config)
    of_seed = lambda state: responsibilities_of(networks, config, state, demos, hooks)
    return jax.device_get(jax.jit(jax.vmap(of_seed))(states))


def kept_clustering(
    responsibilities: Responsibilities, kept: np.ndarray, demos, mode: ResponsibilityMode
) -> dict[str, np.ndarray]:
    """``{cluster_accuracy, trajectory_cluster_accuracy}`` ``[S]`` of every seed's final E-step
    (``responsibilities``, leaves ``[S, ...]``, in E-step ``mode``) when only the intentions
    ``kept [S, M]`` are: a retired intention's demonstrations go to the kept one the posterior
    ranks next."""
    of_seed = lambda r, in_use: clustering_metrics(r, demos, kept.shape[1], mode, in_use)
    clustering = jax.vmap(of_seed)(responsibilities, kept)
    return {
        name.removeprefix("eval/"): np.asarray([float(v) for v in values])
        for name, values in clustering.items()
    }


def matched_again(history: dict[str, np.ndarray], kept: np.ndarray, demos) -> dict:
    """``erd [S]``, ``erd_per_intention [S, K]`` and ``returns [S, K]``: the means over each
    seed's last evaluations of the ERD matched to the intentions it keeps (``kept [S, M]``),
    from every learned intention's returns the compiled update logged
    (``eval/learned_returns``, flattened ``[S, L, M * K]``)."""
    seeds, m = kept.shape
    k = demos.true_intentions
    returns = history["eval/learned_returns"]
    returns = returns.reshape(*returns.shape[:2], m, k)  # [S, L, M learned, K true]
    windows = [last_measured(~np.isnan(returns[seed, :, 0, 0])) for seed in range(seeds)]
    seed_of = np.concatenate([np.full(len(w), seed) for seed, w in enumerate(windows)])
    evaluated = returns[seed_of, np.concatenate(windows)]  # [P, M, K]: every seed's window
    erd = jax.vmap(normalized_erd, in_axes=(0, None, None, 0))(
        evaluated, demos.expert_returns, demos.random_returns, kept[seed_of]
    )
    means, per_intention = np.asarray(erd.mean), np.asarray(erd.per_intention)
    matching = np.asarray(erd.matching)
    matched = evaluated[np.arange(len(seed_of))[:, None], matching, np.arange(k)]  # [P, K]
    rows = [seed_of == seed for seed in range(seeds)]
    return {
        "erd": np.stack([np.mean(means[row].astype(np.float64)) for row in rows]),
        "erd_per_intention": np.stack([np.mean(per_intention[row], 0) for row in rows]),
        "returns": np.stack([np.mean(matched[row], 0) for row in rows]),
    }


def _rounded(values: np.ndarray | None) -> np.ndarray | None:
    return None if values is None else np.rint(values).astype(int)


def _last(values: np.ndarray | None) -> np.ndarray | None:
    """``[S]`` a count's value at the last iteration (the re-seedings so far)."""
    return None if values is None else values[:, -1].astype(int)
