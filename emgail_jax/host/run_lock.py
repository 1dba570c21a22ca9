"""One writer per run directory: an exclusive ``flock`` on ``DIR/run.lock``, held while a run
writes ``DIR``; the commands that read a finished run (``evaluate``, ``reoptimize``) share it,
so that none reads checkpoints a live run is still writing or pruning.

The kernel releases a ``flock`` when its file is closed, and closes every file of a process that
ends, however it ends (SIGKILL and crashes included), so a lock never outlives its holder and
never needs clearing by hand. The lock file itself stays; it names the last holder.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import socket

from emgail_jax.host.run_spec import RunError

LOCK_NAME = "run.lock"
UNWRITABLE = (errno.EACCES, errno.EPERM, errno.EROFS, errno.ENOENT, errno.ENOTDIR)


@contextlib.contextmanager
def hold(run_dir: str):
    """Holds ``run_dir``'s lock for the ``with`` block, alone.

    Raises:
      RunError: another live process holds it (the message names its pid and host).
    """
    with _locked(run_dir, shared=False):
        yield


@contextlib.contextmanager
def reading(run_dir: str):
    """Shares ``run_dir``'s lock with other readers for the ``with`` block; a directory this
    process may not write (a read-only copy of a run) is read unguarded.

    Raises:
      RunError: a live run writes it (the message names its pid and host).
    """
    with _locked(run_dir, shared=True):
        yield


@contextlib.contextmanager
def _locked(run_dir: str, shared: bool):
    try:
        descriptor = os.open(os.path.join(run_dir, LOCK_NAME), os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as error:
        # A reader of a directory it cannot write, or of no directory: no run writes there
        # either (the command says what is missing when it reads).
        if not shared or error.errno not in UNWRITABLE:
            raise
        yield
        return
    try:
        fcntl.flock(descriptor, (fcntl.LOCK_SH if shared else fcntl.LOCK_EX) | fcntl.LOCK_NB)
    except BlockingIOError:
        holder = os.read(descriptor, 256).decode(errors="replace").strip() or "a live process"
        os.close(descriptor)
        if shared:
            raise RunError(
                f"'{run_dir}' is being written by a run ({holder}): wait for it to end or stop "
                "it (a stopped run is read as of its last checkpoint)"
            ) from None
        raise RunError(
            f"'{run_dir}' is being written or read by another process ({holder}): wait for it "
            "to end, stop it, or choose another --out"
        ) from None
    except OSError:
        # A file system without flock (some network mounts): the run goes on unguarded.
        pass
    try:
        os.ftruncate(descriptor, 0)
        os.write(descriptor, f"pid {os.getpid()} on {socket.gethostname()}\n".encode())
        yield
    finally:
        os.close(descriptor)
