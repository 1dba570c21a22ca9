"""SIGINT/SIGTERM end a run within seconds wherever its main thread is, even blocked in a call
that does not return to Python; within the chunk loop the first one asks for a clean stop."""

import signal
import subprocess
import sys
import time

import pytest

from emgail_jax.host import stopping

# The main thread blocks in os.read, which retries after each signal (PEP 475) without
# returning to the program: like XLA's compiles and collective waits.
BLOCKED = """
import os, sys
from emgail_jax.host import stopping
with stopping.Signals() as signals:
    stoppable = signals.stoppable() if sys.argv[1] != "start-up" else open(os.devnull)
    with stoppable:
        if sys.argv[1] == "chunk-done":
            signals.progressed()
        read, _ = os.pipe()
        print("ready", flush=True)
        os.read(read, 1)
"""


def _start(where: str) -> subprocess.Popen:
    process = subprocess.Popen(
        [sys.executable, "-c", BLOCKED, where],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert process.stdout.readline().strip() == "ready"
    return process


@pytest.mark.parametrize(
    ("sig", "where"),
    [(signal.SIGTERM, "start-up"), (signal.SIGINT, "start-up"), (signal.SIGTERM, "first-chunk")],
)
def test_a_signal_before_a_chunk_is_done_ends_a_blocked_process_at_once(sig, where):
    process = _start(where)
    start = time.monotonic()
    process.send_signal(sig)
    assert process.wait(timeout=10) == stopping.INTERRUPTED
    assert time.monotonic() - start < 5
    err = process.stderr.read().strip()
    assert err.startswith(f"error: stopped by {sig.name} at once") and "\n" not in err


def test_in_the_chunk_loop_the_first_signal_asks_and_the_second_ends():
    process = _start("chunk-done")
    process.send_signal(signal.SIGTERM)
    time.sleep(1)
    assert process.poll() is None  # asked to stop at the next chunk boundary, still running
    process.send_signal(signal.SIGTERM)
    assert process.wait(timeout=10) == stopping.INTERRUPTED
    first, second = process.stderr.read().strip().splitlines()
    assert first.startswith("SIGTERM: stopping after the iteration chunk in progress")
    assert second.startswith("error: stopped by SIGTERM at once")


def test_the_previous_handlers_come_back():
    before = signal.getsignal(signal.SIGTERM)
    with stopping.Signals() as signals:
        assert signal.getsignal(signal.SIGTERM) is not before
        with signals.stoppable():
            signals.progressed()
            signal.raise_signal(signal.SIGTERM)
            time.sleep(0.5)
            assert signals.requested == signal.SIGTERM
    assert signal.getsignal(signal.SIGTERM) is before


def test_outside_the_main_thread_the_signals_are_left_alone():
    import threading

    before, seen = signal.getsignal(signal.SIGTERM), []

    def body():
        with stopping.Signals() as signals, signals.stoppable():
            seen.append(signal.getsignal(signal.SIGTERM))

    thread = threading.Thread(target=body)
    thread.start()
    thread.join()
    assert seen == [before]
