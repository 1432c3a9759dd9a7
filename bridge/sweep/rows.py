"""One trial's row of a sweep's results: its settings, what its run directory holds (best test
loss, epochs run, seconds) and its status, read from the run's :class:`StopReason` (never from
the wording of its ``stopped`` sentence). No Ray here: Tune's result is read through its
``metrics`` and ``error`` attributes."""

from __future__ import annotations

import math
from pathlib import Path

from softpinn.bridge.sweep.space import Trial
from softpinn.learn import Stop, StopReason, read_json

__all__ = ["trial_row"]


def _status(trial: Trial, result, finished: bool, root: Path, scheduler: str,
            metrics: dict | None, last: dict) -> tuple[str, bool]:
    """(the row's status, stopped early or not)."""
    error = None if result is None else result.error
    if error is not None:
        lines = [s for s in str(error).strip().splitlines() if s.strip()]
        status = "error: " + (lines[-1].strip() if lines else type(error).__name__)
        if (root / "tune" / trial.name / "error.txt").is_file():
            status += f" (traceback: tune/{trial.name}/error.txt)"
        return status, False
    if last.get("status") == "error":
        return f"error: {last.get('error')}", False
    if result is None:
        return "not run", False
    if metrics is None:
        return ("failed: no run directory" if finished else "not run (interrupted)"), False
    if not finished:
        return "interrupted", False
    reason = Stop.read(metrics).reason
    if last.get("status") == "diverged" or reason is StopReason.DIVERGED:
        return "diverged", False
    if reason.early:
        return f"early stop ({reason.value})", True
    if reason is StopReason.TARGET:
        return "reached the target loss", False
    if reason in (StopReason.RUNNING, StopReason.INTERRUPTED):  # cut short by the scheduler
        return (f"stopped by ASHA at epoch {metrics.get('epochs_run')}" if scheduler == "asha"
                else "interrupted"), True
    return "completed", False


def trial_row(trial: Trial, result, finished: bool, root: Path, scheduler: str) -> dict:
    """The row of ``trial``: ``result`` is its ``ray.tune.Result`` (None: never started),
    ``finished`` whether Tune finished it (not interrupted), ``root`` the sweep's folder."""
    tdir = root / "trials" / trial.name
    last = dict(result.metrics or {}) if result is not None else {}
    metrics = None
    if (tdir / "metrics.json").is_file() and (tdir / "model.eqx").is_file():
        try:
            metrics = read_json(tdir / "metrics.json")
        except Exception:  # noqa: BLE001 - a damaged file: the row says so
            metrics = None
    status, stopped_early = _status(trial, result, finished, root, scheduler, metrics, last)
    best = None if metrics is None else metrics.get("best_test_loss")
    return {
        "trial": trial.name,
        "settings": dict(trial.settings),
        "seed": trial.seed,
        "best_test_loss": None if best is None or not math.isfinite(best) else float(best),
        "final_test_loss": None if metrics is None else metrics.get("final_test_loss"),
        "epochs_run": None if metrics is None else metrics.get("epochs_run"),
        "epochs": trial.config.epochs,
        "stopped_early": stopped_early,
        "status": status,
        "seconds": None if metrics is None else metrics.get("seconds"),
        "wall_seconds": None if last.get("time_total_s") is None
        else round(float(last["time_total_s"]), 3),
        "path": f"trials/{trial.name}" if metrics is not None else None,
        "warnings": list(last.get("warnings") or []),
    }
