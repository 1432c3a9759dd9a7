"""Trajectories farmed out to a Ray cluster (issue 21, part 4): a ``simulator`` for
:func:`symbolic.simulation._datasets.make_dataset` that integrates chunks of the trajectories as
Ray tasks, each on a worker that derives (and compiles, through the shared code cache) the model
itself, then puts the chunks back in order. Trajectories are independent and each is integrated
by the same code as in-process, so the data set is identical either way (a test).

Ray is an optional extra (``pip install 'softpinn[ray]'``) imported only here, only when asked.
"""

from __future__ import annotations

import math
import os
import warnings
from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np

from softpinn.errors import UserError
from softpinn.progress import Progress
from softpinn.symbolic.codegen._codegen import compile_functions
from softpinn.symbolic.model._functions import functions
from softpinn.symbolic.simulation._sim_config import SimResult
from softpinn.symbolic.simulation._simulate import simulate

RAY_MISSING = "simulate --ray needs Ray: pip install 'softpinn[ray]'"


def ray_init(ray, **kwargs):
    """``ray.init(**kwargs)`` without JAX's warning that the process forked: Ray starts its
    services with subprocess (fork, then exec at once), which cannot deadlock on JAX's threads;
    the warning would only alarm the user (and fails a test run that turns warnings into
    errors)."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r"os\.fork\(\) was called",
                                category=RuntimeWarning)
        return ray.init(**kwargs)


def _chunk(spec, x0, signals, config, compile, cache):
    """One Ray task: the model's functions on this worker, then the trajectories."""
    fns = functions(spec)
    if compile:
        fns = compile_functions(fns, directory=cache).functions
    return simulate(fns, x0, signals, config, actuator=spec.actuator_dynamics)


def ray_simulator(spec, *, address: str | None = None, chunks: int | None = None,
                  compile: bool = True, cache: str | os.PathLike | None = None,
                  num_cpus: int | None = None) -> Callable:
    """A ``simulator(x0, signals, config, progress=None)`` that runs on Ray: a local instance
    (``address`` None or "local"; ``num_cpus`` of this machine) or the cluster at ``address``
    (``"auto"`` or ``"HOST:PORT"``), in ``chunks`` tasks (default: one per CPU of the cluster,
    at least one trajectory each)."""
    try:
        import ray  # an optional extra: imported only when asked for
    except ImportError:
        raise UserError(RAY_MISSING) from None
    if chunks is not None and not (isinstance(chunks, int) and chunks >= 1):
        raise UserError(f"chunks: expected an integer >= 1, got {chunks!r}")

    def run(x0: np.ndarray, signals: Sequence, config, progress=None):
        started = False
        if not ray.is_initialized():
            try:
                ray_init(ray, address=None if address in (None, "local") else address,
                         num_cpus=num_cpus if address in (None, "local") else None,
                         include_dashboard=False, log_to_driver=False,
                         logging_level="ERROR")
            except (ConnectionError, ValueError, RuntimeError) as exc:
                where = f"the Ray cluster at {address}" if address not in (None, "local") else \
                    "a local Ray instance"
                first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
                raise UserError(f"ray: cannot start or reach {where}: {first}") from None
            started = True
        try:
            k = len(x0)
            parts = chunks or max(1, int(ray.cluster_resources().get("CPU", 1)))
            size = math.ceil(k / min(parts, k))
            task = ray.remote(_chunk).options(num_cpus=1)
            one = replace(config, threads=1)
            refs = [task.remote(spec, x0[i:i + size], list(signals[i:i + size]), one, compile,
                                cache) for i in range(0, k, size)]
            results = []
            finished = 0
            for ref in refs:  # in order; the progress counts finished chunks
                results.append(ray.get(ref))
                finished += len(results[-1].x)
                if progress is not None:
                    progress(Progress(done=finished, total=k, unit="trajectory"))
        finally:
            if started:
                ray.shutdown()
        info = {
            "integrate_seconds": sum(r.info.get("integrate_seconds", 0.0) for r in results),
            "postprocess_seconds": sum(r.info.get("postprocess_seconds", 0.0) for r in results),
            "max_mass_condition": (max(r.info["max_mass_condition"] for r in results)
                                   if results[0].info.get("max_mass_condition") is not None
                                   else None),
            "ray_tasks": len(results),
        }
        cat = lambda key: np.concatenate([getattr(r, key) for r in results])  # noqa: E731
        return SimResult(t=results[0].t, x=cat("x"), u=cat("u"), qdd=cat("qdd"), p=cat("p"),
                         config=config, info=info)

    run.actuated = True  # each task simulates the spec's [actuator] (make_dataset checks)
    return run
