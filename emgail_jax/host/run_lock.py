"""One writer per run directory: an exclusive ``flock`` on ``DIR/run.lock``, held while a run
writes ``DIR``.

The kernel releases a ``flock`` when its file is closed, and closes every file of a process that
ends, however it ends (SIGKILL and crashes included), so a lock never outlives its holder and
never needs clearing by hand. The lock file itself stays; it names the last holder.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import socket

from emgail_jax.host.run_spec import RunError

LOCK_NAME = "run.lock"


@contextlib.contextmanager
def hold(run_dir: str):
    """Holds ``run_dir``'s lock for the ``with`` block.

    Raises:
      RunError: another live process holds it (the message names its pid and host).
    """
    descriptor = os.open(os.path.join(run_dir, LOCK_NAME), os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        holder = os.read(descriptor, 256).decode(errors="replace").strip()
        os.close(descriptor)
        raise RunError(
            f"'{run_dir}' is being written by another run ({holder or 'a live process'}): "
            "wait for it to end, stop it, or choose another --out"
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
