"""A run's metric history on the host: ``{name: [S, L, ...]}``, chunk after chunk, and its
final means."""

from __future__ import annotations

import numpy as np

from emgail_jax.host.schedule import FINAL_WINDOW, last_measured, measured_iterations


def concat_history(history: dict | None, metrics: dict[str, np.ndarray]) -> dict:
    """``history`` with a chunk's ``metrics [S, L, ...]`` appended along the iterations."""
    if history is None:
        return dict(metrics)
    return {k: np.concatenate([history[k], metrics[k]], axis=1) for k in history}


def final_means(history: dict[str, np.ndarray], last: int = FINAL_WINDOW) -> dict[str, np.ndarray]:
    """Per-seed means over the last ``last`` iterations in which a metric was measured (an
    iteration without evaluation logs NaN; NaN where none was); ``{name: [S, ...]}``."""
    final = {}
    for name, values in history.items():
        values = np.asarray(values, np.float64)
        per_seed = []
        for seed_values, seed_measured in zip(values, measured_iterations(values), strict=True):
            chosen = seed_values[last_measured(seed_measured, last)]
            empty = np.full(values.shape[2:], np.nan)
            per_seed.append(chosen.mean(0) if len(chosen) else empty)
        final[name] = np.stack(per_seed)
    return final
