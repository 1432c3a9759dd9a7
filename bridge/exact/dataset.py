"""Data sets simulated in JAX, in the file format of ``softpinn simulate``.

:func:`make_dataset` is :func:`softpinn.symbolic.make_dataset` with the integration
done by :func:`.simulate.simulate` (fixed-step RK4 on the translated exact model, all
trajectories at once) instead of CasADi, passed in as its ``simulator``: the same plan, the
same draws of initial states and signals (trajectory k from ``default_rng([seed, k])``), the
same arrays and the same ``meta``, so every consumer takes it unchanged.
``meta["simulation"]["method"]`` and ``meta["compiled"]`` (``"c-kernel"``: the batched C kernels
of :mod:`softpinn.symbolic.codegen._kernel`, the default on a CPU with a C compiler;
``"jax"``: XLA, on a
GPU or without a compiler) say how it was made.
"""

from __future__ import annotations

import time
from pathlib import Path

from softpinn.bridge.exact.model import jax_model
from softpinn.bridge.exact.simulate import choose_backend, simulate
from softpinn.progress import ProgressFn
from softpinn.symbolic import DatasetArrays, DatasetPlan, ModelSpec, package_version, plan_dataset
from softpinn.symbolic import make_dataset as _make_dataset

METHOD = "classical Runge-Kutta 4, fixed step (JAX/XLA, translated exact model, vmap + scan)"
METHOD_C = ("classical Runge-Kutta 4, fixed step (batched C kernels of the exact model's SX "
            "instructions, vectorised over trajectories)")


def make_dataset(
    model: str | Path | ModelSpec | None = None,
    *,
    plan: DatasetPlan | None = None,
    progress: ProgressFn | None = None,
    backend: str = "auto",
    **options,
) -> DatasetArrays:
    """Simulate a model's data set (Section III-B) with all trajectories at once; ``plan`` or
    ``model`` with the keyword ``options`` of :func:`softpinn.symbolic.plan_dataset`
    (``integrator`` defaults to, and must be, ``"rk4"``); ``backend`` as in
    :func:`.simulate.simulate`."""
    backend = choose_backend(backend)
    if plan is None:
        options.setdefault("integrator", "rk4")
        plan = plan_dataset(model, **options)
    elif model is not None or options:
        raise TypeError("make_dataset: give either a plan or a model with options")
    t0 = time.perf_counter()
    em = jax_model(plan.spec)
    translate_s = time.perf_counter() - t0

    def batch_rk4(x0, signals, config, progress=None):
        return simulate(em, x0, signals, config, progress=progress, backend=backend)

    data = _make_dataset(plan=plan, progress=progress, simulator=batch_rk4, simulator_meta={
        "compiled": "c-kernel" if backend == "c" else "jax", "compiled_from_cache": None,
        "jax_version": package_version("jax")})
    data.meta["simulation"]["method"] = METHOD_C if backend == "c" else METHOD
    data.meta["timings_s"]["functions"] = translate_s
    return data


__all__ = ["METHOD", "METHOD_C", "make_dataset"]
