"""A run's final results: one pipeline from its history and final state, and one reader.

:func:`final_results` turns what a run leaves (the metric history ``[S, L, ...]``, every seed's
final train state, its timings) into a :class:`FinalResults`: the means over the last
:data:`~emgail_jax.host.schedule.FINAL_WINDOW` evaluations (:mod:`emgail_jax.host.schedule`),
and, from the final state's E-step (one compiled call for all seeds), the demonstrations each
learned intention holds and, when K is chosen from the data, the intentions kept with the ERD
of the last evaluations matched to them. ``summary.json``'s ``"final"`` is
:meth:`FinalResults.to_summary`; the run's table, ``evaluate`` and the sweep read it back with
:func:`read_final` (or :meth:`FinalResults.from_summary`), which also reads the summaries of
earlier versions (a field they lack is None).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import jax
import numpy as np

from emgail_jax.host.history import final_means
from emgail_jax.host.run_spec import read_summary
from emgail_jax.host.schedule import last_measured
from emgail_jax.method.choosing import chosen_intentions, demonstrations_held
from emgail_jax.method.metrics import normalized_erd
from emgail_jax.method.posterior import Responsibilities
from emgail_jax.method.training import (
    clustering_metrics,
    evaluation_phases,
    make_networks,
    responsibilities_of,
)

PerSeed = Sequence | np.ndarray  # a value per seed (leading axis); JSON lists when read back


@dataclasses.dataclass(frozen=True)
class FinalResults:
    """The final numbers of a run, per seed (``summary.json``'s ``"final"``; README,
    "Running"). Produced by :func:`final_results` as numpy arrays; read back from a summary as
    its JSON values (lists, ``None`` for a NaN). A field None is not measured by the run: it is
    left out of the summary, except the first four, which are written as null."""

    erd: PerSeed | None  # [S]; None without the experts' returns
    erd_per_intention: PerSeed | None  # [S, K true]
    cluster_accuracy: PerSeed | None  # [S] eq. 29; None for GAIL or without hidden labels
    expert_returns: PerSeed | None  # [K true]
    returns: PerSeed  # [S, K true] true returns of the matched learned intentions
    random_returns: PerSeed  # [K true]
    compile_time_s: float
    train_time_s: float
    iteration_time_s: float
    env_steps: int
    intention_weights: PerSeed | None = None  # [S, K] the mixture prior
    intentions_held: PerSeed | None = None  # [S] by the weights alone (--intentions auto)
    reseedings: PerSeed | None = None  # [S] re-seedings of emptied intentions
    trajectory_cluster_accuracy: PerSeed | None = None  # [S] the M-step's labels
    demonstrations_held: PerSeed | None = None  # [S, K] under the final E-step
    intentions_kept: PerSeed | None = None  # [S, K] bool (--intentions auto)
    intentions_chosen: PerSeed | None = None  # [S] (--intentions auto)
    # Whether the E-step labels whole demonstrations: then the summary reports
    # trajectory_cluster_accuracy, null without hidden labels.
    trajectory_labels: bool = False

    def to_summary(self) -> dict[str, Any]:
        """``summary.json``'s ``"final"``, its keys in the order runs have written them."""
        always = {"erd", "erd_per_intention", "cluster_accuracy", "expert_returns"}
        if self.trajectory_labels:
            always.add("trajectory_cluster_accuracy")
        final = {}
        for name in _SUMMARY_ORDER:
            value = getattr(self, name)
            if value is not None or name in always:
                final[name] = value
        return final

    @classmethod
    def from_summary(cls, summary: dict) -> FinalResults | None:
        """The final results a ``summary.json`` holds; None before the run has them."""
        final = summary.get("final")
        if not isinstance(final, dict):
            return None
        known = {name: final[name] for name in _SUMMARY_ORDER if name in final}
        return cls(**known, trajectory_labels="trajectory_cluster_accuracy" in final)

    @property
    def seeds(self) -> int:
        return len(self.returns)


_SUMMARY_ORDER = (
    "erd",
    "erd_per_intention",
    "cluster_accuracy",
    "returns",
    "expert_returns",
    "random_returns",
    "compile_time_s",
    "train_time_s",
    "iteration_time_s",
    "env_steps",
    "intention_weights",
    "intentions_held",
    "reseedings",
    "trajectory_cluster_accuracy",
    "demonstrations_held",
    "intentions_kept",
    "intentions_chosen",
)


def read_final(run_dir: str) -> FinalResults | None:
    """The final results of the run in ``run_dir`` (None while it has none); raises
    :class:`~emgail_jax.host.run_spec.RunError` for a directory without a readable
    ``summary.json``."""
    return FinalResults.from_summary(read_summary(run_dir))


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
    means = final_means(history)
    no_accuracy = config.algo == "gail" or problem.demos.intentions is None
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
        env_steps=env_steps(history, problem.env, config),
        intention_weights=means.get("posterior/intention_weights"),
        intentions_held=_rounded(means.get("posterior/intentions_in_use")),
        reseedings=_last(history.get("reseed/reseedings")),
        trajectory_cluster_accuracy=accuracy("eval/trajectory_cluster_accuracy")
        if trajectory
        else None,
        trajectory_labels=trajectory,
    )
    if config.algo == "gail":  # no posterior: no E-step to read
        return results
    networks = make_networks(config, problem.env)
    responsibilities = final_responsibilities(networks, config, states, demos)
    gamma = np.asarray(responsibilities.gamma)  # [S, N, K]
    held = np.stack([demonstrations_held(g, demos.episode, demos.episodes) for g in gamma])
    results = dataclasses.replace(results, demonstrations_held=held)
    if not config.choose_intentions:
        return results
    kept = kept_intentions(responsibilities, states.intention_weights, demos)
    chosen = {"intentions_kept": kept, "intentions_chosen": kept.sum(1)}
    if problem.demos.expert_returns is not None:
        chosen.update(matched_again(history, kept, demos))
    if demos.has_labels:
        chosen.update(kept_clustering(responsibilities, kept, demos, config.responsibilities))
    return dataclasses.replace(results, **chosen)


def kept_intentions(responsibilities: Responsibilities, weights, demos) -> np.ndarray:
    """``[S, M]`` bool: the intentions each seed keeps when K is chosen from the data, decided
    by the seeds together from their final E-step (``responsibilities``, leaves ``[S, ...]``)
    and mixture ``weights [S, M]``
    (:func:`~emgail_jax.method.choosing.chosen_intentions`)."""
    gamma = np.asarray(responsibilities.gamma)
    return chosen_intentions(gamma, np.asarray(weights), demos.episode, demos.episodes)


def env_steps(history: dict[str, np.ndarray], env, config) -> int:
    """Env steps of every seed's rollouts and evaluation episodes over the ``history``."""
    returns = history["eval/returns"]
    seeds, iterations = returns.shape[:2]
    evaluated = int(np.sum(~np.isnan(returns[0, :, 0])))
    per_rollout = config.num_envs * config.rollout_length  # per intention
    eval_steps = per_rollout * evaluation_phases(config, env)  # per intention and evaluation
    return env.num_intentions * (per_rollout * iterations + eval_steps * evaluated) * seeds


def final_responsibilities(networks, config, states, demos) -> Responsibilities:
    """The E-step's responsibilities of ``demos`` under every seed's final state (``states``,
    leading axis seed), as training computes them: one compiled call vmapped over the seeds;
    every leaf ``[S, ...]``."""
    of_seed = lambda state: responsibilities_of(networks, config, state, demos)
    return jax.device_get(jax.jit(jax.vmap(of_seed))(states))


def kept_clustering(
    responsibilities: Responsibilities, kept: np.ndarray, demos, mode: str
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
