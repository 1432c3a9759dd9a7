"""Models side by side: ``softpinn reproduce TASK --jobs N``.

After the data stages, every model of the run (a task's Lagrangian, Hamiltonian or black-box
network on one of its data sets; the experiment's network on one rate and preprocessing) runs its
own chain of stages (train, predict, and the analyses: :func:`.pipeline.model_stages`,
:func:`.experiment.model_stages`) in one of ``N`` worker processes; the chains write to folders
of their own, so they never touch each other's files. The calling process then gathers every
model's results from the stages' records (``done.json``) as a second call would, and writes the
report: a run with ``--jobs`` gives the same files and numbers as one without, sooner.

Workers are fresh processes (``spawn``: JAX cannot be forked once started) that inherit the
environment (``XLA_FLAGS`` included); their log lines and training progress come back through a
queue. The first Ctrl-C lets every training finish its epoch and save a checkpoint, as a serial
run does; a second one stops the workers at once.
"""

from __future__ import annotations

import dataclasses
import multiprocessing
import os
import queue as queue_mod
import signal
import time
from collections.abc import Callable
from pathlib import Path

import jax

from softpinn.bridge.figures.figsave import draft_figures
from softpinn.bridge.tasks.plan import ReproduceConfig
from softpinn.bridge.tasks.stages import Stages
from softpinn.progress import Progress, ProgressFn, TrainProgress

__all__ = ["Probe", "run_in_worker", "run_models", "suggest_jobs", "unfinished"]

#: how long an interrupted run waits for its workers to save their checkpoints
INTERRUPT_GRACE_S = 120.0


class NotDone(Exception):
    """A stage of a model's chain has not finished with the plan's settings."""


class Probe(Stages):
    """Stages that only read: a stage not finished raises :class:`NotDone`."""

    def run(self, name, settings, fn):
        if self.finished(name, settings) is None:
            raise NotDone(name)
        return super().run(name, settings, fn)


class WorkerInterrupted(Exception):
    """A worker's model was interrupted (Ctrl-C); its training saved a checkpoint."""


def suggest_jobs(models: int, log: Callable[[str], None]) -> None:
    """On a machine with cores to spare, say once that ``--jobs`` would use them."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    if models > 1 and (cores or 1) > 1:
        log(f"[models] {models} models, one at a time: --jobs {min(models, cores)} would train "
            f"{min(models, cores)} side by side on this machine's {cores} cores")


def unfinished(chain: Callable[[Stages], object], out: Path) -> bool:
    """Whether ``chain(stages)`` would run a stage (one has not finished with its settings)."""
    try:
        chain(Probe(out, lambda _: None))
    except NotDone:
        return True
    return False


# ------------------------------------------------------------------------------ the workers

_QUEUE = None  # the worker's end of the queue (set by _start)


def _start(queue) -> None:
    global _QUEUE
    _QUEUE = queue
    # Ctrl-C reaches every process of the terminal: a worker heeds it only while it trains
    # (learn's DeferredInterrupt: finish the epoch, save a checkpoint, stop); the caller stops
    # the rest
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def run_in_worker(config: ReproduceConfig, key: str, out: str,
                  body: Callable[[Stages, Callable[[dict], None]], object]) -> list[str]:
    """In a worker: ``body(stages, progress)`` runs one model's chain in float64, with the run's
    figure mode, its log lines and training progress sent to the caller under ``key``; returns
    the names of the stages it ran."""
    jax.config.update("jax_enable_x64", True)

    stages = Stages(Path(out), lambda line: _QUEUE.put(("log", key, line)))

    def progress(event: TrainProgress) -> None:
        _QUEUE.put(("progress", key, event))

    try:
        with draft_figures(config.quick):
            body(stages, progress)
    except KeyboardInterrupt:  # training saved a checkpoint; a plain error crosses the pool
        raise WorkerInterrupted(f"{key}: interrupted") from None
    return sorted(stages.ran)


# ------------------------------------------------------------------------------ the caller


def run_models(work: list, *, jobs: int, log: Callable[[str], None],
               progress: ProgressFn | None, after: list | None = None) -> set[str]:
    """Run ``work`` (``[(key, function, args, epochs)]``: a module-level ``function(*args)``
    runs one model's chain and returns the names of the stages it ran), ``jobs`` at a time;
    returns the names of every stage the workers ran. ``progress`` gets a
    :class:`~softpinn.progress.Progress` of unit "model" and phase "start" first, then each
    worker's training events with ``model`` set to its key, and one of phase "done" (``label``:
    the key) when a model's chain has finished.
    ``after``: ``[(key, needs, function, args)]``, work that waits for the models ``needs``
    (keys of ``work``; those not in it count as finished) and then takes the next free
    worker, e.g. a data set's report figures once its models are done (drawn while the other
    models train)."""
    after = list(after or [])
    if not work and not after:
        return set()
    n = min(jobs, len(work) + len(after))
    log(f"[models] {len(work)} model(s) to train and analyse"
        + (f", {len(after)} data set(s)' figures to draw" if after else "") + f", {n} at a time")
    if progress is not None:
        progress(Progress(done=0, total=len(work), unit="model", phase="start"))
    ctx = multiprocessing.get_context("spawn")
    queue = ctx.Queue()
    pool = ctx.Pool(n, initializer=_start, initargs=(queue,))

    def drain() -> None:
        while True:
            try:
                what, key, payload = queue.get_nowait()
            except queue_mod.Empty:
                return
            if what == "log":
                log(payload)
            elif progress is not None:
                progress(dataclasses.replace(payload, model=key))

    ran: set[str] = set()
    models = {key for key, _, _, _ in work}
    pending = {key: pool.apply_async(fn, args) for key, fn, args, _ in work}

    def release() -> None:  # the waiting work whose models have all finished
        for item in [a for a in after if not (set(a[1]) & models) - done]:
            after.remove(item)
            pending[item[0]] = pool.apply_async(item[2], item[3])

    done: set[str] = set()
    try:
        release()
        while pending:
            drain()
            for key in [k for k, r in pending.items() if r.ready()]:
                try:
                    ran.update(pending.pop(key).get())  # a worker's error is raised here
                except WorkerInterrupted:  # Ctrl-C reached the worker first
                    raise KeyboardInterrupt from None
                done.add(key)
                if progress is not None and key in models:
                    progress(Progress(done=len(done & models), total=len(models), unit="model",
                                      label=key, phase="done"))
                release()
            time.sleep(0.1)
        drain()
        pool.close()
        pool.join()
    except KeyboardInterrupt:
        log("interrupted: the models in training save a checkpoint (Ctrl-C again: stop now)")
        try:
            deadline = time.monotonic() + INTERRUPT_GRACE_S
            while any(not r.ready() for r in pending.values()) and time.monotonic() < deadline:
                drain()
                time.sleep(0.1)
        finally:
            pool.terminate()
            pool.join()
        raise
    except BaseException:
        pool.terminate()
        pool.join()
        raise
    return ran
