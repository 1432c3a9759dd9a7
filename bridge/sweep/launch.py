"""The sweep's entry point :func:`sweep`: check the settings, claim the output folder, start (or
join) Ray, run the trials through Ray Tune (:mod:`.tuner`) and write the results
(:mod:`.results`).

Ray is an optional extra: it is imported only inside :func:`sweep`, so ``import
softpinn.bridge.sweep`` works without it.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
from pathlib import Path

from softpinn import locks
from softpinn.bridge.base import outputs
from softpinn.bridge.sweep.config import SweepConfig
from softpinn.bridge.sweep.results import SweepResult, write_results
from softpinn.bridge.sweep.space import check_space, make_trials
from softpinn.errors import UserError
from softpinn.learn import Dataset, TrainConfig, load_dataset
from softpinn.symbolic import ray_init

__all__ = ["RAY_MISSING", "sweep"]

RAY_MISSING = "softpinn sweep needs Ray: pip install 'softpinn[ray]'"


def _import_ray():
    try:
        # Ray is optional (softpinn[ray]): imported only when a sweep runs
        import ray
        from ray import tune  # noqa: F401 - Tune too (the extra installs both)
    except ImportError:
        raise UserError(RAY_MISSING) from None
    return ray


def _check_reachable(address: str) -> None:
    """A ``HOST:PORT`` nobody answers at is one line now, not Ray's minutes of retries."""
    host, sep, port = address.removeprefix("ray://").rpartition(":")
    if address == "auto" or not sep or not port.isdigit():
        return  # 'auto' (the cluster this node belongs to) and the like: Ray decides
    try:
        socket.create_connection((host, int(port)), timeout=10).close()
    except OSError as exc:
        raise UserError(f"address: nothing answers at {address} ({exc.strerror or exc}); is "
                        "'ray start --head' running there, on that port?") from None


def _start_ray(ray, config: SweepConfig, verbose: int) -> None:
    """A new local Ray instance (even where 'ray start' runs one), or the cluster at
    ``config.address``; a failure is one line."""
    address = config.address
    try:
        # "local": a new instance, even where 'ray start' runs one (--address auto joins it)
        ray_init(ray, address=address or "local", num_cpus=config.num_cpus,
                 include_dashboard=False, log_to_driver=verbose > 0,
                 logging_level="INFO" if verbose > 0 else "ERROR")
    except (ConnectionError, ValueError, RuntimeError) as exc:
        where = f"the Ray cluster at {address}" if address else "a local Ray instance"
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        hint = ""
        if address not in (None, "auto") and "RAY_AUTH_MODE" not in os.environ:
            hint = ("; a cluster with token authentication (Ray's default) needs "
                    "RAY_AUTH_MODE=token and its token (see docs/sweep.md)")
        raise UserError(f"address: cannot start or reach {where}: {first}{hint}") from None


@locks.scope()  # the output's lock is given up when the call returns
def sweep(data, base_config: TrainConfig, space: dict, out: str | Path,
          config: SweepConfig | None = None, *, force: bool = False, verbose: int = 0,
          progress=None) -> SweepResult:
    """Train every trial of ``space`` over ``base_config`` on ``data`` through Ray Tune; write
    ``out`` (see :mod:`softpinn.bridge.sweep`) and return the ranked rows.

    ``space``: setting -> a list of values (a grid) or a random range (``"log:1e-4:1e-2"``, a
    :class:`~.space.Random`); ``config`` (default :class:`SweepConfig()`): the draws and seeds
    of the trials (``base_config.seeds`` must be 1), the scheduler and where Ray runs them. On
    a cluster ``out`` must be a folder every node sees at the same path. ``out`` is refused if
    it holds anything but an earlier sweep's output, unless ``force``. ``verbose``: Ray Tune's
    console output (0-3) and the trials' logs; ``progress(info)`` is called on every reported
    evaluation and every finished trial (see :func:`.tuner._callback`; the CLI draws a
    progress bar from it).
    """
    config = SweepConfig() if config is None else config
    if not isinstance(config, SweepConfig):
        raise UserError(f"config: expected a SweepConfig, got {type(config).__name__}")
    if not isinstance(base_config, TrainConfig):
        raise UserError(f"base_config: expected a TrainConfig, got {type(base_config).__name__}")
    space = check_space(space)
    trials = make_trials(base_config, space, samples=config.samples, seeds=config.seeds,
                         random_seed=config.random_seed)
    most = max(t.config.epochs for t in trials)
    if config.scheduler == "asha" and config.grace_period is not None and \
            config.grace_period > most:
        raise UserError(f"grace_period: {config.grace_period} is more than the epochs ({most})")
    ray = _import_ray()
    if config.address is not None:
        _check_reachable(config.address)

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
                      "force": tdir.is_dir() and any(tdir.iterdir()),
                      "gpus": config.gpus_per_trial})

    started = False
    if not ray.is_initialized():
        _start_ray(ray, config, verbose)
        started = True
    if progress is not None:
        progress({"event": "start", "trial": None, "epoch": None, "best_test_loss": None,
                  "finished": 0, "total": len(trials)})
    sigint = signal.getsignal(signal.SIGINT)  # Tune installs its own; put ours back after
    try:
        # imports Ray Tune at its top: only now that Ray is known to be installed
        from softpinn.bridge.sweep.tuner import run_trials

        grid, finished = run_trials(trials, specs, data, root, config, verbose=verbose,
                                    progress=progress)
    finally:
        if signal.getsignal(signal.SIGINT) is not sigint:
            signal.signal(signal.SIGINT, sigint)
        if started:
            ray.shutdown()
    result = write_results(out, trials, grid, finished, data, base_config, space, config)
    if len(finished) < len(trials):  # Ctrl-C: Tune ended the trials; what they reached is kept
        raise KeyboardInterrupt
    return result
