"""The multi-seed runner: chunk sizes, seed sharding over host devices, chunked scans of the
update, programs shared through the process's cache. Uses a toy update so that it compiles in
moments."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.sharding import PartitionSpec

from emgail_jax.host import program_cache, seed_runner
from emgail_jax.host.history import concat_history
from emgail_jax.host.seed_runner import (
    Runner,
    chunk_length,
    chunks,
    intention_runner,
    seed_sharding,
)
from emgail_jax.method.rl import RLTrainer

CHUNK = 3
INPUTS = np.array([True, False, True])


def toy_init(key, data=None):
    """A seed's state: its own key, a random vector and an iteration counter."""
    key_x, key_next = jax.random.split(key)
    return {
        "key": key_next,
        "x": jax.random.normal(key_x, (3,)),
        "iteration": jnp.zeros((), jnp.int32),
    }


def toy_update(state, flag, data=None):
    """x <- x / 2 + noise (+ ``data["shift"]`` when given), with a fresh key per iteration;
    metrics: a scalar, a [3] vector, the iteration, and, when the per-iteration ``flag`` is set,
    the norm of x (NaN otherwise, the way an iteration without evaluation logs)."""
    key_next, key_noise = jax.random.split(state["key"])
    x = 0.5 * state["x"] + jax.random.normal(key_noise, (3,))
    if data is not None:
        x = x + data["shift"]
    iteration = state["iteration"] + 1
    norm = jax.lax.cond(flag, lambda: jnp.linalg.norm(x), lambda: jnp.float32(jnp.nan))
    metrics = {"x/sum": x.sum(), "x": x, "iteration": iteration, "x/norm": norm}
    return {"key": key_next, "x": x, "iteration": iteration}, metrics


def reference(seed_key, iterations):
    """One seed, no vmap, no sharding: ``{name: [iterations, ...]}``."""
    state = jax.jit(toy_init)(seed_key)
    update = jax.jit(toy_update)
    out = []
    for i in range(iterations):
        state, metrics = update(state, INPUTS[i % CHUNK])
        out.append(jax.device_get(metrics))
    return {k: np.stack([m[k] for m in out]) for k in out[0]}


def run_chunks(runner, chunks, key=0):
    """``chunks`` steps of ``runner`` from fresh seeds: (final state, host history)."""
    state = runner.init(jax.random.PRNGKey(key))
    history = None
    for _ in range(chunks):
        state, metrics = runner.step(state, INPUTS)
        history = concat_history(history, metrics)
    return state, history


def run(seeds, chunks, key=0):
    runner = Runner(toy_init, toy_update, seeds)
    return runner, *run_chunks(runner, chunks, key)


@pytest.fixture(scope="module")
def four_seeds():
    return run(4, 2)


@pytest.fixture(scope="module")
def three_seeds():
    return run(3, 2)


@pytest.mark.parametrize(
    ("iterations", "chunk_size", "expected"),
    [(400, 10, 10), (5, 10, 5), (7, 10, 7), (13, 10, 1), (12, 5, 4), (1, 10, 1), (9, 4, 3)],
)
def test_chunk_length_is_the_largest_divisor_up_to_chunk_size(iterations, chunk_size, expected):
    assert chunk_length(iterations, chunk_size) == expected


def test_chunks_are_full_chunks_and_one_remainder():
    assert chunks(0, 400, 10) == [(i, 10) for i in range(0, 400, 10)]
    # A resume from 10 to 397: 38 chunks of 10 and one of 7, two programs.
    plan = chunks(10, 397, 10)
    assert plan[0] == (10, 10) and plan[-1] == (390, 7) and len(plan) == 39
    assert {length for _, length in plan} == {10, 7}
    assert sum(length for _, length in plan) == 387
    assert chunks(5, 5, 10) == []
    assert chunks(0, 3, 10) == [(0, 3)]


def test_seed_sharding_uses_as_many_devices_as_divide_the_seeds():
    assert len(jax.devices()) == 2  # tests/conftest.py
    for seeds, devices in ((4, 2), (3, 1), (2, 2), (1, 1), (6, 2), (5, 1)):
        sharding = seed_sharding(seeds)
        assert sharding.mesh.devices.size == devices, seeds
        assert sharding.mesh.axis_names == ("seed",)
        assert sharding.spec == PartitionSpec("seed")


def test_state_has_a_leading_seed_axis_sharded_over_the_devices(four_seeds, three_seeds):
    _, state, _ = four_seeds
    assert state["x"].shape == (4, 3) and state["iteration"].shape == (4,)
    assert len(state["x"].sharding.device_set) == 2
    np.testing.assert_array_equal(state["iteration"], np.full(4, 2 * CHUNK))
    _, state3, _ = three_seeds
    assert len(state3["x"].sharding.device_set) == 1


def test_step_returns_host_metrics_seed_by_iteration(four_seeds):
    runner, _, history = four_seeds
    assert all(isinstance(v, np.ndarray) for v in history.values())
    assert history["x/sum"].shape == (4, 2 * CHUNK)
    assert history["x"].shape == (4, 2 * CHUNK, 3)
    # Chunks follow each other: iterations 1..6 for every seed.
    np.testing.assert_array_equal(history["iteration"], np.tile(np.arange(1, 7), (4, 1)))
    np.testing.assert_allclose(history["x/sum"], history["x"].sum(-1), rtol=1e-5, atol=1e-6)
    assert runner.timings.iterations == 2 * CHUNK


def test_each_seed_equals_a_single_seed_run_without_vmap_or_sharding(four_seeds):
    _, _, history = four_seeds
    keys = jax.random.split(jax.random.PRNGKey(0), 4)
    for seed in range(4):
        expected = reference(keys[seed], 2 * CHUNK)
        np.testing.assert_allclose(history["x"][seed], expected["x"], rtol=1e-6, atol=1e-6)
    # Seeds differ from each other.
    assert not np.allclose(history["x"][0], history["x"][1])


def test_adding_seeds_leaves_the_first_seeds_unchanged(three_seeds, four_seeds):
    """Seed keys are split from one key; with JAX's partitionable threefry the first S keys of
    a split into S + 1 are those of a split into S, so seeds 0..2 of a 4-seed run (two
    devices) are seeds 0..2 of a 3-seed run (one device)."""
    _, _, three = three_seeds
    _, _, four = four_seeds
    for name in three:
        np.testing.assert_allclose(four[name][:3], three[name], rtol=1e-6, atol=1e-6)


def test_results_do_not_depend_on_the_number_of_devices(four_seeds, monkeypatch):
    one_device = jax.devices()[:1]
    with monkeypatch.context() as patch:
        patch.setattr(seed_runner.jax, "devices", lambda *args: one_device)
        runner = Runner(toy_init, toy_update, 4)
    assert runner.sharding.mesh.devices.size == 1
    _, history = run_chunks(runner, 2)
    _, _, two_devices = four_seeds
    for name in history:
        np.testing.assert_allclose(history[name], two_devices[name], rtol=1e-6, atol=1e-6)


def test_data_is_an_argument_of_one_program(four_seeds):
    """Two data values: one lowered program (the same text), and the data takes effect."""
    shift = lambda value: {"shift": np.full(3, value, np.float32)}
    runners = [Runner(toy_init, toy_update, 4, shift(v)) for v in (0.0, 1.0)]
    state = runners[0].init(jax.random.PRNGKey(0))
    lower = lambda r: r._programs.chunk.lower(state, r._replicated(INPUTS), r.data)
    texts = [lower(r).as_text() for r in runners]
    assert texts[0] == texts[1]
    (_, zero), (_, one) = (r.step(state, INPUTS) for r in runners)
    _, _, plain = four_seeds
    np.testing.assert_allclose(zero["x"], plain["x"][:, :CHUNK], rtol=1e-6, atol=1e-6)
    assert not np.allclose(one["x"], zero["x"])


def test_runners_of_one_program_key_share_their_compiled_programs(four_seeds):
    """A second runner of the same key and data shapes compiles nothing and computes with its
    own data; another key, seed count or data shape gets its own programs."""
    shift = lambda value, n=3: {"shift": np.full(n, value, np.float32)}
    first = Runner(toy_init, toy_update, 4, shift(0.0), program_key="toy")
    _, zero = first.step(first.init(jax.random.PRNGKey(0)), INPUTS)
    second = Runner(toy_init, toy_update, 4, shift(1.0), program_key="toy")
    state = second.init(jax.random.PRNGKey(0))
    second.compile(state, INPUTS)
    assert second._programs is first._programs and second.programs == 1
    _, one = second.step(state, INPUTS)
    unshared = Runner(toy_init, toy_update, 4, shift(1.0))
    _, expected = unshared.step(unshared.init(jax.random.PRNGKey(0)), INPUTS)
    np.testing.assert_array_equal(one["x"], expected["x"])
    assert not np.allclose(one["x"], zero["x"])
    others = [
        Runner(toy_init, toy_update, 4, shift(0.0), program_key="other"),
        Runner(toy_init, toy_update, 2, shift(0.0), program_key="toy"),
        Runner(toy_init, toy_update, 4, shift(0.0, n=1), program_key="toy"),
    ]
    assert all(r._programs is not first._programs for r in others)


def test_runners_share_programs_through_the_process_cache():
    """A runner with a program key builds its programs into the process's cache once."""
    program_cache.SHARED.clear()
    first = Runner(toy_init, toy_update, 2, program_key="cached")
    assert len(program_cache.SHARED) == 1
    second = Runner(toy_init, toy_update, 2, program_key="cached")
    assert second._programs is first._programs and len(program_cache.SHARED) == 1
    Runner(toy_init, toy_update, 2)  # no key: programs of its own, not kept
    assert len(program_cache.SHARED) == 1


def test_a_placed_state_steps_like_an_initial_one_with_empty_leaves():
    """A restored state (host arrays) with a zero-size leaf, as MJX states have: placed, it runs
    chunk after chunk on the programs compiled for a fresh state, with the same results."""

    def init(key, data=None):
        return {**toy_init(key), "empty": jnp.zeros((2, 0))}

    def update(state, flag, data=None):
        toy_state, metrics = toy_update({k: state[k] for k in ("key", "x", "iteration")}, flag)
        return {**toy_state, "empty": state["empty"]}, metrics

    fresh = Runner(init, update, 4, program_key="empty-leaves")
    state = fresh.init(jax.random.PRNGKey(0))
    state, _ = fresh.step(state, INPUTS)
    resumed = Runner(init, update, 4, program_key="empty-leaves")
    placed = resumed.place_state(jax.device_get(state))
    histories = []
    for runner, start in ((fresh, state), (resumed, placed)):
        for _ in range(2):
            start, metrics = runner.step(start, INPUTS)
        histories.append(metrics["x"])
    np.testing.assert_array_equal(*histories)
    assert resumed.programs == 1


def test_explicit_compile_then_step():
    runner = Runner(toy_init, toy_update, 2)
    state = runner.init(jax.random.PRNGKey(1))
    runner.compile(state, INPUTS)
    state, metrics = runner.step(state, INPUTS)
    np.testing.assert_array_equal(metrics["iteration"], [[1, 2, 3], [1, 2, 3]])
    assert runner.timings.iterations == CHUNK
    assert runner.programs == 1


def test_per_iteration_inputs_reach_every_seed_and_a_remainder_compiles_once(four_seeds):
    """The flags select, for every seed alike, which iterations measure x/norm; chunks of 3,
    3 and a remainder of 1 compile two programs and give the same history as 3 + 3 + 1 steps
    of one seed without the runner."""
    runner = Runner(toy_init, toy_update, 4)
    state = runner.init(jax.random.PRNGKey(0))
    history = None
    for inputs in (INPUTS, INPUTS, INPUTS[:1]):
        state, metrics = runner.step(state, inputs)
        history = concat_history(history, metrics)
    assert runner.programs == 2
    measured = ~np.isnan(history["x/norm"])
    np.testing.assert_array_equal(measured, np.tile([1, 0, 1, 1, 0, 1, 1], (4, 1)).astype(bool))
    np.testing.assert_allclose(
        history["x/norm"][measured], np.linalg.norm(history["x"], axis=-1)[measured], rtol=1e-5
    )
    _, _, six = four_seeds
    np.testing.assert_allclose(history["x"][:, :6], six["x"], rtol=1e-6, atol=1e-6)


def test_default_seed_batch_is_one_on_cpu():
    assert jax.default_backend() == "cpu"
    assert seed_runner.default_seed_batch() == 1
    assert Runner(toy_init, toy_update, 4).seed_batch == 1


@pytest.mark.parametrize("batch", [1, 2, 3, None])
def test_map_in_batches_equals_vmap_and_keeps_zero_size_leaves(batch):
    """Groups of seeds one after the other compute what one vmap over all seeds does, also
    with zero-size leaves (MJX states hold some) and a batch that does not divide the seeds
    (3 of 4 -> groups of 2)."""
    f = lambda tree: {"y": 2.0 * tree["x"] + 1.0, "empty": tree["empty"] + 1.0}
    tree = {"x": jnp.arange(12.0).reshape(4, 3), "empty": jnp.zeros((4, 0, 2))}
    mapped = jax.jit(seed_runner.map_in_batches(f, batch))(tree)
    expected = jax.vmap(f)(tree)
    np.testing.assert_array_equal(mapped["y"], expected["y"])
    assert mapped["empty"].shape == (4, 0, 2)


@pytest.mark.parametrize("seed_batch", [2, None])
def test_vmapped_seed_batches_give_the_sequential_results(four_seeds, seed_batch):
    """Two seeds per device, vmapped together or (the CPU default) one after the other."""
    runner = Runner(toy_init, toy_update, 4, seed_batch=seed_batch)
    _, history = run_chunks(runner, 2)
    _, _, sequential = four_seeds
    for name in history:
        np.testing.assert_allclose(history[name], sequential[name], rtol=1e-6, atol=1e-6)


def test_intention_runner_gives_each_seed_its_own_policies():
    """Seed s's policies start from the keys its own key splits into, and policy i trains on
    ``intentions[i]`` (a toy trainer; test_experts' experts train through the runner)."""

    def init(key):
        return {"w": jax.random.normal(key, (3,)), "iteration": jnp.zeros((), jnp.int32),
                "intention": jnp.full((), -1)}  # fmt: skip

    def update(state, intention):
        state = {"w": state["w"] + 1.0, "iteration": state["iteration"] + 1,
                 "intention": intention}  # fmt: skip
        return state, {"w": state["w"].sum()}

    trainer = RLTrainer(init=init, update=update, policy=None)
    runner = intention_runner(trainer, jnp.array([1, 0]), seeds=2)
    stop_after_first = lambda first, length, states, metrics: False
    first = runner.init(jax.random.PRNGKey(1))
    states = runner.run(first, chunks(0, 4, 2), lambda f, n: np.zeros(n, bool), stop_after_first)
    assert np.asarray(states["iteration"]).tolist() == [[2, 2], [2, 2]]  # stopped after one chunk
    assert np.asarray(states["intention"]).tolist() == [[1, 0], [1, 0]]
    w = np.asarray(first["w"])  # [seeds, intentions, 3]
    for seed, key in enumerate(jax.random.split(jax.random.PRNGKey(1), 2)):
        np.testing.assert_array_equal(w[seed], jax.vmap(init)(jax.random.split(key, 2))["w"])
    assert not np.allclose(w[0], w[1]) and not np.allclose(w[0, 0], w[0, 1])
    np.testing.assert_allclose(np.asarray(states["w"]), w + 2.0, rtol=1e-6)
