"""Data sets simulated in JAX, in the file format of ``softpinn simulate``.

:func:`make_dataset` is :func:`softpinn.symbolic.datasets.make_dataset` with the integration
done by :func:`.simulate.simulate` (fixed-step RK4 on the translated exact model, all
trajectories at once) instead of CasADi: the same plan, the same draws of initial states and
signals (trajectory k from ``default_rng([seed, k])``), the same arrays and the same ``meta``
keys, so :func:`softpinn.symbolic.datasets.write_dataset` / ``read_dataset`` and every consumer
take it unchanged. ``meta["simulation"]["method"]`` and ``meta["compiled"] = "jax"`` say how it
was made.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

from ...symbolic.datasets import (
    FORMAT,
    FORMAT_VERSION,
    DatasetArrays,
    DatasetPlan,
    _version,
    draw_trajectories,
    paper_splits,
    plan_dataset,
)
from ...symbolic.spec import ModelSpec
from .model import jax_model
from .simulate import simulate

METHOD = "classical Runge-Kutta 4, fixed step (JAX/XLA, translated exact model, vmap + scan)"


def make_dataset(
    model: str | Path | ModelSpec | None = None,
    *,
    plan: DatasetPlan | None = None,
    progress: Callable[[int], None] | None = None,
    **options,
) -> DatasetArrays:
    """Simulate a model's data set (Section III-B) in JAX; ``plan`` or ``model`` with the
    keyword ``options`` of :func:`softpinn.symbolic.datasets.plan_dataset` (``integrator``
    defaults to, and must be, ``"rk4"``)."""
    if plan is None:
        options.setdefault("integrator", "rk4")
        plan = plan_dataset(model, **options)
    elif model is not None or options:
        raise TypeError("make_dataset: give either a plan or a model with options")
    spec, cfg, sim = plan.spec, plan.data, plan.sim
    total, seed, noise, kind = plan.trajectories, plan.seed, plan.noise, plan.signal
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    em = jax_model(spec)
    timings["functions"] = time.perf_counter() - t0
    ids = list(range(total))
    x0, sigs = draw_trajectories(cfg, spec.n, spec.m, ids, kind=kind, duration=sim.duration,
                                 seed=seed)
    t0 = time.perf_counter()
    run = replace(sim, duration=sim.duration + plan.settle) if plan.settle else sim
    res = simulate(em, x0, sigs, run, progress=progress)
    timings["simulate"] = time.perf_counter() - t0
    timings.update({k: v for k, v in res.info.items() if k.endswith("_seconds")})

    skip = int(round(plan.settle * sim.rate))
    K = res.x.shape[0]
    T = res.x.shape[1] - skip
    n, m = spec.n, spec.m
    arrays = {
        "t": np.tile(res.t[skip:], K),
        "q": res.q[:, skip:].reshape(K * T, n).copy(),
        "qd": res.qd[:, skip:].reshape(K * T, n).copy(),
        "qdd": res.qdd[:, skip:].reshape(K * T, n),
        "p": res.p[:, skip:].reshape(K * T, n),
        "u": res.u[:, skip:].reshape(K * T, m),
        "traj": np.repeat(np.arange(K, dtype=np.int64), T),
    }
    noise_meta = {"sigma": noise, "arrays": [], "seed": None}
    if noise > 0:
        rng = np.random.default_rng([seed, 2**31 - 1])
        for key in ("q", "qd", "qdd", "p"):
            arrays[key] = arrays[key] + noise * rng.standard_normal(arrays[key].shape)
        noise_meta = {
            "sigma": noise,
            "arrays": ["q", "qd", "qdd", "p"],
            "seed": [seed, 2**31 - 1],
            "distribution": "Gaussian, independent per entry",
        }
    meta = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "spec": spec.to_dict(),
        "n": n,
        "m": m,
        "coordinates": list(spec.coordinate_names),
        "simulation": sim.describe() | {"settle": plan.settle, "method": METHOD},
        "rate": sim.rate,
        "trajectories": K,
        "samples_per_trajectory": T,
        "initial_states": x0.tolist(),
        "signals": [s.to_dict() for s in sigs],
        "signal_kind": kind,
        "seed": seed,
        "seeding": "trajectory k: numpy.random.default_rng([seed, k]) draws x0, then the signal",
        "noise": noise_meta,
        "splits": paper_splits(cfg, K, sim.integrator),
        "physics_samples": cfg.physics_samples,
        "rates": [sim.rate],
        "max_mass_condition": res.info.get("max_mass_condition"),
        "compiled": "jax",
        "compiled_from_cache": None,
        "package_version": _version("softpinn"),
        "casadi_version": _version("casadi"),
        "jax_version": _version("jax"),
        "numpy_version": np.__version__,
        "timings_s": timings,
    }
    return DatasetArrays(meta=meta, **arrays)


__all__ = ["METHOD", "make_dataset"]
