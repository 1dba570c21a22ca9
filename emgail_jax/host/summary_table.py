"""The table a run prints at its end: its final results per seed."""

from __future__ import annotations

from rich.console import Console
from rich.table import Table

from emgail_jax.host.final_results import FinalResults
from emgail_jax.host.schedule import window_text


def print_summary(summary: dict) -> None:
    """Prints ``summary`` (a run's ``summary.json``): per seed its final ERD, accuracy, true
    returns, and the demonstrations held and K chosen where the run has them."""
    final = FinalResults.from_summary(summary)
    table = Table(
        title=f"{summary['algo']} on {summary['env']} (K={summary['intentions']}), "
        f"mean of {window_text(summary['iterations_done'])} iterations ({summary['status']})"
    )
    for name in ("seed", "norm. ERD", "per intention", "cluster acc."):
        table.add_column(name, justify="right")
    table.add_column("true returns (learned / expert)")
    held, chosen = final.demonstrations_held, final.intentions_chosen
    if held is not None:
        table.add_column("demos held", justify="right")
    if chosen is not None:
        table.add_column("K chosen", justify="right")
    for seed, row in enumerate(_rows(final, summary["intentions"])):
        table.add_row(
            str(summary["first_seed"] + seed),
            *row,
            *([] if held is None else [" ".join(str(n) for n in held[seed])]),
            *([] if chosen is None else [str(chosen[seed])]),
        )
    console = Console()
    console.print(table)
    console.print(
        f"compile {final.compile_time_s:.1f} s, train {final.train_time_s:.1f} s "
        f"({final.iteration_time_s * 1000:.0f} ms per iteration for all seeds)"
    )


def _rows(final: FinalResults, intentions: int) -> list[list[str]]:
    """Each seed's ERD, ERD per intention, accuracy and returns (with the experts'), as text."""
    seeds = final.seeds
    erds = final.erd or [None] * seeds
    per_intention = final.erd_per_intention or [None] * seeds
    accuracy = final.cluster_accuracy or [None] * seeds
    expert = final.expert_returns or [None] * intentions
    number = lambda x: "-" if x is None else f"{x:.3f}"
    rows = []
    for erd, erd_i, acc, returns in zip(erds, per_intention, accuracy, final.returns, strict=True):
        pairs = ", ".join(
            f"{r:.1f}" if e is None else f"{r:.1f}/{e:.1f}"
            for r, e in zip(returns, expert, strict=True)
        )
        erd_text = "-" if erd_i is None else " ".join(f"{e:.2f}" for e in erd_i)
        rows.append([number(erd), erd_text, number(acc), pairs])
    return rows
