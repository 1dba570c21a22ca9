"""Shared test setup: two host devices (so seed sharding is exercised), JAX's persistent
compilation cache and a fast compile, all before JAX creates its backend."""

import json
import os
import pathlib
import shutil
import warnings

import pytest

# The two workers compile many of the same small programs (network inits, single operations
# run eagerly): with every compile cached, however short, the second worker reads them. Set
# before JAX is imported, which reads it once; child processes inherit it.
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")

from emgail_jax.host import jax_setup

_REPO = pathlib.Path(__file__).resolve().parents[1]

# The two test workers share the two cores: BLAS threads of their own only fight over them (the
# driver separability test's classifier: 43 s with 2 threads, 12 s with 1, on a busy machine).
# Set before NumPy loads its BLAS; child processes inherit it.
for _variable in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")

# The tests compile many small programs once each and run them for moments: LLVM's lowest
# optimisation level halves a cold compile (the tiny driver run: 45-48 s -> 22-25 s), and
# the child processes some tests start inherit it.
jax_setup.add_xla_flags("--xla_backend_optimization_level=0")
# The tests' own compilation cache, for the child processes some tests start too: they reuse
# what the workers compiled for the same runs, and never read or fill the user's cache.
os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", str(_REPO / ".cache" / "jax"))
jax_setup.setup(host_devices=2, cache_dir=os.environ["JAX_COMPILATION_CACHE_DIR"])


def pytest_collection_modifyitems(items):
    """Files marked ``heavy`` first, in their own order otherwise: with ``--dist loadfile`` and no
    reordering, the workers take files in this order, and a heavy file left to the end keeps one
    worker busy while the other idles."""
    items.sort(key=lambda item: item.get_closest_marker("heavy") is None)


TINY_RUN = [
    *("--env", "driver", "--seeds", "2", "--iterations", "4", "--num-envs", "2"),
    *("--rollout-length", "20", "--chunk-size", "2", "--snapshot-every", "2", "--quiet"),
]


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory):
    """A finished tiny EM-GAIL driver run (2 seeds, 4 iterations) with its checkpoint and
    snapshots of iterations 2 and 4. Its sizes
    and chunk are those of the other tiny driver runs (test_run, test_resume, test_distributed),
    so that they all share one compiled program through the persistent compilation cache.
    Under xdist the first worker to ask trains it and every worker gets a copy of its own."""
    import fcntl

    from emgail_jax import run

    out = tmp_path_factory.mktemp("tiny") / "emgail"
    if "PYTEST_XDIST_WORKER" not in os.environ:  # one process
        assert run.main([*TINY_RUN, "--out", str(out)]) == 0
        return out
    session = tmp_path_factory.getbasetemp().parent  # shared by this session's workers
    trained = session / "tiny-run" / "emgail"
    with open(session / "tiny-run.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # the others wait for the first to train it
        summary = trained / "summary.json"
        if not summary.exists() or json.loads(summary.read_text())["status"] != "completed":
            shutil.rmtree(trained, ignore_errors=True)
            assert run.main([*TINY_RUN, "--out", str(trained)]) == 0
    shutil.copytree(trained, out)
    return out


@pytest.fixture
def copied_run(tiny_run, tmp_path):
    """A copy of the tiny run, without what was derived from it (refits, checks), that a test
    may write rewards and checks into."""
    copy = tmp_path / "run"
    shutil.copytree(
        tiny_run, copy, ignore=shutil.ignore_patterns("rewards", "reward", "reoptimize*")
    )
    return copy


@pytest.fixture(scope="session")
def renumbered_run(tiny_run, tmp_path_factory):
    """``tiny_run`` as if started with ``run --seed 4``: its seeds are numbered 4 and 5."""
    copy = tmp_path_factory.mktemp("renumbered") / "emgail"
    shutil.copytree(tiny_run, copy)
    summary = json.loads((copy / "summary.json").read_text())
    (copy / "summary.json").write_text(json.dumps({**summary, "first_seed": 4}))
    return copy


@pytest.fixture
def random_batch():
    """``random_batch(k, m, n, obs_dim, act_dim, seed)``: a ``NormalizedBatch`` of random
    samples (``[k, m, ...]``) and demonstration pairs (``[n, ...]``) for the step tests."""
    import jax

    from emgail_jax.method.batches import NormalizedBatch
    from emgail_jax.method.normalizer import RunningStats

    def make(k=3, m=4, n=6, obs_dim=2, act_dim=1, seed=0):
        keys = jax.random.split(jax.random.PRNGKey(seed), 4)
        return NormalizedBatch(
            normalizer=RunningStats.create(obs_dim),
            obs=jax.random.normal(keys[0], (k, m, obs_dim)),
            executed=jax.random.normal(keys[1], (k, m, act_dim)),
            expert_obs=jax.random.normal(keys[2], (n, obs_dim)),
            expert_actions=jax.random.normal(keys[3], (n, act_dim)),
        )

    return make


class MinariUser:
    """Writes Minari datasets with Minari's own API (``create_dataset_from_buffers``), as a
    user of Minari would, for the tests of ``--demos``; under ``MINARI_DATASETS_PATH``."""

    @staticmethod
    def buffers(demos, intention, **replaced):
        """Minari episode buffers of one intention's demonstrations, as a user would make them."""
        import numpy as np
        from minari.data_collector import EpisodeBuffer

        bounds = [*np.flatnonzero(demos.episode_starts), len(demos)]
        buffers = []
        for episode in np.unique(demos.episode[demos.intentions == intention]):
            first, end = bounds[episode], bounds[episode + 1]
            fields = {
                "observations": np.concatenate(
                    [demos.observations[first:end], demos.final_observations[episode][None]]
                ),
                "actions": demos.actions[first:end],
                "rewards": demos.rewards[first:end].astype(np.float64),
                "terminations": np.zeros(end - first, bool),
                "truncations": np.arange(end - first) == end - first - 1,
            }
            buffers.append(EpisodeBuffer(**{**fields, **replaced}))
        return buffers

    @staticmethod
    def dataset(name, buffers, obs_dim=10, act_dim=1, **spaces):
        """A dataset written by Minari's own ``create_dataset_from_buffers``; its directory."""
        import gymnasium
        import minari
        import numpy as np

        with warnings.catch_warnings():  # about the env spec it has not been given
            warnings.simplefilter("ignore", UserWarning)
            dataset = minari.create_dataset_from_buffers(
                f"user/{name}-v0",
                buffers,
                observation_space=spaces.get(
                    "observation_space",
                    gymnasium.spaces.Box(-np.inf, np.inf, (obs_dim,), np.float32),
                ),
                action_space=spaces.get(
                    "action_space", gymnasium.spaces.Box(-1.0, 1.0, (act_dim,), np.float32)
                ),
                algorithm_name="a user's expert",
                description="a test dataset",
                author="a user",
                author_email="user@example.org",
                code_permalink="https://example.org/code",
            )
        return str(dataset.storage.data_path.parent)


@pytest.fixture(scope="session")
def minari_user():
    return MinariUser


# ---- the sweep's cells on disk (tests/test_sweep*.py) ------------------------------------------

# A finished cell's reward check as reoptimize writes it now (every seed, the baseline), and as
# it wrote it when the check took seed 0 alone.
_CHECK_OF_EVERY_SEED = {
    "iteration": 4,
    "budget": {"iterations": 4, "gamma": 0.995},
    "seeds": [0, 1],
    "erd": [0.5, 0.7],
    "erd_mean": 0.6,
    "erd_std": 0.1,
    "baseline": {"erd": 0.03, "cache": "hopper-k2-4it-g0.995-0123456789ab.json"},
    "compile_time_s": 5.0,
    "train_time_s": 16.0,
}
_CHECK_OF_SEED_0 = {"run_seed": 0, "iterations": 4, "erd": 0.49, "compile_time_s": 3.0,
                   "train_time_s": 6.0}  # fmt: skip
_REFIT_OF_EVERY_SEED = {
    **_CHECK_OF_EVERY_SEED,
    "erd": [0.1, 0.2],
    "baseline": {"erd": 0.02},
    "consolidation": [{"run_seed": 0, "seconds": 30.0}, {"run_seed": 1, "seconds": 50.0}],
    # The refit of today's recipe for hopper, read as it reads it.
    "saved_reward": "consolidated-4000-penalty-10-fresh-noise-1-batch-5000-ranking-10-absorbing",
    "reward_form": "logit",
}
# The sweep's checks draw 3 agents per seed and intention; these three draws are alike.
_CHECK_OF_EVERY_SEED["draws"] = [dict(_CHECK_OF_EVERY_SEED) for _ in range(3)]
_REFIT_OF_EVERY_SEED["draws"] = [
    {key: value for key, value in _REFIT_OF_EVERY_SEED.items() if key != "draws"}
] * 3


def _finished_cell(out, cell, erd, check=None, refit=None):
    """``out/runs/<cell>`` as a finished 4-iteration run leaves it: its ``summary.json`` (ERD
    ``erd`` per seed, 1 s per seed-iteration-intention, 10 s to compile), ``check`` as
    ``reoptimize.json`` and ``refit`` as ``reoptimize-refit.json``."""
    from emgail_jax.host.final_results import FinalResults

    k, seeds = cell.intentions, len(erd)
    final = FinalResults(
        erd=erd, erd_per_intention=[[e] * k for e in erd], cluster_accuracy=None,
        expert_returns=[1.0] * k, returns=[[0.0] * k] * seeds, random_returns=[0.0] * k,
        compile_time_s=10.0, train_time_s=4.0 * seeds * k, iteration_time_s=1.0, env_steps=1,
    )  # fmt: skip
    summary = {
        "env": cell.env, "intentions": k, "seeds": seeds, "status": "completed",
        "iterations_done": 4, "parameters": {"total": 1}, "final": final.to_summary(),
        "timings": {"compile_time_s": 10.0, "train_time_s": 4.0 * seeds * k, "iterations": 4},
        "config": {"iterations": 4, "gamma": 0.995, "gae_lambda": 0.97},
    }  # fmt: skip
    run_dir = out / "runs" / cell.name
    run_dir.mkdir(parents=True)
    (run_dir / "summary.json").write_text(json.dumps(summary))
    if check is not None:
        (run_dir / "reoptimize.json").write_text(json.dumps(check))
    if refit is not None:
        (run_dir / "reoptimize-refit.json").write_text(json.dumps(refit))
    return run_dir


@pytest.fixture
def hopper_cells(tmp_path):
    """The sweep's finished hopper cells, their reward checks of either form or none: the
    sweep's results of them and its OUT."""
    import sweep_cells
    import sweep_report

    Cell = sweep_cells.Cell
    out = tmp_path / "results"
    _finished_cell(out, Cell("hopper", 1, "gail"), [0.01, 0.01])
    _finished_cell(
        out, Cell("hopper", 2, "emgail"), [0.01, 0.01], _CHECK_OF_EVERY_SEED, _REFIT_OF_EVERY_SEED
    )
    _finished_cell(out, Cell("hopper", 2, "infogail"), [0.02, 0.04])  # its checks are to do
    gail_check = {**_CHECK_OF_EVERY_SEED, "erd": [0.9, 1.1], "erd_mean": 1.0}
    _finished_cell(out, Cell("hopper", 2, "gail"), [0.5, 0.6], gail_check)  # its refit's to do
    _finished_cell(out, Cell("hopper", 3, "emgail"), [0.03, 0.05], _CHECK_OF_SEED_0)
    _finished_cell(out, Cell("hopper", 3, "gail"), [0.4, 0.4])
    return sweep_report.collect(str(out), sweep_cells.all_cells(), 2, 4), out


@pytest.fixture
def kept_checkpoints(monkeypatch):
    """The finished cells' run directories as if they kept their final checkpoints."""
    from emgail_jax.host import checkpoints

    monkeypatch.setattr(checkpoints, "latest_iteration", lambda run_dir: 4)
