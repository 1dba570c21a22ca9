"""A run's final results, typed, and their one reader.

:func:`~emgail_jax.host.results_pipeline.final_results` makes a :class:`FinalResults` at the
end of a run; ``summary.json``'s ``"final"`` is its :meth:`~FinalResults.to_summary`, and the
run's table, ``evaluate`` and the sweep read it back with :func:`read_final` (or
:meth:`FinalResults.from_summary`), which reads the summaries of earlier versions too (a field
they lack is None). Imports no JAX: a report of finished runs starts none.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from emgail_jax.host.run_spec import read_summary

PerSeed = Sequence | np.ndarray  # a value per seed (leading axis); JSON lists when read back


@dataclasses.dataclass(frozen=True)
class FinalResults:
    """The final numbers of a run, per seed (``summary.json``'s ``"final"``; README,
    "Running"): numpy arrays as :func:`~emgail_jax.host.results_pipeline.final_results` makes
    them, JSON values (lists, ``None`` for a NaN) as read back from a summary. A field None is
    not measured by the run: it is left out of the summary, except the first four, which are
    written as null."""

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
