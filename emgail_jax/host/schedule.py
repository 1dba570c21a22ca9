"""When a run evaluates, and which iterations its final numbers average.

The final numbers of a run are means over its last :data:`FINAL_WINDOW` evaluated iterations
(a single evaluation's ERD is noisy). The evaluation schedule therefore evaluates each of the
last ``FINAL_WINDOW`` iterations besides every ``eval_every``-th, and :func:`last_measured` is
the one place that picks those iterations out of a history.
"""

from __future__ import annotations

import numpy as np

FINAL_WINDOW = 10


def evaluation_plan(first: int, length: int, total: int, every: int) -> np.ndarray:
    """``[length]`` whether iterations ``first + 1 .. first + length`` (of ``total``) run the
    evaluation episodes: every ``every``-th iteration and each of the last
    :data:`FINAL_WINDOW`, so that the final metrics always average evaluated iterations."""
    numbers = np.arange(first + 1, first + length + 1)
    return (numbers % every == 0) | (numbers > total - FINAL_WINDOW)


def last_measured(measured: np.ndarray, last: int = FINAL_WINDOW) -> np.ndarray:
    """The indices of the last ``last`` iterations of ``measured [L]`` (bool) that were
    measured (an iteration without evaluation logs NaN), oldest first."""
    return np.flatnonzero(measured)[-last:]


def measured_iterations(values: np.ndarray) -> np.ndarray:
    """``[S, L]`` whether a metric ``values [S, L, ...]`` was measured at each iteration of
    each seed: some entry of it is not NaN."""
    values = np.asarray(values)
    return ~np.all(np.isnan(values.reshape(*values.shape[:2], -1)), -1)


def window_text(done: int, last: int = FINAL_WINDOW) -> str:
    """The iterations a final mean covers, in words: "the last 10 of 400" or "all 7"."""
    return f"the last {last} of {done}" if done > last else f"all {done}"
