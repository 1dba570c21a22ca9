"""The paper's metrics (§5.2): normalised ERD, clustering accuracy and separability.

Learned intentions come in an arbitrary order, so ERD and accuracy both take the best one-to-one
matching of learned to true intentions. Inside ``jit`` the K! matchings are enumerated (K <= 4 here,
at most 24); on the host, :func:`hungarian_accuracy` solves the same assignment with SciPy.
"""

from __future__ import annotations

import itertools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from scipy.optimize import linear_sum_assignment
from sklearn.mixture import GaussianMixture
from sklearn.preprocessing import StandardScaler


def permutations(k: int) -> np.ndarray:
    """``[K!, K]`` every permutation of ``range(k)``."""
    return np.asarray(list(itertools.permutations(range(k))), np.int32)


class ERD(NamedTuple):
    """The normalised ERD of a set of learned intentions (see :func:`normalized_erd`)."""

    mean: jax.Array  # [] the mean over true intentions: the paper's ERD
    per_intention: jax.Array  # [K] e_i of every true intention under the matching
    matching: jax.Array  # [K] learned intention assigned to each true intention


def normalized_erd(returns: jax.Array, expert_returns: jax.Array, random_returns: jax.Array) -> ERD:
    """Normalised expected reward difference (eq. 28): 0 is the expert, 1 random actions.

    Every true intention is normalised on its own,
    ``e_i = |J_i(expert_i) - J_i(learned sigma(i))| / |J_i(expert_i) - J_i(random)|``, and the
    ERD is the mean of the ``e_i`` (eq. 28's expectation over intentions), so an intention whose
    returns are small counts as much as one whose returns are large. ``sigma`` is the one-to-one
    matching of true to learned intentions that minimises that mean.

    Args:
      returns: ``[K_learned, K]`` mean true return of learned intention j under true intention i
        (column i). GAIL's single policy fills every row the same.
      expert_returns: ``[K]`` J_i of the expert of intention i.
      random_returns: ``[K]`` J_i of uniformly random actions.
    """
    k = expert_returns.shape[0]
    perms = jnp.asarray(permutations(k))
    matched = returns[perms, jnp.arange(k)]  # [K!, K] J_i of learned perm[i]
    scale = jnp.abs(expert_returns - random_returns)  # [K]
    per_intention = jnp.abs(expert_returns - matched) / scale  # [K!, K]
    best = jnp.argmin(per_intention.mean(-1))
    return ERD(per_intention[best].mean(), per_intention[best], perms[best])


def confusion_matrix(predicted: jax.Array, labels: jax.Array, k: int) -> jax.Array:
    """``[K, K]`` counts, rows predicted cluster, columns true label."""
    return jnp.zeros((k, k)).at[predicted, labels].add(1.0)


def cluster_accuracy(predicted: jax.Array, labels: jax.Array, k: int) -> jax.Array:
    """Unsupervised clustering accuracy (eq. 29), best one-to-one mapping by enumeration."""
    counts = confusion_matrix(predicted, labels, k)
    perms = jnp.asarray(permutations(k))
    matched = counts[perms, jnp.arange(k)].sum(-1)
    # A product with the reciprocal, written out: XLA turns a division by a constant into one
    # when compiling but not eagerly, and the accuracy must not depend on which ran it.
    return matched.max() * (1.0 / predicted.shape[0])


def hungarian_accuracy(predicted: np.ndarray, labels: np.ndarray, k: int | None = None) -> float:
    """Clustering accuracy with the Hungarian algorithm (host side, any K)."""
    predicted = np.asarray(predicted)
    labels = np.asarray(labels)
    k = k or int(max(predicted.max(), labels.max())) + 1
    counts = np.zeros((k, k))
    np.add.at(counts, (predicted, labels), 1)
    rows, cols = linear_sum_assignment(-counts)
    return float(counts[rows, cols].sum() / len(labels))


def gaussian_mixture_accuracies(
    observations: np.ndarray,
    actions: np.ndarray,
    labels: np.ndarray,
    k: int | None = None,
    seeds: tuple[int, ...] = (0, 1, 2, 3, 4),
) -> np.ndarray:
    """``[len(seeds)]`` clustering accuracy of a K-component Gaussian mixture on expert pairs.

    The pairs are standardised per dimension (observations and actions live on different
    scales) and a full-covariance mixture is fitted once per seed: the paper's GMM baseline
    (Table 3) and the basis of its separability.
    """
    labels = np.asarray(labels)
    k = k or int(labels.max()) + 1
    pairs = np.concatenate([observations, actions], 1).astype(np.float64)
    pairs = StandardScaler().fit_transform(pairs)
    return np.asarray(
        [
            hungarian_accuracy(
                GaussianMixture(k, covariance_type="full", random_state=seed)
                .fit(pairs)
                .predict(pairs),
                labels,
                k,
            )
            for seed in seeds
        ]
    )


def separability(
    observations: np.ndarray,
    actions: np.ndarray,
    labels: np.ndarray,
    k: int | None = None,
    seeds: tuple[int, ...] = (0, 1, 2, 3, 4),
) -> tuple[float, float]:
    """How well a Gaussian mixture separates the intentions of expert pairs: its clustering
    accuracy (:func:`gaussian_mixture_accuracies`) normalised so that chance (1/K) is 0 and
    perfect is 1. Returns ``(mean, std)`` over the mixture seeds.
    """
    k = k or int(np.max(labels)) + 1
    scores = separability_of(
        gaussian_mixture_accuracies(observations, actions, labels, k, seeds), k
    )
    return float(np.mean(scores)), float(np.std(scores))


def separability_of(accuracies: np.ndarray, k: int) -> np.ndarray:
    """Clustering accuracies of K intentions rescaled so that chance (1/K) is 0, perfect 1."""
    return (np.asarray(accuracies) - 1.0 / k) / (1.0 - 1.0 / k)
