"""One progress bar for every long step (training, re-optimising, experts, demonstrations)."""

from __future__ import annotations

import time


class ProgressBar:
    """A rich bar with a label, ``done/total``, named fields (e.g. ``ERD 0.04``), it/s and ETA.

    ``fields`` maps a shown name to its initial text; :meth:`update` replaces their texts.
    A disabled bar does nothing, so callers need no ``if``.
    """

    def __init__(
        self,
        label: str,
        total: int,
        fields: dict[str, str] | None = None,
        completed: int = 0,
        enabled: bool = True,
    ):
        self.enabled = enabled
        self.fields = dict(fields or {})
        if not enabled:
            return
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        shown = "  ".join(f"{name} {{task.fields[f{i}]}}" for i, name in enumerate(self.fields))
        self.progress = Progress(
            TextColumn(f"[bold]{label}"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn(shown + "  {task.fields[speed]}"),
            TimeElapsedColumn(),
            TextColumn("ETA"),
            TimeRemainingColumn(),
        )
        self.progress.start()
        texts = {f"f{i}": text for i, text in enumerate(self.fields.values())}
        self.task = self.progress.add_task(
            label, total=total, completed=completed, speed="", **texts
        )
        self.start = time.perf_counter()
        self.done = 0

    def update(self, advance: int, **fields: str) -> None:
        if not self.enabled:
            return
        self.done += advance
        names = list(self.fields)
        texts = {f"f{names.index(name)}": text for name, text in fields.items()}
        speed = self.done / max(time.perf_counter() - self.start, 1e-9)
        self.progress.update(self.task, advance=advance, speed=f"{speed:.2f} it/s", **texts)

    def close(self) -> None:
        if self.enabled:
            self.progress.stop()

    def __enter__(self) -> ProgressBar:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
