"""The JAX set-up a command makes before its first computation."""

import os
import subprocess
import sys

import pytest

from emgail_jax.host import jax_setup


def test_available_cores_are_those_of_the_process_affinity(monkeypatch):
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {3}, raising=False)
    assert jax_setup.available_cores() == 1
    monkeypatch.delattr(os, "sched_getaffinity", raising=False)
    monkeypatch.setattr(os, "cpu_count", lambda: 4)
    assert jax_setup.available_cores() == 4


def test_add_xla_flags_keeps_a_flag_the_user_set(monkeypatch):
    monkeypatch.setenv("XLA_FLAGS", "--xla_force_host_platform_device_count=3")
    jax_setup.add_xla_flags("--xla_force_host_platform_device_count=1", "--xla_cpu_flag=x")
    flags = os.environ["XLA_FLAGS"].split()
    assert flags == ["--xla_force_host_platform_device_count=3", "--xla_cpu_flag=x"]


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="no CPU affinity here")
def test_a_process_pinned_to_one_core_gets_one_device():
    """A run under ``taskset -c 0`` (or a scheduler's one-core allocation) is one device, not
    as many as the machine has cores competing for one."""
    code = (
        "import os; os.sched_setaffinity(0, {min(os.sched_getaffinity(0))}); "
        "from emgail_jax.host import jax_setup; jax_setup.setup(cache_dir=None); "
        "import jax; print(jax.device_count())"
    )
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
    )
    assert out.stdout.strip() == "1"
