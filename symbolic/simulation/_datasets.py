"""Data generation after the paper (Section III-B, Table III): a spec's ``[data]`` table
(:mod:`symbolic.simulation._datatable`) becomes trajectories in the dataset format
(:mod:`symbolic.simulation._datafile`, re-exported here).

A preset's ``[data]`` table says how the paper generated the data of its task; :class:`DataConfig`
validates it (unknown keys are refused with a message naming the file and the field).
:func:`make_dataset` draws the initial states and input signals, simulates
(:mod:`symbolic.simulation._simulate`), optionally adds Gaussian measurement noise and returns a
:class:`DatasetArrays`; :func:`write_dataset` writes it atomically (temporary file, then
:func:`os.replace`); :func:`read_dataset` reads it back with numpy alone.

File contents (``docs/dataset.md``): flat arrays over all samples of all trajectories,
``t`` (T,), ``q``, ``qd``, ``qdd``, ``p`` (T, n), ``u`` (T, m), ``traj`` (T,) int64, and
``meta``, a 0-d string of JSON with the keys ``format``, ``format_version``, ``spec`` (the model
spec, ``ModelSpec.to_dict()``), ``n``, ``m``, ``coordinates``, ``simulation`` (integrator,
tolerances or step, output rate), ``trajectories``, ``initial_states``, ``signals`` (one per
trajectory, :meth:`Signal.to_dict`), ``seed`` and ``seeding``, ``noise``, ``splits`` (the paper's
train/test/black-box trajectory indices), ``package_version``, ``casadi_version``, ``timings_s``,
and ``actuator`` (per input, from a spec's ``[actuator]``: u holds the commands).

Seeding: trajectory k draws its initial state and then its signal from
``numpy.random.default_rng([seed, k])``, so trajectory k is the same whatever the count.
"""


from __future__ import annotations

import dataclasses
import logging
import os
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

from softpinn.progress import ProgressFn
from softpinn.symbolic.codegen._codegen import compile_functions
from softpinn.symbolic.model._functions import functions
from softpinn.symbolic.simulation._datafile import (
    ARRAY_KEYS,
    FORMAT,
    FORMAT_VERSION,
    DatasetArrays,
    read_dataset,
    resample,
    select_trajectories,
    signals_of,
    split,
    take_samples,
    write_dataset,
)
from softpinn.symbolic.simulation._datatable import (
    DATA_KEYS,
    SIGNAL_RANGE_KEYS,
    DataConfig,
    DataError,
    data_config,
    with_overrides,
)
from softpinn.symbolic.simulation._defaults import physics_data_table
from softpinn.symbolic.simulation._signals import KINDS as SIGNAL_KINDS
from softpinn.symbolic.simulation._signals import Signal, sample_signal
from softpinn.symbolic.simulation._sim_config import INTEGRATORS, SimulationConfig
from softpinn.symbolic.simulation._simulate import simulate
from softpinn.symbolic.spec._model_spec import ModelSpec
from softpinn.symbolic.spec._spec import load_spec

__all__ = [
    "ARRAY_KEYS",
    "DATA_KEYS",
    "FORMAT",
    "FORMAT_VERSION",
    "SIGNAL_RANGE_KEYS",
    "DataConfig",
    "DataError",
    "DatasetArrays",
    "DatasetPlan",
    "data_config",
    "draw_trajectories",
    "make_dataset",
    "paper_splits",
    "plan_dataset",
    "read_dataset",
    "resample",
    "select_trajectories",
    "signals_of",
    "split",
    "take_samples",
    "with_overrides",
    "write_dataset",
]

#: seeds are 32-bit unsigned integers, as on the learning side
MAX_SEED = 2**32 - 1


def check_seed(seed) -> int:
    """``seed`` as an int in [0, 2**32 - 1], else a :class:`DataError` naming the field."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not (
        0 <= seed <= MAX_SEED
    ):
        raise DataError(f"seed: expected an integer from 0 to {MAX_SEED} (2**32 - 1), got {seed!r}")
    return int(seed)


LOG = logging.getLogger("softpinn.symbolic")


def _rng(seed: int, k: int) -> np.random.Generator:
    return np.random.default_rng([int(seed), int(k)])


def draw_trajectories(
    cfg: DataConfig,
    n: int,
    m: int,
    indices: Sequence[int],
    *,
    kind: str | None = None,
    duration: float | None = None,
    seed: int | None = None,
) -> tuple[np.ndarray, list[Signal]]:
    """Initial states (K, 2n), uniform in the ``[data]`` ranges (zero where none is given), and
    one input signal per trajectory; trajectory k draws both from ``default_rng([seed, k])``.
    Trajectory k < len(``q0_points``) then starts at ``q0_points[k]`` instead of its drawn q
    (its qd and signal are the drawn ones, so no other trajectory changes)."""
    seed = cfg.seed if seed is None else seed
    kind = kind or cfg.signal
    lo = np.r_[cfg.q0_low or (0.0,) * n, cfg.qd0_low or (0.0,) * n]
    hi = np.r_[cfg.q0_high or (0.0,) * n, cfg.qd0_high or (0.0,) * n]
    x0 = np.zeros((len(indices), 2 * n))
    sigs = []
    for row, k in enumerate(indices):
        rng = _rng(seed, k)
        x0[row] = lo + (hi - lo) * rng.uniform(size=2 * n)
        if k < len(cfg.q0_points):
            x0[row, :n] = cfg.q0_points[k]
        sigs.append(
            sample_signal(
                kind,
                m,
                rng,
                cfg.ranges,
                duration=duration or cfg.duration,
                components=cfg.components,
                steps=cfg.steps,
            )
        )
    return x0, sigs


def paper_splits(cfg: DataConfig, total: int, integrator: str) -> dict[str, list[int]]:
    """The paper's use of the trajectories (Section III-B): the last ``test_trajectories`` for
    testing; the first ``train_trajectories`` train the physics model and the first
    ``blackbox_train_trajectories`` the black box. Fixed-step (rk4) data: the first
    ``fixed_step_train_trajectories`` train, the rest test."""
    ids = list(range(total))
    if integrator == "rk4" and cfg.fixed_step_train_trajectories is not None:
        ntr = min(cfg.fixed_step_train_trajectories, total)
        return {"train": ids[:ntr], "test": ids[ntr:], "blackbox_train": ids[:ntr]}
    ntest = min(cfg.test_trajectories, max(total - 1, 0))
    pool = ids[: total - ntest]
    ntr = len(pool) if cfg.train_trajectories is None else min(cfg.train_trajectories, len(pool))
    nbb = (
        len(pool)
        if cfg.blackbox_train_trajectories is None
        else min(cfg.blackbox_train_trajectories, len(pool))
    )
    return {"train": pool[:ntr], "test": ids[total - ntest :], "blackbox_train": pool[:nbb]}


@dataclass(frozen=True)
class DatasetPlan:
    """A validated request for a data set: everything :func:`make_dataset` will do."""

    spec: ModelSpec
    data: DataConfig
    sim: SimulationConfig
    trajectories: int
    seed: int
    noise: float
    signal: str
    settle: float = 0.0
    #: how the defaults were made when the spec has no [data] table (symbolic.simulation._defaults)
    data_defaults: str | None = None


def plan_dataset(
    model: str | Path | ModelSpec,
    *,
    trajectories: int | None = None,
    duration: float | None = None,
    settle: float | None = None,
    rate: float | None = None,
    dt: float | None = None,
    integrator: str | None = None,
    signal: str | None = None,
    seed: int | None = None,
    noise: float | None = None,
    rtol: float | None = None,
    atol: float | None = None,
    threads: int = 2,
    max_condition: float | None = 1e12,
    data: Mapping[str, Any] | None = None,
) -> DatasetPlan:
    """Validate a data-set request; every argument left None comes from the spec's ``[data]``.

    ``rate`` defaults to the highest of ``[data]``'s rates (cvodes) or ``fixed_step_rate`` / 1 /
    ``fixed_step_dt`` (rk4); ``dt`` (rk4 step) to ``fixed_step_dt`` or 1 / rate. ``settle``
    seconds are simulated before the recording starts (``t`` then runs from ``settle`` to
    ``settle + duration``); it must be a whole number of output samples.
    """
    spec = load_spec(model)
    defaults = None
    if data is None and not spec.data:  # no [data]: defaults from the physics, not q = 0, u = 0
        table, defaults = physics_data_table(spec)
        spec = dataclasses.replace(spec, data=table)
        given = {"trajectories": trajectories, "duration [s]": duration, "rate [Hz]": rate,
                 "settle [s]": settle, "signal": signal, "seed": seed, "noise": noise,
                 "integrator": integrator, "dt [s]": dt}
        told = [f"{k} {v:g}" if isinstance(v, float) else f"{k} {v}"
                for k, v in given.items() if v is not None]
        LOG.warning(defaults + (f"; instead, as given: {', '.join(told)}" if told else ""))
    cfg = data_config(spec, data)
    integ = integrator or cfg.integrator
    if integ not in INTEGRATORS:
        raise DataError(f"integrator: expected one of {', '.join(INTEGRATORS)}, got {integ!r}")
    if integ == "rk4":
        dt = dt if dt is not None else cfg.fixed_step_dt
        if rate is None:
            rate = cfg.fixed_step_rate or (1.0 / dt if dt else cfg.rate)
    rate = cfg.rate if rate is None else rate
    duration = cfg.duration if duration is None else duration
    if duration is None or not duration > 0:
        raise DataError(f"duration: must be positive, got {duration}")
    total = cfg.total_trajectories(integ) if trajectories is None else trajectories
    if isinstance(total, bool) or not isinstance(total, (int, np.integer)) or total < 1:
        raise DataError(f"trajectories: must be an integer of at least 1, got {total!r}")
    seed = cfg.seed if seed is None else check_seed(seed)
    noise = cfg.noise if noise is None else float(noise)
    if not (np.isfinite(noise) and noise >= 0):
        raise DataError(f"noise: must be a non-negative standard deviation, got {noise}")
    sim = SimulationConfig(
        integrator=integ,
        duration=float(duration),
        rate=float(rate),
        dt=float(dt) if (integ == "rk4" and dt is not None) else None,
        rtol=cfg.rtol if rtol is None else float(rtol),
        atol=cfg.atol if atol is None else float(atol),
        threads=threads,
        max_condition=max_condition,
    )
    _check_memory(total, spec.n, spec.m, sim, cfg.settle if settle is None else settle)
    kind = signal or cfg.signal
    if kind not in SIGNAL_KINDS:
        raise DataError(f"signal: expected one of {', '.join(SIGNAL_KINDS)}, got {kind!r}")
    if total > 1:
        x0, sigs = draw_trajectories(cfg, spec.n, spec.m, range(total), kind=kind,
                                     duration=float(duration), seed=seed)
        if np.all(x0 == x0[0]) and all(s.to_dict() == sigs[0].to_dict() for s in sigs):
            raise DataError(
                f"{spec.source}: [data] makes all {total} trajectories identical (the same "
                f"initial state and the same input): give ranges q0_low/q0_high or "
                f"qd0_low/qd0_high, or a signal whose ranges differ (docs/spec.md); without a "
                "[data] table defaults come from the physics"
            )
    settle = cfg.settle if settle is None else float(settle)
    skip = settle * float(rate)
    if not (np.isfinite(settle) and settle >= 0):
        raise DataError(f"settle: must be a non-negative number of seconds, got {settle}")
    if abs(skip - round(skip)) > 1e-6 * max(skip, 1.0):
        raise DataError(
            f"settle: {settle:g} s is not a whole number of samples at {float(rate):g} Hz"
        )
    return DatasetPlan(
        spec=spec,
        data=cfg,
        sim=sim,
        trajectories=total,
        seed=seed,
        noise=noise,
        signal=kind,
        settle=settle,
        data_defaults=defaults,
    )


def _check_memory(trajectories: int, n: int, m: int, sim, settle) -> None:
    """Refuse a data set whose arrays would not fit in this machine's memory (before any work)."""
    settle = float(settle) if np.isfinite(settle) and settle > 0 else 0.0  # checked later
    samples = sim.samples + settle * sim.rate
    per_sample = 8 * (2 * (5 * n + m) + 2)  # simulated arrays, the flat copies, t and traj
    need = float(trajectories) * samples * per_sample
    total = _physical_memory()
    if total and need > total:
        raise DataError(
            f"trajectories x duration x rate: {trajectories} x {sim.duration + settle:g} s x "
            f"{sim.rate:g} Hz would need {need / 1e9:.3g} GB for the arrays, more than this "
            f"machine's {total / 1e9:.3g} GB of memory; ask for fewer or shorter trajectories "
            "or a lower rate"
        )


def _physical_memory() -> int | None:
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):  # pragma: no cover - not POSIX
        return None


def make_dataset(
    model: str | Path | ModelSpec | None = None,
    *,
    plan: DatasetPlan | None = None,
    fns: Mapping | None = None,
    compile: bool = True,
    cache: str | os.PathLike | None = None,
    progress: ProgressFn | None = None,
    simulator: Callable | None = None,
    simulator_meta: Mapping | None = None,
    **options,
) -> DatasetArrays:
    """Simulate a model's data set (Section III-B) and return its arrays and meta.

    Either ``plan`` (from :func:`plan_dataset`) or ``model`` with the keyword ``options`` of
    :func:`plan_dataset`. ``fns`` overrides the model's functions (else
    :func:`symbolic.model._functions.functions`, compiled to C with
    :func:`symbolic.codegen._codegen.compiled` when ``compile``; ``cache`` is the compiled-code
    cache directory). ``progress`` is told the trajectories finished (a
    :class:`softpinn.progress.Progress`).

    ``simulator(x0, signals, config, progress=...)`` replaces CasADi's integration (it returns what
    :func:`symbolic.simulation._simulate.simulate` does: ``t``, ``x``, ``q``, ``qd``, ``qdd``,
    ``p``, ``u``, ``info``), e.g. the JAX RK4 of :func:`softpinn.bridge.exact.make_dataset`; its
    ``simulator_meta`` is merged into ``meta``. Everything else (the plan, the draws of initial
    states and signals, the settle time, the noise, the meta) is this function's, whichever
    integrates.
    """
    if plan is None:
        plan = plan_dataset(model, **options)
    elif model is not None or options:
        raise TypeError("make_dataset: give either a plan or a model with options")
    spec, cfg, sim = plan.spec, plan.data, plan.sim
    total, seed, noise, kind = plan.trajectories, plan.seed, plan.noise, plan.signal
    integ = sim.integrator
    timings: dict[str, float] = {}
    is_compiled = from_cache = None  # unknown when the caller passes the functions
    actuator = spec.actuator_dynamics
    if simulator is not None:
        if fns is not None:
            raise TypeError("make_dataset: give fns or a simulator, not both")
        if actuator and not actuator.is_identity and not getattr(simulator, "actuated", 0):
            raise DataError(f"{spec.source}: [actuator]: this integrator does not model the "
                            "actuator's lag and delay; use --integrator rk4 or cvodes")
    elif fns is None:
        t0 = time.perf_counter()
        fns = functions(spec)
        timings["functions"] = time.perf_counter() - t0
        if compile:
            t0 = time.perf_counter()
            built = compile_functions(fns, directory=cache)
            fns, is_compiled = built.functions, built.compiled
            timings["compile"] = time.perf_counter() - t0
            from_cache = built.from_cache
        else:
            is_compiled = False
    ids = list(range(total))
    x0, sigs = draw_trajectories(
        cfg, spec.n, spec.m, ids, kind=kind, duration=sim.duration, seed=seed
    )
    t0 = time.perf_counter()
    # with settle > 0 the arm is simulated from its drawn initial state for ``settle`` seconds
    # before recording: the release transient (e.g. Task 5's second segment, eigenvalue about
    # -288 1/s) would otherwise hold nearly all of the one-step loss in a few samples
    run = replace(sim, duration=sim.duration + plan.settle) if plan.settle else sim
    if simulator is None:
        res = simulate(fns, x0, sigs, run, progress=progress, actuator=actuator)
    else:
        res = simulator(x0, sigs, run, progress=progress)
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
        "simulation": sim.describe() | {"settle": plan.settle},
        "rate": sim.rate,
        "trajectories": K,
        "samples_per_trajectory": T,
        "initial_states": x0.tolist(),  # at t = 0, before any settle time
        "signals": [s.to_dict() for s in sigs],
        "signal_kind": kind,
        "data_defaults": plan.data_defaults,
        "seed": seed,
        "seeding": "trajectory k: numpy.random.default_rng([seed, k]) draws x0, then the signal",
        "noise": noise_meta,
        "splits": paper_splits(cfg, K, integ),
        "physics_samples": cfg.physics_samples,
        "rates": sorted(set(cfg.rates) | {sim.rate}) if integ == "cvodes" else [sim.rate],
        "max_mass_condition": res.info.get("max_mass_condition"),
        "compiled": is_compiled,
        "compiled_from_cache": from_cache,
        "package_version": package_version("softpinn"),
        "casadi_version": package_version("casadi"),
        "numpy_version": np.__version__,
        "timings_s": timings,
    }
    meta.update({"actuator": spec.actuator_meta()} if actuator else {}, **(simulator_meta or {}))
    return DatasetArrays(meta=meta, **arrays)


def package_version(dist: str) -> str | None:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return None

