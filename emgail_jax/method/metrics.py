"""The paper's metrics (§5.2): normalised ERD, clustering accuracy and separability.

Learned intentions come in an arbitrary order, so ERD and accuracy both take the best one-to-one
matching of true to learned intentions. Inside ``jit`` the matchings are enumerated (K <= 4 here,
at most 24); on the host, :func:`hungarian_accuracy` solves the same assignment with SciPy.

More intentions may be learned than the demonstrations hold (``--intentions auto`` starts from
the env's maximum and keeps those in use): every true intention is matched to a distinct learned
one in use; the learned ones left over are unmatched, and a true intention that finds none in
use is scored as random actions (e = 1; its pairs count as misclustered).
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


def matchings(k_learned: int, k_true: int) -> np.ndarray:
    """``[M, K_true]`` every one-to-one matching of true intentions (columns) to distinct learned
    ones (entries), ``K_true <= K_learned``; the permutations when the two are equal."""
    return np.asarray(list(itertools.permutations(range(k_learned), k_true)), np.int32)


class ERD(NamedTuple):
    """The normalised ERD of a set of learned intentions (see :func:`normalized_erd`)."""

    mean: jax.Array  # [] the mean over true intentions: the paper's ERD
    per_intention: jax.Array  # [K] e_i of every true intention under the matching
    matching: jax.Array  # [K] learned intention assigned to each true intention


def reward_difference(matched_returns, expert_returns, random_returns):
    """``[..., K]`` eq. 28's ``e_i = |J_i(expert_i) - J_i(learned)| / |J_i(expert_i) -
    J_i(random)|`` of the learned returns ``matched_returns [..., K]`` under their true
    intention (0 is the expert, 1 random actions), of numpy or JAX arrays alike."""
    return abs(expert_returns - matched_returns) / abs(expert_returns - random_returns)


def normalized_erd(
    returns: jax.Array,
    expert_returns: jax.Array,
    random_returns: jax.Array,
    in_use: jax.Array | None = None,
) -> ERD:
    """Normalised expected reward difference (eq. 28): 0 is the expert, 1 random actions.

    Every true intention is normalised on its own,
    ``e_i = |J_i(expert_i) - J_i(learned sigma(i))| / |J_i(expert_i) - J_i(random)|``, and the
    ERD is the mean of the ``e_i`` (eq. 28's expectation over intentions), so an intention whose
    returns are small counts as much as one whose returns are large. ``sigma`` is the one-to-one
    matching of true to learned intentions that minimises that mean, among those that match the
    most true intentions to learned ones in use; one matched to a learned intention not in use
    scores e = 1, as random actions would.

    Args:
      returns: ``[K_learned, K_env]`` mean true return of learned intention j under the env's
        intention i (column i; the first ``K`` are the true ones). GAIL's single policy fills
        every row the same.
      expert_returns: ``[K]`` J_i of the expert of intention i.
      random_returns: ``[K]`` J_i of uniformly random actions.
      in_use: ``[K_learned]`` bool, the learned intentions kept (None: all).
    """
    k_learned, k = returns.shape[0], expert_returns.shape[0]
    maps = jnp.asarray(matchings(k_learned, k))  # [M, K]
    matched = returns[maps, jnp.arange(k)]  # [M, K] J_i of learned sigma(i)
    per_intention = reward_difference(matched, expert_returns, random_returns)  # [M, K]
    if in_use is not None:
        used = in_use[maps]  # [M, K]
        per_intention = jnp.where(used, per_intention, 1.0)
        unmatched = jnp.sum(~used, -1)
        mean = jnp.where(unmatched == unmatched.min(), per_intention.mean(-1), jnp.inf)
    else:
        mean = per_intention.mean(-1)
    best = jnp.argmin(mean)
    return ERD(per_intention[best].mean(), per_intention[best], maps[best])


def confusion_matrix(predicted: jax.Array, labels: jax.Array, k: int, k_true: int | None = None):
    """``[K, K_true]`` counts, rows predicted cluster, columns true label."""
    return jnp.zeros((k, k_true or k)).at[predicted, labels].add(1.0)


def cluster_accuracy(
    predicted: jax.Array,
    labels: jax.Array,
    k: int,
    k_true: int | None = None,
    in_use: jax.Array | None = None,
) -> jax.Array:
    """Unsupervised clustering accuracy (eq. 29), best one-to-one mapping by enumeration.

    ``k`` learned clusters, ``k_true`` true intentions (``<= k``; default ``k``); pairs put in
    a cluster not ``in_use`` ``[K]`` (or one left unmatched) count as misclustered.
    """
    k_true = k_true or k
    counts = confusion_matrix(predicted, labels, k, k_true)
    if in_use is not None:
        counts = counts * in_use[:, None]
    maps = jnp.asarray(matchings(k, k_true))
    matched = counts[maps, jnp.arange(k_true)].sum(-1)
    # A product with the reciprocal, written out: XLA turns a division by a constant into one
    # when compiling but not eagerly, and the accuracy must not depend on which ran it.
    return matched.max() * (1.0 / predicted.shape[0])


def hungarian_accuracy(predicted: np.ndarray, labels: np.ndarray, k: int | None = None) -> float:
    """Clustering accuracy with the Hungarian algorithm (host side, any K)."""
    predicted = np.asarray(predicted)
    labels = np.asarray(labels)
    k = k or int(max(predicted.max(), labels.max())) + 1
    counts = np.zeros((max(k, int(predicted.max()) + 1), max(k, int(labels.max()) + 1)))
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
    observations: np.ndarray, actions: np.ndarray, labels: np.ndarray, **mixture
) -> tuple[float, float]:
    """How well a Gaussian mixture separates the intentions of expert pairs: its clustering
    accuracy (:func:`gaussian_mixture_accuracies`, which takes ``mixture``'s ``k`` and
    ``seeds``) normalised so that chance (1/K) is 0 and perfect is 1. Returns ``(mean, std)``
    over the mixture seeds.
    """
    k = mixture.pop("k", None) or int(np.max(labels)) + 1
    accuracies = gaussian_mixture_accuracies(observations, actions, labels, k, **mixture)
    scores = separability_of(accuracies, k)
    return float(np.mean(scores)), float(np.std(scores))


def separability_of(accuracies: np.ndarray, k: int) -> np.ndarray:
    """Clustering accuracies of K intentions rescaled so that chance (1/K) is 0, perfect 1."""
    return (np.asarray(accuracies) - 1.0 / k) / (1.0 - 1.0 / k)
