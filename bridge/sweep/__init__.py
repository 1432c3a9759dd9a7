"""Hyperparameter sweeps and seed ensembles through Ray Tune (``pip install 'softpinn[ray]'``).

:func:`sweep` trains one :func:`softpinn.learn._train.train` run per trial, a grid and/or random
draws over :class:`learn._config.TrainConfig` settings times seeds (:mod:`.space`), on a local
Ray instance or a Ray cluster (``address``), with ASHA stopping the worse trials early
(:mod:`.trial`), and writes::

    OUT/trials/<name>/   every trial a normal run directory (predict, analyze, --resume)
    OUT/results.csv      one row per trial: settings, best test loss, epochs run, stopped
    OUT/results.json     early, status, seconds; the best trial's folder
    OUT/results.md       the same, ranked, with the plot and the best trial linked
    OUT/sweep.png        best test loss against each swept setting (log scale)
    OUT/best             a link to the best trial's folder
    OUT/tune/            Ray Tune's own experiment folder (its logs and per-trial results)

Ray is imported only inside :func:`sweep` (and by :mod:`.trial`, which only it imports), so
``import softpinn.bridge`` works without it.
"""

from __future__ import annotations

import contextlib
import io
import logging
import math
import os
import shutil
import signal
from dataclasses import dataclass
from pathlib import Path

from softpinn.bridge.base import outputs
from softpinn.bridge.sweep.space import Random, Trial, check_space, make_trials, parse_space
from softpinn.errors import UserError
from softpinn.learn import Dataset, TrainConfig, dataset_info, load_dataset, read_json
from softpinn.symbolic import ray_init

__all__ = ["METRICS", "RAY_MISSING", "SCHEDULERS", "Random", "SweepResult", "Trial",
           "make_trials", "parse_space", "sweep"]

SCHEDULERS = ("asha", "none")
#: What ASHA compares at its rungs: the best test loss so far (it never rises), or the test loss
#: of the latest evaluation. The trials are ranked by their best test loss either way (the loss
#: of the model each run directory keeps).
METRICS = ("best_test_loss", "test_loss")
RAY_MISSING = "softpinn sweep needs Ray: pip install 'softpinn[ray]'"


@dataclass
class SweepResult:
    """What :func:`sweep` returns: the output folder, one row per trial (best first) and the
    best row (None if no trial reached a finite loss)."""

    out: Path
    rows: list[dict]
    best: dict | None

    @property
    def best_dir(self) -> Path | None:
        return None if self.best is None else self.out / self.best["path"]


def _import_ray():
    try:
        import ray
        from ray import tune
    except ImportError:
        raise UserError(RAY_MISSING) from None
    return ray, tune


def _check(scheduler, metric, cpus_per_trial, gpus_per_trial, max_concurrent, grace_period,
           reduction_factor, num_cpus):
    if scheduler not in SCHEDULERS:
        raise UserError(f"scheduler: expected one of {', '.join(SCHEDULERS)}, got {scheduler!r}")
    if metric not in METRICS:
        raise UserError(f"metric: expected one of {', '.join(METRICS)}, got {metric!r}")
    for name, v, low in (("cpus_per_trial", cpus_per_trial, 0), ("gpus_per_trial",
                                                                 gpus_per_trial, None)):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or (
                v <= 0 if low == 0 else v < 0):
            raise UserError(f"{name}: expected a number {'> 0' if low == 0 else '>= 0'}, "
                            f"got {v!r}")
    for name, v in (("max_concurrent", max_concurrent), ("grace_period", grace_period),
                    ("num_cpus", num_cpus)):
        if v is not None and (isinstance(v, bool) or not isinstance(v, int) or v < 1):
            raise UserError(f"{name}: expected an integer >= 1, got {v!r}")
    if isinstance(reduction_factor, bool) or not isinstance(reduction_factor, (int, float)) or \
            not reduction_factor > 1:
        raise UserError(f"reduction_factor: expected a number > 1, got {reduction_factor!r}")


def _check_reachable(address: str) -> None:
    """A ``HOST:PORT`` nobody answers at is one line now, not Ray's minutes of retries."""
    import socket

    host, sep, port = address.removeprefix("ray://").rpartition(":")
    if address == "auto" or not sep or not port.isdigit():
        return  # 'auto' (the cluster this node belongs to) and the like: Ray decides
    try:
        socket.create_connection((host, int(port)), timeout=10).close()
    except OSError as exc:
        raise UserError(f"address: nothing answers at {address} ({exc.strerror or exc}); is "
                        "'ray start --head' running there, on that port?") from None


def _trial_dirname(trial) -> str:
    return trial.config["trial"]


def sweep(
    data,
    base_config: TrainConfig,
    space: dict,
    out: str | Path,
    *,
    samples: int = 1,
    seeds: int = 1,
    address: str | None = None,
    scheduler: str = "asha",
    metric: str = "best_test_loss",
    cpus_per_trial: float = 1,
    gpus_per_trial: float = 0,
    max_concurrent: int | None = None,
    num_cpus: int | None = None,
    grace_period: int | None = None,
    reduction_factor: float = 2,
    random_seed: int = 0,
    force: bool = False,
    verbose: int = 0,
    progress=None,
) -> SweepResult:
    """Train every trial of ``space`` over ``base_config`` on ``data`` through Ray Tune; write
    ``out`` (see the module's docstring) and return the ranked rows.

    ``space``: setting -> a list of values (a grid) or a random range (``"log:1e-4:1e-2"``, a
    :class:`Random`); ``samples`` draws of the random settings, each with every combination of
    the grid, each with ``seeds`` seeds (one trial each; ``base_config.seeds`` must be 1).
    ``address``: a Ray cluster (``"auto"``: the one this node belongs to, ``"HOST:PORT"``,
    ``"ray://HOST:10001"``); None starts a new local Ray instance (unless this process is
    connected to one already) and stops it after. On a cluster ``out`` must be a folder every
    node sees at the same path.
    ``scheduler``: "asha" (asynchronous successive halving on ``metric`` at every evaluation:
    from ``grace_period`` epochs on (default a tenth of the most epochs), at rungs
    ``grace_period * reduction_factor**k``, a trial whose loss is not among the best
    ``1 / reduction_factor`` of those that reached the rung is stopped) or "none".
    ``cpus_per_trial`` / ``gpus_per_trial``: Ray resources of a trial (fractions share a GPU);
    ``max_concurrent``: at most that many trials at once (default: as the resources allow);
    ``num_cpus``: the CPUs of a local Ray instance this starts (default: all).
    ``random_seed`` draws the random settings. ``out`` is refused if it holds anything but an
    earlier sweep's output, unless ``force``. ``verbose``: Ray Tune's console output (0-3)
    and the trials' logs; ``progress(info)`` is called on every reported evaluation and every
    finished trial (see :func:`_callback`; the CLI draws a progress bar from it).
    """
    _check(scheduler, metric, cpus_per_trial, gpus_per_trial, max_concurrent, grace_period,
           reduction_factor, num_cpus)
    if address is not None and num_cpus is not None:
        raise UserError("num_cpus: sizes a local Ray instance; a cluster (address) has its own")
    if not isinstance(base_config, TrainConfig):
        raise UserError(f"base_config: expected a TrainConfig, got {type(base_config).__name__}")
    space = check_space(space)
    trials = make_trials(base_config, space, samples=samples, seeds=seeds,
                         random_seed=random_seed)
    most = max(t.config.epochs for t in trials)
    if scheduler == "asha" and grace_period is not None and grace_period > most:
        raise UserError(f"grace_period: {grace_period} is more than the epochs ({most})")
    ray, tune = _import_ray()
    if address is not None:
        _check_reachable(address)

    mc = base_config.model
    if not isinstance(data, Dataset):
        data = load_dataset(data, n=mc.n, m=mc.m)
    elif (data.n, data.m) != (mc.n, mc.m):
        raise UserError(f"dataset file {data.path}: model has n={mc.n}, m={mc.m}; the file has "
                        f"n={data.n}, m={data.m}")

    out = Path(out)
    ours = outputs.owner(out) == "sweep"
    out = outputs.claim(out, "sweep", force=force)
    if ours and (out / "tune").is_dir():
        shutil.rmtree(out / "tune")  # an earlier sweep's Ray Tune folder
    root = out.resolve()
    specs = []
    for t in trials:
        tdir = root / "trials" / t.name
        specs.append({"name": t.name, "config": t.config.to_dict(), "dir": str(tdir),
                      "force": tdir.is_dir() and any(tdir.iterdir()), "gpus": gpus_per_trial})

    started = False
    if not ray.is_initialized():
        try:
            # "local": a new instance, even where 'ray start' runs one (--address auto joins it)
            ray_init(ray, address=address or "local", num_cpus=num_cpus, include_dashboard=False,
                     log_to_driver=verbose > 0,
                     logging_level="INFO" if verbose > 0 else "ERROR")
        except (ConnectionError, ValueError, RuntimeError) as exc:
            where = f"the Ray cluster at {address}" if address else "a local Ray instance"
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            hint = ""
            if address not in (None, "auto") and "RAY_AUTH_MODE" not in os.environ:
                hint = ("; a cluster with token authentication (Ray's default) needs "
                        "RAY_AUTH_MODE=token and its token (see docs/sweep.md)")
            raise UserError(f"address: cannot start or reach {where}: {first}{hint}") from None
        started = True
    if progress is not None:
        progress({"event": "start", "trial": None, "epoch": None, "best_test_loss": None,
                  "finished": 0, "total": len(trials)})
    sigint = signal.getsignal(signal.SIGINT)  # Tune installs its own; put ours back after
    try:
        grid, finished = _tune(tune, trials, specs, data, root, scheduler=scheduler,
                               metric=metric, cpus=cpus_per_trial, gpus=gpus_per_trial,
                               max_concurrent=max_concurrent, grace_period=grace_period,
                               reduction_factor=reduction_factor, verbose=verbose,
                               progress=progress)
    finally:
        if signal.getsignal(signal.SIGINT) is not sigint:
            signal.signal(signal.SIGINT, sigint)
        if started:
            ray.shutdown()
    result = _write_results(out, trials, grid, finished, data, base_config, space,
                            samples=samples, seeds=seeds, scheduler=scheduler, metric=metric,
                            address=address)
    if len(finished) < len(trials):  # Ctrl-C: Tune ended the trials; what they reached is kept
        raise KeyboardInterrupt
    return result


def _tune(tune, trials, specs, data, root, *, scheduler, metric, cpus, gpus, max_concurrent,
          grace_period, reduction_factor, verbose, progress):
    """Run the trials; return ({trial name: ray.tune.Result}, the names of the trials that
    finished: completed, stopped by the scheduler or failed, not interrupted)."""
    from ray.tune.schedulers import ASHAScheduler, FIFOScheduler

    from softpinn.bridge.sweep.trial import Trial as TrialTrainable

    max_t = max(t.config.epochs for t in trials)
    if scheduler == "asha":
        grace = grace_period or max(1, max_t // 10)
        sched = ASHAScheduler(time_attr="epoch", max_t=max_t, grace_period=grace,
                              reduction_factor=reduction_factor, stop_last_trials=False)
    else:
        sched = FIFOScheduler()
    trainable = tune.with_resources(
        tune.with_parameters(TrialTrainable, data=data, specs={s["name"]: s for s in specs}),
        {"cpu": cpus, "gpu": gpus})
    events = _callback(tune, progress, len(specs))
    tuner = tune.Tuner(
        trainable,
        param_space={"trial": tune.grid_search([s["name"] for s in specs])},
        tune_config=tune.TuneConfig(
            metric=metric, mode="min", scheduler=sched, num_samples=1,
            max_concurrent_trials=max_concurrent, trial_dirname_creator=_trial_dirname,
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


def _callback(tune, progress, total):
    """A Ray Tune callback (in this process) that hands ``progress`` one dict per event:
    ``{"event": "result" | "complete" | "error", "trial", "epoch", "best_test_loss",
    "finished", "total"}`` (and one ``"start"`` from :func:`sweep` once Ray is up)."""

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


def _row(trial: Trial, result, finished: bool, root: Path, scheduler: str) -> dict:

    tdir = root / "trials" / trial.name
    last = dict(result.metrics or {}) if result is not None else {}
    error = None if result is None else result.error
    metrics = None
    if (tdir / "metrics.json").is_file() and (tdir / "model.eqx").is_file():
        try:
            metrics = read_json(tdir / "metrics.json")
        except Exception:  # noqa: BLE001 - a damaged file: the row says so
            metrics = None
    stopped_early = False
    if error is not None:
        lines = [s for s in str(error).strip().splitlines() if s.strip()]
        status = "error: " + (lines[-1].strip() if lines else type(error).__name__)
        if (root / "tune" / trial.name / "error.txt").is_file():
            status += f" (traceback: tune/{trial.name}/error.txt)"
    elif last.get("status") == "error":
        status = f"error: {last.get('error')}"
    elif result is None:
        status = "not run"
    elif metrics is None:
        status = "failed: no run directory" if finished else "not run (interrupted)"
    elif not finished:
        status = "interrupted"
    else:
        stopped = str(metrics.get("stopped", ""))
        if last.get("status") == "diverged" or stopped.startswith("diverged"):
            status = "diverged"
        elif stopped.startswith("early stop"):
            why = "overfit" if "(overfit" in stopped else "patience"
            status, stopped_early = f"early stop ({why})", True
        elif stopped.startswith("reached"):
            status = "reached the target loss"
        elif stopped == "running" or stopped.startswith("interrupted"):  # cut short
            stopped_early = True
            status = (f"stopped by ASHA at epoch {metrics.get('epochs_run')}"
                      if scheduler == "asha" else "interrupted")
        else:
            status = "completed"
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


def _write_results(out, trials, grid, finished, data, base_config, space, *, samples, seeds,
                   scheduler, metric, address) -> SweepResult:

    from softpinn.bridge.sweep import results as res

    root = out.resolve()
    rows = res.rank([_row(t, grid.get(t.name), t.name in finished, root, scheduler)
                     for t in trials])
    ok = [r for r in rows if r["best_test_loss"] is not None]
    best = ok[0] if ok else None
    names = list(space)
    info = {
        "data": dataset_info(data),
        "model": base_config.model.kind,
        "base_config": base_config.to_dict(),
        "space": {k: (v.describe() if isinstance(v, Random) else v) for k, v in space.items()},
        "samples": samples,
        "seeds": seeds,
        "scheduler": scheduler,
        "metric": metric,
        "address": address,
        "trials": len(trials),
        "best": None if best is None else {
            "trial": best["trial"], "path": best["path"], "dir": str(root / best["path"]),
            "link": "best", "best_test_loss": best["best_test_loss"],
            "settings": best["settings"], "seed": best["seed"]},
    }
    written = [
        res.write_csv(out / "results.csv", rows, names),
        res.write_json(out / "results.json", rows, info),
        res.write_markdown(out / "results.md", rows, names, info),
        res.plot(out / "sweep.png", rows, space, metric.replace("_", " ")),
    ]
    res.link_best(out, best)
    outputs.record(out, [*written, *outputs.written_files(out / "tune")])
    return SweepResult(out=out, rows=rows, best=best)

