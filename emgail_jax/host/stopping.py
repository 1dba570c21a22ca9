"""SIGINT and SIGTERM at any moment of a run, also while the main thread waits in compiled code.

Python runs a signal handler only when the main thread returns to the interpreter, which it does
not while XLA compiles, computes, or waits for another process (``jax.distributed``'s start,
a collective). So the signals are read from a wakeup pipe by a thread of their own, which acts
whatever the main thread is doing:

- within :meth:`Signals.stoppable` (the chunk loop), once a chunk is done (:meth:`progressed`),
  the first signal asks the run to stop after the chunk in progress (``requested``, read between
  chunks; the run then checkpoints);
- a second signal, or any signal before that (start-up, the first compile), ends the process at
  once with one line (exit 130): nothing is lost but the iterations since the last checkpoint,
  which ``--resume`` redoes.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
INTERRUPTED = 130  # the exit code of a run stopped by a signal


class Signals:
    """Use as a context manager from the main thread, around the whole run."""

    def __init__(self):
        self.requested: int | None = None  # the signal that asked to stop after the chunk
        self._in_loop = False
        self._progressed = False
        self._previous_handlers = {}
        self._previous_wakeup = -1
        self._pipe = None
        self._active = False

    def __enter__(self) -> Signals:
        global _stderr
        self._active = threading.current_thread() is threading.main_thread()
        if not self._active:  # only the main thread may take signals: they stay as they are
            return self
        _stderr = os.dup(2)  # stderr as it is now, also while fd 2 is held back
        read, write = os.pipe()
        os.set_blocking(write, False)
        self._pipe = (read, write)
        self._previous_wakeup = signal.set_wakeup_fd(write, warn_on_full_buffer=False)
        self._previous_handlers = {sig: signal.getsignal(sig) for sig in STOP_SIGNALS}
        self.install()
        self._thread = threading.Thread(target=self._watch, args=(read,), daemon=True)
        self._thread.start()
        return self

    def install(self) -> None:
        """(Re)takes SIGINT and SIGTERM; needed after code that installs its own handlers
        (``jax.distributed.initialize`` takes SIGTERM for its preemption notices)."""
        if not self._active:
            return
        for sig in STOP_SIGNALS:
            # The handler only makes Python write the signal to the wakeup pipe.
            signal.signal(sig, _ignore)

    def __exit__(self, *exc) -> None:
        global _stderr
        if not self._active:
            return
        for sig, handler in self._previous_handlers.items():
            signal.signal(sig, handler)
        signal.set_wakeup_fd(self._previous_wakeup)
        os.close(self._pipe[1])  # ends the watching thread
        self._thread.join(timeout=5)
        os.close(_stderr)
        _stderr = 2

    @contextlib.contextmanager
    def stoppable(self):
        """Within the block, once :meth:`progressed`, a first signal asks to stop at the next
        chunk boundary."""
        self._in_loop = True
        try:
            yield self
        finally:
            self._in_loop = self._progressed = False

    def progressed(self) -> None:
        """A chunk is done: there is work a clean stop would save."""
        self._progressed = True

    def _watch(self, read: int) -> None:
        try:
            while data := os.read(read, 64):
                for number in data:
                    self._on_signal(number)
        finally:
            os.close(read)

    def _on_signal(self, number: int) -> None:
        name = signal.Signals(number).name
        if self._in_loop and self._progressed and self.requested is None:
            self.requested = number
            _say(
                f"{name}: stopping after the iteration chunk in progress, with a checkpoint "
                "(a second signal stops at once)"
            )
            return
        _say(
            f"error: stopped by {name} at once; --resume continues from the last checkpoint, "
            "if the run wrote one"
        )
        os._exit(INTERRUPTED)


def _ignore(signum, frame) -> None:
    pass


_stderr = 2


def _say(line: str) -> None:
    # os.write, not print: the main thread may hold sys.stderr's lock.
    os.write(_stderr, f"{line}\n".encode())
