"""A run's directory: where a new run goes, and who may write it.

Imports no JAX: a command takes the directory's lock, and refuses a taken or unusable one,
before JAX starts.
"""

from __future__ import annotations

import contextlib
import glob
import itertools
import os
import shutil

from emgail_jax.host import run_lock
from emgail_jax.host.run_spec import RunError, read_summary

OUTPUTS = ("summary.json", "metrics.csv", "tensorboard", "checkpoints", "snapshots")
# What `reoptimize` and `refit` derive from a run's networks in its directory: its checks, their
# finished draws and parts (a check spread over processes), the rewards refitted and the one
# saved to take away. They go with the run they were made from.
DERIVED = ("rewards", "reward", "reoptimize*.json", "reoptimize*.draws", "reoptimize*.parts")


def default_output(env: str, algo: str, root: str = "runs") -> str:
    """``runs/ENV-ALGO``, or the first ``runs/ENV-ALGO-N`` not taken: a run without ``--out``
    never touches an earlier one."""
    base = os.path.join(root, f"{env}-{algo}")
    candidates = itertools.chain([base], (f"{base}-{n}" for n in itertools.count(2)))
    return next(path for path in candidates if not os.path.exists(path))


def create_output(out: str) -> None:
    """Creates the directory ``out`` (nothing in it yet)."""
    if os.path.exists(out) and not os.path.isdir(out):
        raise RunError(f"--out '{out}' is a file, not a directory: choose another --out")
    os.makedirs(out, exist_ok=True)
    if not os.access(out, os.W_OK):
        raise RunError(f"cannot write to '{out}': choose a writable --out")


@contextlib.contextmanager
def writing(out: str, new: bool):
    """Holds ``out``'s run lock, creating the directory first for a ``new`` run; a run that
    ends before writing anything (refused) leaves no directory behind."""
    created = new and not os.path.exists(out)
    if new:
        create_output(out)
    elif not os.path.isdir(out):
        read_summary(out)  # says it is no run directory
    try:
        with run_lock.hold(out):
            yield
    finally:
        if created and os.listdir(out) == [run_lock.LOCK_NAME]:
            shutil.rmtree(out)


def prepare_output(out: str, overwrite: bool) -> None:
    """Creates ``out``; refuses to mix with an earlier run unless ``overwrite``, which removes
    the earlier run and what was derived from its networks (:data:`DERIVED`)."""
    create_output(out)
    existing = [name for name in OUTPUTS if os.path.exists(os.path.join(out, name))]
    if existing and not overwrite:
        raise RunError(
            f"'{out}' already holds a run ({', '.join(existing)}): "
            "pass --resume to continue it, --overwrite to replace it, or choose another --out"
        )
    derived = [path for pattern in DERIVED for path in glob.glob(os.path.join(out, pattern))]
    for path in [os.path.join(out, name) for name in existing] + (derived if overwrite else []):
        shutil.rmtree(path) if os.path.isdir(path) else os.remove(path)
