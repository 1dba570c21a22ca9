"""The stderr of one process of a multi-process run, passed through with one translation.

jax.distributed's client ends its process with ``abort()`` when the coordination service is
lost (process 0 killed) or reports another process dead: a fatal log line and a C++ stack
trace, within a second, before this project's peer watch can say anything. Its Python API has
no hook for that moment (the callback it accepts cannot be handed the status), so
:func:`emgail_jax.host.jax_setup.setup` routes such a process's stderr through this filter,
which replaces that log with the run's one-line error naming the lost process, or drops it if
the process has already given its own error line. Everything else passes unchanged, as it
comes (progress output without a newline too).

    python emgail_jax/host/fatal_log.py COORDINATOR PROCESS_ID   # stdin: the process's stderr

Standard library only: it runs as a script of its own.
"""

from __future__ import annotations

import os
import re
import signal
import sys

FATAL = b"Terminating process because the JAX distributed service detected fatal errors"
# A glog/absl line that may still become the fatal one: held back until its newline.
_FATAL_START = re.compile(rb"F\d{0,4}$|F\d{4} ")


def error_line(fatal: str, coordinator: str, process_id: int) -> str:
    """The run's one-line error for the client's fatal log ``fatal`` (its first lines)."""
    lost_service = "send RPC to coordination service" in fatal or "leader task" in fatal
    if process_id != 0 and lost_service:
        return (
            f"error: the run's coordinator, process 0 at {coordinator}, is gone (it failed or "
            "was killed); this process stops too"
        )
    status = fatal.split("absl::Status:", 1)[-1].strip()
    # The service names the processes it lost after "unhealthy ...:", one per line.
    task = re.search(r"(?:task[:_ /]*|unhealthy[^:\n]*:\s*)(\d+)", status)
    status = status.splitlines()[0][:200] if status else ""
    if task and int(task.group(1)) != process_id:
        return (
            f"error: process {task.group(1)} of the run stopped answering ({status}); this "
            "process stops too"
        )
    return f"error: the run's coordination service ended this process ({status})"


class Translator:
    """Feeds bytes through: :meth:`feed` returns what to write now, :meth:`close` the rest."""

    def __init__(self, coordinator: str, process_id: int):
        self.coordinator, self.process_id = coordinator, process_id
        self.pending = b""  # an unfinished line that may be the fatal one, or the fatal log
        self.fatal = False  # the fatal line was seen: what follows is the abort's
        self.said = False  # the process wrote its own error line (it knows why it ends)

    def feed(self, data: bytes) -> bytes:
        if self.fatal:
            if self.pending is None:  # translated already: the rest is the abort's trace
                return b""
            self.pending += data
            return self._translated(complete=False)
        data, self.pending = self.pending + data, b""
        at = data.find(FATAL)
        if at >= 0:
            self.fatal = True
            start = data.rfind(b"\n", 0, at) + 1
            self._hear(data[:start])
            self.pending = data[start:]
            return data[:start] + self._translated(complete=False)
        last = data.rfind(b"\n") + 1
        self._hear(data[:last])
        if _FATAL_START.match(data[last:]):
            self.pending = data[last:]
            return data[:last]
        return data

    def close(self) -> bytes:
        return self._translated(complete=True) if self.fatal else self.pending

    def _hear(self, lines: bytes) -> None:
        self.said = self.said or lines.startswith(b"error: ") or b"\nerror: " in lines

    def _translated(self, complete: bool) -> bytes:
        """The run's line for the fatal log held in ``pending``, once its first two lines are
        in (the second may name the lost processes) or the input has ended; given once."""
        if self.pending is None or (not complete and self.pending.count(b"\n") < 2):
            return b""
        fatal, self.pending = self.pending.decode(errors="replace"), None
        if self.said:
            return b""
        return f"{error_line(fatal, self.coordinator, self.process_id)}\n".encode()


def main(argv: list[str]) -> int:
    # It ends when the process it serves ends (end of input), not on the terminal's signals.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    translator = Translator(argv[0], int(argv[1]))
    while chunk := os.read(0, 65536):
        _write(translator.feed(chunk))
    _write(translator.close())
    return 0


def _write(data: bytes) -> None:
    while data:
        data = data[os.write(1, data) :]


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
