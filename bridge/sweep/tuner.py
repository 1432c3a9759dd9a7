"""The trials of a sweep through Ray Tune: a Tuner over one :class:`.trial.Trial` per trial name,
ASHA or FIFO scheduling, and a callback that hands every evaluation and finished trial to the
caller's ``progress``.

This module imports Ray at the top: only :func:`softpinn.bridge.sweep.sweep` imports it, after
checking that Ray is installed.
"""

from __future__ import annotations

import contextlib
import io
import logging

from ray import tune
from ray.tune.schedulers import ASHAScheduler, FIFOScheduler

from softpinn.bridge.sweep.config import SweepConfig
from softpinn.bridge.sweep.trial import Trial as TrialTrainable

__all__ = ["run_trials"]


def _trial_dirname(trial) -> str:
    return trial.config["trial"]


def run_trials(trials, specs, data, root, config: SweepConfig, *, verbose, progress):
    """Run the trials; return ({trial name: ray.tune.Result}, the names of the trials that
    finished: completed, stopped by the scheduler or failed, not interrupted)."""
    max_t = max(t.config.epochs for t in trials)
    if config.scheduler == "asha":
        grace = config.grace_period or max(1, max_t // 10)
        sched = ASHAScheduler(time_attr="epoch", max_t=max_t, grace_period=grace,
                              reduction_factor=config.reduction_factor, stop_last_trials=False)
    else:
        sched = FIFOScheduler()
    trainable = tune.with_resources(
        tune.with_parameters(TrialTrainable, data=data, specs={s["name"]: s for s in specs}),
        {"cpu": config.cpus_per_trial, "gpu": config.gpus_per_trial})
    events = _callback(progress, len(specs))
    tuner = tune.Tuner(
        trainable,
        param_space={"trial": tune.grid_search([s["name"] for s in specs])},
        tune_config=tune.TuneConfig(
            metric=config.metric, mode="min", scheduler=sched, num_samples=1,
            max_concurrent_trials=config.max_concurrent, trial_dirname_creator=_trial_dirname,
            reuse_actors=True,
        ),
        run_config=tune.RunConfig(
            name="tune", storage_path=str(root), verbose=verbose, log_to_file=True,
            checkpoint_config=tune.CheckpointConfig(checkpoint_frequency=0,
                                                    checkpoint_at_end=False),
            callbacks=[events],
        ),
    )
    quiet = contextlib.redirect_stdout(io.StringIO()) if verbose == 0 else contextlib.nullcontext()
    tune_log = logging.getLogger("ray.tune")
    level = tune_log.level
    if verbose == 0:  # Tune's messages (an interruption, a trial's traceback) stay in OUT/tune
        tune_log.setLevel(logging.CRITICAL)
    try:
        with quiet:
            results = tuner.fit()
    finally:
        tune_log.setLevel(level)
    grid = {}
    for i in range(len(results)):
        name = (results[i].config or {}).get("trial")  # no config: never started
        if name is not None:
            grid[name] = results[i]
    return grid, set(events.names)


def _callback(progress, total):
    """A Ray Tune callback (in this process) that hands ``progress`` one dict per event:
    ``{"event": "result" | "complete" | "error", "trial", "epoch", "best_test_loss",
    "finished", "total"}`` (and one ``"start"`` from :func:`~softpinn.bridge.sweep.sweep` once
    Ray is up)."""

    class Progress(tune.Callback):
        def __init__(self):
            self.finished = 0
            self.names: list[str] = []

        def _send(self, event, trial, result):
            if event != "result":
                self.finished += 1
                self.names.append(trial.config["trial"])
            if progress is None:
                return
            result = result or {}
            progress({"event": event, "trial": trial.config["trial"],
                      "epoch": result.get("epoch"),
                      "best_test_loss": result.get("best_test_loss"),
                      "finished": self.finished, "total": total})

        def on_trial_result(self, iteration, trials, trial, result, **info):
            self._send("result", trial, result)

        def on_trial_complete(self, iteration, trials, trial, **info):
            self._send("complete", trial, trial.last_result)

        def on_trial_error(self, iteration, trials, trial, **info):
            self._send("error", trial, trial.last_result)

    return Progress()
