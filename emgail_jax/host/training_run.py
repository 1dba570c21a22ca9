"""Trains a run into its directory: the chunk loop, and what it leaves after each chunk and at
the end (``metrics.csv``, TensorBoard, checkpoints, snapshots, ``summary.json``).

In a run of several processes (``jax.distributed``) every process trains its share of the
seeds and takes part in every gather; process 0 alone writes.
"""

from __future__ import annotations

import dataclasses
import os
import signal

import jax
import numpy as np
from jax.experimental import multihost_utils

from emgail_jax.host import checkpoints, records, stopping
from emgail_jax.host.history import concat_history
from emgail_jax.host.progress import ProgressBar
from emgail_jax.host.results_pipeline import final_results
from emgail_jax.host.run_spec import RunError, RunSpec, read_summary, stored_sources
from emgail_jax.host.schedule import evaluation_plan
from emgail_jax.host.seed_runner import Runner, chunks, gather
from emgail_jax.method.batches import DemonstrationPairs
from emgail_jax.method.training import RunData
from emgail_jax.variants import make_train

SUMMARY = "summary.json"


def train(
    spec: RunSpec,
    problem,
    out: str,
    *,
    resume: bool = False,
    progress: bool = True,
    signals: stopping.Signals | None = None,
    wandb_run=None,
) -> dict:
    """Trains (or, with ``resume``, continues) the run ``spec`` and writes its outputs to ``out``
    (and the metrics to ``wandb_run``, a W&B run of :func:`~emgail_jax.host.records.start_wandb`).

    Returns the summary as written to ``summary.json``; its ``status`` is ``"completed"`` or
    ``"interrupted"`` (a first signal within the chunk loop of ``signals``, the command's).
    """
    config = spec.config.resolved(problem.env)
    runner, parameters = _runner(spec, problem, config)
    writes = jax.process_index() == 0
    summary = {**summary_header(spec, problem, config), **_where(runner), "parameters": parameters}
    earlier = read_summary(out).get("timings", NO_TIMINGS) if resume else NO_TIMINGS
    write = _SummaryWriter(os.path.join(out, SUMMARY), writes)
    if not resume:  # before the first compile: from then on a killed run can be resumed
        write.running(summary, earlier)
    state, history, done = _first_state(runner, out, resume, jax.random.PRNGKey(spec.first_seed))
    if resume:  # once the checkpoint is read: a failed restore leaves the summary as it was
        write.running(summary, earlier)
    schedule = config.schedule
    saver = Saver(out, schedule.checkpoint_every, schedule.snapshot_every, writes, last_saved=done)
    recorder = ChunkRecorder(
        schedule.iterations, history, done, saver, signals or stopping.Signals()
    )
    timings = earlier
    if done < schedule.iterations:
        log = records.MetricsLog(
            out,
            keep_until=done if resume else None,
            enabled=writes,
            wandb_run=wandb_run,
            first_seed=spec.first_seed,
        )
        state = recorder.run(runner, state, schedule, log, progress and writes)
        timings = _added(earlier, runner.timings)
    summary.update(timings=timings, iterations_done=recorder.iteration, **recorder.status())
    final = final_results(
        recorder.history,
        problem=problem,
        config=config,
        states=saver.host_state if saver.host_state is not None else gather(state),
        demos=jax.device_get(runner.data.demos),
        timings=timings,
    )
    summary["final"] = final.to_summary()
    write.final(summary)
    return records.to_json_value(summary)


NO_TIMINGS = {"compile_time_s": 0.0, "train_time_s": 0.0, "iterations": 0}


def _where(runner: Runner) -> dict:
    """``summary.json``'s record of where the run trained."""
    return {
        "devices": [str(d) for d in runner.sharding.mesh.devices.flat],
        "processes": jax.process_count(),
        "machine": records.machine_facts(),
    }


@dataclasses.dataclass(frozen=True)
class _SummaryWriter:
    """``summary.json`` written atomically, by process 0 only."""

    path: str
    writes: bool

    def running(self, summary: dict, timings: dict) -> None:
        self.final({**summary, "status": "running", "timings": timings})

    def final(self, summary: dict) -> None:
        if self.writes:
            records.write_json(self.path, summary)


def _added(earlier: dict, timings) -> dict:
    """The run's timings: those of its earlier parts and this process's runner's."""
    return {
        "compile_time_s": earlier["compile_time_s"] + timings.compile_s,
        "train_time_s": earlier["train_time_s"] + timings.train_s,
        "iterations": earlier["iterations"] + timings.iterations,
    }


@dataclasses.dataclass
class Saver:
    """A checkpoint every ``checkpoint_every`` iterations and at the end (or on a stop
    request), and a snapshot of the learned networks after each chunk that reaches a multiple
    of ``snapshot_every`` and at the end (0: none). ``host_state``: every seed's state as last
    checkpointed, on the host."""

    out: str
    checkpoint_every: int
    snapshot_every: int
    writes: bool  # process 0 of the run
    last_saved: int = 0
    host_state: object = None

    def after_chunk(self, first: int, iteration: int, state, history, finished: bool) -> None:
        if finished or iteration - self.last_saved >= self.checkpoint_every:
            host_state = gather(state)  # every process takes part
            if self.writes:
                checkpoints.save(self.out, iteration, host_state, history)
            self.last_saved, self.host_state = iteration, host_state
        every = self.snapshot_every
        if every and (finished or iteration // every > first // every):
            snapshot = gather(checkpoints.snapshot_of(state))  # every process takes part
            if self.writes:
                checkpoints.save_snapshot(self.out, iteration, snapshot)


@dataclasses.dataclass
class ChunkRecorder:
    """After each chunk: its metrics logged and appended to the ``history``, the progress bar,
    the :class:`Saver`, and whether to go on (no stop requested)."""

    iterations: int  # the run's total
    history: dict | None
    iteration: int  # iterations done
    saver: Saver
    signals: stopping.Signals
    stopped_by: int | None = None  # the signal that stopped the run, in every process
    _log: records.MetricsLog | None = None
    _bar: ProgressBar | None = None

    def run(self, runner: Runner, state, schedule, log: records.MetricsLog, progress: bool):
        """Steps ``state`` from the iterations done to the run's total (unless stopped), each
        chunk's metrics to ``log``, a progress bar shown when ``progress``; returns the last
        state. Chunks only group iterations into compiled calls: they change no result."""
        plan = chunks(self.iteration, self.iterations, schedule.chunk_size)
        evaluating = lambda first, length: evaluation_plan(
            first, length, self.iterations, schedule.eval_every
        )
        fields = {"ERD": "-", "acc": "-"}
        self._log = log
        self._bar = ProgressBar(
            "training", self.iterations, fields, self.iteration, enabled=progress
        )
        try:
            with self.signals.stoppable():
                return runner.run(state, plan, evaluating, self.after_chunk)
        finally:
            self._bar.close()
            log.close()

    def status(self) -> dict:
        """``summary.json``'s ``status`` (and ``stopped_by`` for an interrupted run)."""
        if self.iteration >= self.iterations:
            return {"status": "completed"}
        return {"status": "interrupted", "stopped_by": signal.Signals(self.stopped_by).name}

    def after_chunk(self, first: int, length: int, state, metrics: dict) -> bool:
        self._log.write(first, metrics)
        self.history = concat_history(self.history, metrics)
        self.iteration = first + length
        self._bar.update(length, **progress_fields(self.history))
        self.stopped_by = _agreed_signal(self.signals.requested)
        finished = self.iteration >= self.iterations or self.stopped_by is not None
        self.saver.after_chunk(first, self.iteration, state, self.history, finished)
        self.signals.progressed()
        return self.stopped_by is None


def progress_fields(history: dict[str, np.ndarray]) -> dict[str, str]:
    """The progress bar's latest ERD and accuracy: means over seeds of the last measured
    values, or "-" when undefined (no labels, nothing evaluated yet)."""
    fields = {}
    for label, name in (("ERD", "eval/erd"), ("acc", "eval/cluster_accuracy")):
        values = history[name]
        measured = np.flatnonzero(~np.all(np.isnan(values), 0))
        fields[label] = "-" if not len(measured) else f"{np.nanmean(values[:, measured[-1]]):.3f}"
    return fields


def _agreed_signal(requested: int | None) -> int | None:
    """The signal that asks the run to stop, as every process sees it: in a run of several
    processes, one asked is all asked (else they would part at the next collective)."""
    if jax.process_count() == 1:
        return requested
    asked = multihost_utils.process_allgather(np.int32(requested or 0))
    return int(asked.max()) or None


def _runner(spec: RunSpec, problem, config) -> tuple[Runner, dict[str, int]]:
    """The multi-seed runner of the run's update, and the update's parameter counts."""
    env = problem.env
    pairs = DemonstrationPairs.create(
        problem.demos, problem.random_returns, problem.true_intentions
    )
    if config.method.m_step.form.airl and pairs.next_observations is None:
        raise RunError(
            "discriminator_form airl needs each demonstration's final observation (s' of its "
            "last pair); these demonstrations store none"
        )
    data = RunData.create(pairs, env, config.info_weight)
    init, update = make_train(config.method, env)
    # Runs of one process that differ only in data (the sweep's driver radii) share programs.
    program_key = (config.program_key(), env.program_key())
    runner = Runner(
        init,
        update,
        spec.seeds,
        data,
        seed_batch=config.schedule.seed_batch,
        program_key=program_key,
    )
    return runner, parameter_counts(init, data)


def _first_state(runner: Runner, out: str, resume: bool, key):
    """``(state, history, iterations done)``: restored from the last checkpoint, or new."""
    if resume and checkpoints.latest_iteration(out) is not None:
        host_state, history, done = checkpoints.restore(out, runner.abstract_state(key))
        return runner.place_state(host_state), history, done
    return runner.init(key), None, 0


def parameter_counts(init, data) -> dict[str, int]:
    """Learnable parameters of each network of one seed, and their total (the paper's Table 2
    "#LP" counts policy, value, discriminator and posterior)."""
    state = jax.eval_shape(init, jax.random.PRNGKey(0), data)
    counts = {
        name: sum(int(np.prod(leaf.shape)) for leaf in jax.tree.leaves(params))
        for name, params in state.network_parameters().items()
    }
    return {**counts, "total": sum(counts.values())}


def summary_header(spec: RunSpec, problem, config) -> dict:
    """The head of ``summary.json``: what the run is (and what W&B takes as its config)."""
    env = problem.env
    return {
        "env": env.name,
        "env_options": env.options(),
        "algo": config.method.algo.value,
        "intentions": env.num_intentions,
        "seeds": spec.seeds,
        "first_seed": spec.first_seed,
        "iterations": config.schedule.iterations,
        "random_episodes": spec.random_episodes,
        "demonstrations": {
            "source": problem.demos_source,
            "path": stored_sources(spec.demo_sources),
            "seed": spec.demo_seed,
            "pairs": len(problem.demos),
            "intentions": problem.true_intentions,
            "labels": problem.demos.intentions is not None,
            "expert_returns": problem.demos.expert_returns is not None,
        },
        "config": config.to_dict(),
    }
