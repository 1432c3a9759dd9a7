"""One trial of a sweep as a Ray Tune :class:`ray.tune.Trainable`: a normal
:func:`softpinn.learn.train` run writing its own run directory, reporting its test loss
to Tune at every evaluation so that a scheduler (ASHA) can stop it early.

This module imports Ray at the top: only :mod:`.tuner` imports it, which only
:func:`softpinn.bridge.sweep.sweep` imports, after checking that Ray is installed.

``train`` runs in a thread of the trial's actor; its ``progress`` callback hands each evaluation
to :meth:`Trial.step` and waits until Tune asks for the next one. When Tune stops the trial
(ASHA decided it is among the worse ones, or the sweep is interrupted), :meth:`Trial.cleanup`
lets the waiting callback raise KeyboardInterrupt, which ``train`` answers as it answers Ctrl-C:
it writes the best model so far, the history, the metrics and a checkpoint, so a stopped trial
is a complete run directory (``softpinn train --resume`` continues it).
"""

from __future__ import annotations

import os
import queue
import sys
import threading
from pathlib import Path

from ray import tune

from softpinn.errors import UserError
from softpinn.learn import NonFiniteStart, TrainConfig, TrainingDiverged, read_json, train
from softpinn.progress import TrainProgress


class Trial(tune.Trainable):
    """``config``: ``{"trial": NAME}``; ``specs``: NAME -> ``{"name", "config"
    (TrainConfig.to_dict()), "dir", "force", "gpus"}``; ``data``: the
    :class:`softpinn.learn.Dataset` (``data`` and ``specs`` go once through Ray's object store,
    so the nodes of a cluster need not see the file).

    An actor runs one trial after another (:meth:`reset_config`): the compiled training
    programs stay in its process, so trials that differ only in settings that are not compiled
    in (lr, seed, patience, ...; see :class:`softpinn.learn.ProgramCache`) compile once."""

    def setup(self, config, data=None, specs=None):
        self._data = data
        self._specs = specs
        self._start(config)

    def _start(self, config) -> None:
        spec = self._specs[config["trial"]]
        if "jax" not in sys.modules:
            if not spec.get("gpus"):
                os.environ.setdefault("JAX_PLATFORMS", "cpu")  # a CPU trial leaves GPUs alone
            elif spec["gpus"] < 1:  # trials sharing a GPU must not take all of its memory
                os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
        self._spec = spec
        self._results: queue.Queue = queue.Queue()
        self._go = threading.Semaphore(0)
        self._stop = threading.Event()
        self._detached = threading.Event()
        self._waiting = False
        self._last_epoch = 0
        self._warnings: list[str] = []
        self._thread = threading.Thread(target=self._work, name="softpinn-trial", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ the training thread

    def _progress(self, event: TrainProgress) -> None:
        if event.test_loss is None or event.epoch == 0 or self._detached.is_set():
            return  # only evaluations after training started are reported
        self._last_epoch = event.epoch
        self._results.put(("report", {
            "epoch": int(event.epoch),
            "phase": event.phase,
            "test_loss": float(min(event.test_loss)),
            "train_loss": float(min(event.train_loss)),
            "best_test_loss": float(min(event.best_test_loss)),
            "status": "running",
        }))
        self._go.acquire()
        if self._stop.is_set():
            raise KeyboardInterrupt  # train() writes a loadable run, then re-raises

    def _work(self) -> None:

        spec = self._spec
        try:
            config = TrainConfig.from_dict(spec["config"])
            try:
                result = train(self._data, config, spec["dir"], progress=self._progress,
                               force=spec["force"], warn=self._warnings.append)
                metrics, status = result.members[0].metrics, "completed"
            except NonFiniteStart:
                raise
            except TrainingDiverged:
                metrics = read_json(Path(spec["dir"]) / "metrics.json")
                status = "diverged"
            self._results.put(("done", self._final(metrics, status)))
        except KeyboardInterrupt:
            self._results.put(("stopped", None))
        except BaseException as exc:  # noqa: BLE001 - handed to Tune, which records it
            self._results.put(("error", exc))

    def _final(self, metrics: dict, status: str) -> dict:
        best = metrics.get("best_test_loss")
        return {
            "epoch": int(metrics.get("epochs_run", self._last_epoch)),
            "best_test_loss": float("inf") if best is None else float(best),
            "test_loss": float("nan") if metrics.get("final_test_loss") is None
            else float(metrics["final_test_loss"]),
            "status": status,
            "warnings": list(self._warnings),
        }

    # ------------------------------------------------------------------ Tune's side

    def step(self) -> dict:
        if self._waiting:
            self._waiting = False
            self._go.release()  # let the training thread go on to the next evaluation
        kind, payload = self._results.get()
        if kind == "report":
            self._waiting = True
            return payload
        # Tune wants the metrics in every result; NaN (which ASHA ignores) where there are none,
        # and no epoch, so that ASHA does not record the trial at a rung
        none = {"best_test_loss": float("nan"), "test_loss": float("nan"), "done": True}
        if kind == "error":
            if isinstance(payload, UserError):  # one line, no traceback
                return {**none, "status": "error", "error": " ".join(str(payload).split())}
            raise payload
        if kind == "stopped":  # interrupted without Tune asking: report what there is
            return {**none, "status": "interrupted"}
        return {**payload, "done": True}

    def reset_config(self, new_config) -> bool:
        self._finish()
        self._start(new_config)
        return True

    def cleanup(self) -> None:
        self._finish()

    def _finish(self) -> None:
        """End the running trial: a trial stopped before its last AdamW epoch is interrupted
        (its run directory is written as on Ctrl-C), a later one is let finish."""
        if self._thread.is_alive():
            if self._last_epoch >= self._spec["config"]["epochs"]:
                self._detached.set()  # stopped after its last AdamW epoch: let it finish
            else:
                self._stop.set()
            self._go.release()
            self._thread.join()
