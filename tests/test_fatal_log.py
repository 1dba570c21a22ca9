"""The stderr filter of a multi-process run's processes: jax.distributed's abort log becomes the
run's one-line error; everything else passes as it came."""

import subprocess
import sys

from emgail_jax.host import fatal_log
from emgail_jax.host.fatal_log import Translator

COORDINATOR = "127.0.0.1:1234"
LOST = (
    b"F1202 02:19:06.723265   11938 client.h:80] Terminating process because the JAX distributed "
    b"service detected fatal errors. This most likely indicates that another task died. "
    b"absl::Status: UNAVAILABLE: Failed to send RPC to coordination service. Either the leader "
    b"task was preempted/died/restarted unexpectedly or this task is experiencing network issues."
    b"\nAdditional GRPC error information\n*** Check failure stack trace: ***\n"
    b"    @ 0x7f18d1440634\n"
)
GONE = (
    "error: the run's coordinator, process 0 at 127.0.0.1:1234, is gone (it failed or was "
    "killed); this process stops too\n"
)


def _through(translator: Translator, *chunks: bytes) -> bytes:
    return b"".join(translator.feed(chunk) for chunk in chunks) + translator.close()


def test_other_output_passes_unchanged_and_at_once():
    translator = Translator(COORDINATOR, 1)
    assert translator.feed(b"step 3\rstep 4") == b"step 3\rstep 4"  # no newline: not held
    assert translator.feed(b"\nFinal ERD 0.1\nW1202 a warning\n") == (
        b"\nFinal ERD 0.1\nW1202 a warning\n"
    )
    assert translator.close() == b""


def test_the_abort_log_of_a_lost_coordinator_becomes_one_line_naming_it():
    before = b"E1202 02:19:06 agent.cc:289] Polled an error\n"
    assert _through(Translator(COORDINATOR, 1), before + LOST) == before + GONE.encode()


def test_a_fatal_line_split_across_reads_is_still_found():
    out = _through(Translator(COORDINATOR, 1), b"ok\nF12", LOST[3:40], LOST[40:])
    assert out == b"ok\n" + GONE.encode()


def test_a_lost_peer_of_process_0_is_named_by_its_task():
    fatal = (
        "F1202 client.h:80] Terminating process because the JAX distributed service detected "
        "fatal errors. absl::Status: UNAVAILABLE: task 1 stopped sending heartbeats"
    )
    line = fatal_log.error_line(fatal, COORDINATOR, 0)
    assert line.startswith("error: process 1 of the run stopped answering (UNAVAILABLE: task 1")
    assert fatal_log.error_line("F1 ... absl::Status: INTERNAL: x", COORDINATOR, 0) == (
        "error: the run's coordination service ended this process (INTERNAL: x)"
    )


def test_the_filter_runs_as_a_script_of_its_own():
    shown = subprocess.run(
        [sys.executable, fatal_log.__file__, COORDINATOR, "1"],
        input=b"hello\n" + LOST,
        capture_output=True,
        timeout=30,
    )
    assert shown.returncode == 0 and shown.stdout == b"hello\n" + GONE.encode()


def test_the_abort_after_the_process_s_own_error_line_is_dropped():
    own = b"error: process 1 of the run is gone (Gloo AllGather failed)\n"
    assert _through(Translator(COORDINATOR, 0), own, b"E1202 x\n" + LOST) == own + b"E1202 x\n"


def test_the_lost_process_named_on_the_line_after_the_status_is_found():
    unhealthy = (
        b"F1202 client.h:80] Terminating process because the JAX distributed service detected "
        b"fatal errors. absl::Status: UNAVAILABLE: The following tasks are unhealthy (stopped "
        b"sending heartbeats):\n"
    )
    translator = Translator(COORDINATOR, 0)
    assert translator.feed(unhealthy) == b""  # the next line may name the process
    out = translator.feed(b"1\nThe tasks have crashed.\n") + translator.feed(b"*** Check fail")
    assert out.startswith(b"error: process 1 of the run stopped answering (UNAVAILABLE: The")
    assert out.count(b"\n") == 1 and translator.close() == b""
