"""Process-wide JAX set-up for the command-line tools: host devices, the compilation cache and,
for a run spread over several processes or hosts, ``jax.distributed``."""

from __future__ import annotations

import contextlib
import dataclasses
import os
import socket
import subprocess
import sys
import threading
import time

DEFAULT_CACHE = os.path.join(os.path.expanduser("~"), ".cache", "emgail_jax", "xla")


# XLA:CPU's concurrency-optimised scheduler deadlocks on the vmapped update step with the
# jaxlib this project pins (every thread idles in BlockUntilReady); the default scheduler does
# not. Set on `import emgail_jax`, before anything imports JAX.
XLA_WORKAROUNDS = ("--xla_cpu_enable_concurrency_optimized_scheduler=false",)


def available_cores() -> int:
    """The cores this process may run on: those of its CPU affinity (``taskset``, a batch
    scheduler's allocation), not every core of the machine."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def add_xla_flags(*flags: str) -> None:
    current = os.environ.get("XLA_FLAGS", "")
    missing = [f for f in flags if f.split("=")[0] not in current]
    if missing:
        os.environ["XLA_FLAGS"] = " ".join([current, *missing]).strip()


# A process that stops answering (killed, its machine gone) is declared dead after this long,
# which ends the others (jax.distributed's coordination service); a finished process waits this
# long at most for the others to finish too.
HEARTBEAT_TIMEOUT_S = 20
SHUTDOWN_TIMEOUT_S = 60
# How long process 0, failing, waits for the others to end first (each ends within seconds of
# reading the failure, unless it is stuck in a long compile).
LEAVE_TIMEOUT_S = 30
# Where a process that fails posts its error for the others (the coordination service's store).
_FAILURES = "emgail_jax/failed/"
_LEFT = "emgail_jax/left/"
_PIDS = "emgail_jax/pids/"
_STDERR = os.dup(2)  # stderr as it is at start-up, also while a checkpoint write holds fd 2
_PEER_POLL_S = 0.5


@dataclasses.dataclass(frozen=True)
class Distributed:
    """Where a process of a multi-process run finds the others (``jax.distributed``)."""

    coordinator: str  # HOST:PORT of process 0
    num_processes: int
    process_id: int

    @classmethod
    def from_options(
        cls, coordinator: str | None, num_processes: int | None, process_id: int | None
    ) -> Distributed | None:
        """From command-line options, else JAX's standard environment variables
        (``JAX_COORDINATOR_ADDRESS``, ``JAX_NUM_PROCESSES``, ``JAX_PROCESS_ID``); ``None`` for a
        single-process run. Raises ``ValueError`` (one line) for an incomplete set."""
        env = os.environ
        coordinator = coordinator or env.get("JAX_COORDINATOR_ADDRESS")
        if num_processes is None and env.get("JAX_NUM_PROCESSES"):
            num_processes = int(env["JAX_NUM_PROCESSES"])
        if process_id is None and env.get("JAX_PROCESS_ID"):
            process_id = int(env["JAX_PROCESS_ID"])
        given = (coordinator, num_processes, process_id)
        if all(value is None for value in given):
            return None
        if any(value is None for value in given):
            raise ValueError(
                "a multi-process run needs --coordinator HOST:PORT, --num-processes N and "
                "--process-id I (or JAX_COORDINATOR_ADDRESS, JAX_NUM_PROCESSES, JAX_PROCESS_ID)"
            )
        if ":" not in coordinator or not 0 <= process_id < num_processes:
            raise ValueError(
                f"--coordinator must be HOST:PORT and 0 <= --process-id < --num-processes; got "
                f"{coordinator}, {process_id}, {num_processes}"
            )
        return cls(coordinator, num_processes, process_id)


def seed_share_error(seeds: int, processes: int) -> str | None:
    """Why ``processes`` cannot share ``seeds`` equally (each trains the same number), or
    None."""
    if seeds % processes:
        return (
            f"--seeds {seeds} cannot be shared equally by {processes} processes: "
            f"give a multiple of {processes} seeds"
        )
    return None


def setup(
    host_devices: int | None = None,
    cache_dir: str | None = DEFAULT_CACHE,
    distributed: Distributed | None = None,
) -> None:
    """Call before the first JAX computation.

    Args:
      host_devices: split the CPU into this many XLA devices (XLA runs one core per device, so
        seeds sharded over two devices use both cores of a 2-core machine). ``None`` uses one
        device per core the process may run on (:func:`available_cores`). Has no effect once JAX's
        backend exists or on GPU/TPU.
      cache_dir: JAX's persistent compilation cache, which removes repeated compiles across
        processes; ``None`` disables it.
      distributed: join a run of several processes (``jax.distributed``): ``jax.devices()``
        then lists every process's devices, and seeds are sharded over all of them.
    """
    devices = host_devices or available_cores()
    add_xla_flags(f"--xla_force_host_platform_device_count={devices}")
    import jax

    if distributed is not None:
        _translate_fatal_logs(distributed)
        jax.distributed.initialize(
            distributed.coordinator,
            distributed.num_processes,
            distributed.process_id,
            heartbeat_timeout_seconds=HEARTBEAT_TIMEOUT_S,
            shutdown_timeout_seconds=SHUTDOWN_TIMEOUT_S,
        )
        _watch_peers(distributed)
        # The CPU collectives (gloo) set up their connections on first use and give up after
        # 30 s; right after `initialize` every process is here at once, later (after compiles
        # that take each process its own time) not.
        from jax.experimental import multihost_utils

        multihost_utils.sync_global_devices("emgail_jax: processes connected")

    # A cache chosen earlier (JAX_COMPILATION_CACHE_DIR, or a caller's config) wins.
    if cache_dir and not jax.config.jax_compilation_cache_dir:
        jax.config.update("jax_compilation_cache_dir", cache_dir)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)
        jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)


def _translate_fatal_logs(distributed: Distributed) -> None:
    """Routes this process's stderr through :mod:`emgail_jax.host.fatal_log`, so that the
    jax.distributed client's abort, when the coordination service is lost, ends with the run's
    one-line error instead of a C++ stack trace. The filter ends when this process does."""
    from emgail_jax.host import fatal_log

    global _STDERR
    read, write = os.pipe()
    command = [sys.executable, fatal_log.__file__, distributed.coordinator]
    subprocess.Popen(
        [*command, str(distributed.process_id)], stdin=read, stdout=_STDERR, stderr=_STDERR
    )
    os.close(read)
    sys.stderr.flush()
    os.dup2(write, 2)
    _STDERR = write  # this process's own last words pass the filter too, which then knows them


class _PeerWatch:
    """Ends this process when another process of the run fails: it posts its error line
    (:func:`report_failure`), it stops answering (killed), or the coordination service that
    process 0 holds disappears."""

    def __init__(self, distributed: Distributed):
        from jax._src import distributed as jax_distributed

        self.distributed = distributed
        self.client = jax_distributed.global_state.client
        self.active = True
        self.thread: threading.Thread | None = None
        self.neighbours: dict[int, int] = {}  # process -> pid, of those on this machine

    def run(self) -> None:
        me = self.distributed.process_id
        with contextlib.suppress(Exception):
            self.client.key_value_set(f"{_PIDS}{me}", f"{socket.gethostname()} {os.getpid()}")
        unreachable = 0.0
        while self.active:
            time.sleep(_PEER_POLL_S)
            try:
                failures = self.client.key_value_dir_get(_FAILURES)
                unreachable = 0.0
            except Exception:  # the service's errors have no Python type of their own
                unreachable += _PEER_POLL_S
                if unreachable >= HEARTBEAT_TIMEOUT_S:
                    self._end_with(
                        f"the run's coordinator, process 0 at {self.distributed.coordinator}, "
                        "is gone (it failed or was killed)"
                    )
                continue
            for key, message in failures:
                peer = key.rsplit("/", 1)[-1]
                if peer != str(me):
                    self._end_with(f"process {peer} of the run failed ({message})")
            gone = self.gone()
            if gone:
                self._end_with(f"process {gone[0]} of the run stopped answering (killed?)")

    def _end_with(self, cause: str) -> None:
        # A moment for this process's own failure, if it fails alike (a check every process
        # makes), to be the one it reports.
        time.sleep(2 * _PEER_POLL_S)
        if self.active:
            self.active = False
            _leave_now(f"error: {cause}; this process stops too", 1)

    def gone(self) -> list[int]:
        """The other processes that no longer answer: on this machine, those whose process
        has ended (at once); elsewhere, those the service misses heartbeats of."""
        me, count = self.distributed.process_id, self.distributed.num_processes
        try:
            if len(self.neighbours) < count - 1:
                self.neighbours = self._neighbours()
        except Exception:  # the service itself is gone, and with it process 0
            return [0]
        ended = [i for i, pid in self.neighbours.items() if not _running(pid)]
        if ended:
            # Asked first: the service's answer waits until it has declared the dead dead.
            return ended
        try:
            live = self.client.get_live_nodes(list(range(count)))
        except Exception:
            return [0]
        return [i for i in range(count) if i != me and i not in live]

    def _neighbours(self) -> dict[int, int]:
        host, me = socket.gethostname(), self.distributed.process_id
        found = {}
        for key, value in self.client.key_value_dir_get(_PIDS):
            their_host, _, pid = value.rpartition(" ")
            if their_host == host and int(key.rsplit("/", 1)[-1]) != me:
                found[int(key.rsplit("/", 1)[-1])] = int(pid)
        return found


def _running(pid: int) -> bool:
    """Whether process ``pid`` of this machine runs (a killed one not yet reaped, a zombie,
    does not)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[-1].split()[0] != "Z"
    except FileNotFoundError:
        return False
    except OSError:  # no /proc: ask the kernel
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return False
        return True


_peer_watch: _PeerWatch | None = None


def peers_gone() -> list[int]:
    """The processes of this run that no longer answer (none in a run of one process)."""
    return [] if _peer_watch is None else _peer_watch.gone()


def _watch_peers(distributed: Distributed) -> None:
    global _peer_watch
    _peer_watch = _PeerWatch(distributed)
    _peer_watch.thread = threading.Thread(target=_peer_watch.run, daemon=True, name="peers")
    _peer_watch.thread.start()


def report_failure(message: str) -> None:
    """Tells the other processes of the run that this one fails with ``message`` (one line);
    they end at once instead of waiting for it in a collective."""
    if _peer_watch is None:
        return
    _peer_watch.active = False
    key = f"{_FAILURES}{_peer_watch.distributed.process_id}"
    with contextlib.suppress(Exception):
        _peer_watch.client.key_value_set(key, message)


def leave(code: int) -> None:
    """Ends this process's part in a multi-process run: after a success, waits for the others
    to finish too (at most :data:`SHUTDOWN_TIMEOUT_S`); after a failure (reported first with
    :func:`report_failure`) exits at once with ``code``, since waiting for processes that will
    not finish would hang."""
    import jax

    global _peer_watch
    if _peer_watch is None:
        return
    _peer_watch.active = False
    if code != 0:
        _leave_now(None, code)
    # A thread still inside the client when the interpreter ends aborts the process.
    _peer_watch.thread.join(timeout=5)
    jax.distributed.shutdown()
    _peer_watch = None


def _leave_now(line: str | None, code: int) -> None:
    """Exits the process at once, ``line`` first on stderr: no interpreter shutdown, which
    would wait for the other processes. Process 0, which holds the coordination service, goes
    last (a few seconds at most), so that the others end with their own line, not with the
    service's abort."""
    sys.stdout.flush()
    sys.stderr.flush()
    if line:
        os.write(_STDERR, f"{line}\n".encode())
    watch = _peer_watch
    if watch is not None and watch.distributed.process_id != 0:
        with contextlib.suppress(Exception):
            watch.client.key_value_set(f"{_LEFT}{watch.distributed.process_id}", "")
    elif watch is not None:
        others = set(range(1, watch.distributed.num_processes))
        deadline = time.monotonic() + LEAVE_TIMEOUT_S
        while time.monotonic() < deadline:
            with contextlib.suppress(Exception):
                left = {
                    int(key.rsplit("/", 1)[-1]) for key, _ in watch.client.key_value_dir_get(_LEFT)
                }
                if others <= left | set(watch.gone()):
                    break
            time.sleep(0.1)
    os._exit(code)
