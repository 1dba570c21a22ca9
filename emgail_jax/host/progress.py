"""One progress bar for every long step (training, re-optimising, experts, demonstrations)."""

from __future__ import annotations

import time


class ProgressBar:
    """A rich bar with a label, ``done/total``, named fields (e.g. ``ERD 0.04``), it/s and ETA.

    ``fields`` maps a shown name to its initial text; :meth:`update` replaces their texts.
    A disabled bar does nothing, so callers need no ``if``. Where the output is not a terminal
    (a log file, CI), a plain line is printed every ``log_every_s`` seconds instead.
    """

    log_every_s = 30.0

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
        self.live = self.progress.console.is_terminal
        self.label, self.total, self.logged = label, total, -float("inf")
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
        self.fields.update(fields)
        now = time.perf_counter()
        completed = self.progress.tasks[0].completed
        if not self.live and (now - self.logged >= self.log_every_s or completed >= self.total):
            self.logged = now
            shown = "  ".join(f"{name} {text}" for name, text in self.fields.items())
            print(
                f"{self.label} {completed:.0f}/{self.total}  {shown}  {speed:.2f} it/s", flush=True
            )

    def close(self) -> None:
        if self.enabled:
            self.progress.stop()

    def __enter__(self) -> ProgressBar:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
