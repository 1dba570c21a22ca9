"""Choosing K from the data (``--intentions auto``): which of the M learned intentions a run keeps.

Training starts with M intentions and the mixture prior, and nothing is ever deleted: this
module only decides which intentions the run reports, from what it learned (no label, no true
reward), in two steps (docs/choosing-k.md):

1. every iteration, per seed (:func:`holds_demonstrations`, inside the compiled update): an
   intention is kept while its mixture weight holds at least half a demonstration's share. The
   trajectory E-step hands each demonstration over whole, so a weight is about a multiple of
   one demonstration's share, and an intention that explains none sits at the weight floor;
2. at the end, over the seeds together (:func:`consensus_intentions`, on the host): surplus
   intentions can split one true intention's demonstrations between them (the reacher's balls),
   and each duplicate's policy, posterior and reward specialise on its share, so no single
   seed's model tells a duplicate from a distinct intention. But each seed splits differently,
   while distinct intentions' demonstrations stay apart in every seed: the groups of
   demonstrations the seeds agree on are the intentions, and in each seed the intention holding
   most of a group is kept, its duplicates retired.

A retired intention's demonstrations count for the kept intention the posterior ranks next
(:meth:`~emgail_jax.method.posterior.Responsibilities.kept_only`).
"""

from __future__ import annotations

import jax
import numpy as np
from scipy.cluster.hierarchy import fcluster, linkage
from scipy.spatial.distance import squareform


def kept_share(episodes: int) -> float:
    """The weight an intention must hold to be kept: half a demonstration's share."""
    return 0.5 / episodes


def holds_demonstrations(weights: jax.Array, episodes: int) -> jax.Array:
    """``[K]`` bool: the intentions whose mixture weight ``weights [K]`` holds at least half a
    demonstration's share of the pairs (``1 / (2 episodes)``, for demonstrations of equal
    length)."""
    return weights >= kept_share(episodes)


def agreed_groups(labels: np.ndarray, intentions: int) -> np.ndarray:
    """``[E]`` the group of each demonstration the seeds agree on, from each seed's intention of
    each demonstration ``labels [S, E]`` (of ``intentions`` learned ones).

    Two demonstrations' agreement is the share of seeds that give them one intention. Groups
    are merged by average linkage while their mean agreement is above ``1 / intentions``. With
    K >= 2 true intentions a seed can spread one over at most M - 1 of its M intentions, so
    its demonstrations agree at least 1 / (M - 1) on average; those of distinct intentions
    agree only as often as seeds put them together, e.g. 1/4 when one seed of four merges two,
    which stays two.
    """
    episodes = labels.shape[1]
    if episodes < 2:
        return np.zeros(episodes, int)
    together = (labels[:, :, None] == labels[:, None, :]).mean(0)  # [E, E]
    tree = linkage(squareform(1.0 - together, checks=False), "average")
    # Merging goes on while the distance, 1 - agreement, is below 1 - 1/M (strictly).
    below = np.nextafter(1.0 - 1.0 / intentions, 0.0)
    return fcluster(tree, t=below, criterion="distance") - 1


def consensus_intentions(labels: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """``[S, K]`` bool: the intentions each seed keeps: for every group of
    :func:`agreed_groups`, the intention that holds most of its demonstrations (ties: the
    heavier); ``labels [S, E]`` each seed's intention of each demonstration (among those it
    keeps by weight), ``weights [S, K]`` the mixture weights. With one seed there is nothing to
    agree on, and every intention holding a demonstration is kept."""
    seeds, k = weights.shape
    groups = agreed_groups(labels, k) if seeds > 1 else labels[0]
    kept = np.zeros((seeds, k), bool)
    for seed in range(seeds):
        for group in np.unique(groups):
            held = np.bincount(labels[seed, groups == group], minlength=k)
            # Most demonstrations first, then the heavier intention.
            kept[seed, np.lexsort((-weights[seed], -held))[0]] = True
    return kept


def demonstration_intentions(
    gamma: np.ndarray, episode: np.ndarray, episodes: int, held: np.ndarray
) -> np.ndarray:
    """``[E]`` the intention of each demonstration among those ``held [K]``: the one with the
    most responsibility over its pairs (``gamma [N, K]``, ``episode [N]``); in the trajectory
    E-step, the one its pairs all share."""
    per_demonstration = np.zeros((episodes, gamma.shape[-1]))
    np.add.at(per_demonstration, np.asarray(episode), np.asarray(gamma))
    return np.argmax(np.where(held, per_demonstration, -1.0), -1)


def demonstrations_held(gamma: np.ndarray, episode: np.ndarray, episodes: int) -> np.ndarray:
    """``[K]`` how many demonstrations each intention holds: those it has the most
    responsibility for over their pairs (``gamma [N, K]``, ``episode [N]``)."""
    k = gamma.shape[-1]
    labels = demonstration_intentions(gamma, episode, episodes, np.ones(k, bool))
    return np.bincount(labels, minlength=k)


def chosen_intentions(
    gamma: np.ndarray, weights: np.ndarray, episode: np.ndarray, episodes: int
) -> np.ndarray:
    """``[S, K]`` bool: the intentions each seed keeps at the end of a run, from every seed's
    responsibilities of the expert pairs ``gamma [S, N, K]`` and mixture weights
    ``weights [S, K]``: those holding demonstrations by their weights, then the seeds'
    consensus on the intention of each demonstration (``episode [N]``)."""
    labels = [
        demonstration_intentions(g, episode, episodes, holds_demonstrations(w, episodes))
        for g, w in zip(gamma, weights, strict=True)
    ]
    return consensus_intentions(np.stack(labels), weights)
