"""Dataset files: the paper's data generation (Section III-B, Table III) and the ``.npz`` format.

A preset's ``[data]`` table says how the paper generated the data of its task; :class:`DataConfig`
validates it (unknown keys are refused with a message naming the file and the field).
:func:`make_dataset` draws the initial states and input signals, simulates
(:mod:`symbolic.simulate`), optionally adds Gaussian measurement noise and returns a
:class:`DatasetArrays`; :func:`write_dataset` writes it atomically (temporary file, then
:func:`os.replace`); :func:`read_dataset` reads it back with numpy alone.

File contents (DESIGN.md, Dataset file): flat arrays over all samples of all trajectories,
``t`` (T,), ``q``, ``qd``, ``qdd``, ``p`` (T, n), ``u`` (T, m), ``traj`` (T,) int64, and
``meta``, a 0-d string of JSON with the keys ``format``, ``format_version``, ``spec`` (the model
spec, ``ModelSpec.to_dict()``), ``n``, ``m``, ``coordinates``, ``simulation`` (integrator,
tolerances or step, output rate), ``trajectories``, ``initial_states``, ``signals`` (one per
trajectory, :meth:`Signal.to_dict`), ``seed`` and ``seeding``, ``noise``, ``splits`` (the paper's
train/test/black-box trajectory indices), ``package_version``, ``casadi_version``, ``timings_s``.

Seeding: trajectory k draws its initial state and then its signal from
``numpy.random.default_rng([seed, k])``, so trajectory k is the same whatever the count.
"""

from __future__ import annotations

import json
import os
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

from .errors import UserError
from .signals import KINDS as SIGNAL_KINDS
from .signals import Signal, sample_signal, signal_from_dict
from .simulate import INTEGRATORS, SimulationConfig, simulate
from .spec import ModelSpec, load_spec

FORMAT = "softpinn-dataset"
FORMAT_VERSION = 1
ARRAY_KEYS = ("t", "q", "qd", "qdd", "p", "u", "traj")


class DataError(UserError):
    """A bad ``[data]`` table, dataset option or dataset file."""


# --------------------------------------------------------------------------------------------
# [data] tables

#: key -> (kind, description). Kinds: "int", "float", "str", "floats" (a list of numbers),
#: "nvec" (n numbers), "mvec" (m numbers or one number), "nrows" (a list of rows of n numbers).
DATA_KEYS: dict[str, tuple[str, str]] = {
    "integrator": ("str", "cvodes | rk4"),
    "rate": ("float", "output rate [Hz]"),
    "rates": ("floats", "output rates [Hz]: written at the highest, resampled to the others"),
    "duration": ("float", "seconds per trajectory"),
    "settle": ("float", "seconds simulated before recording starts (the release transient)"),
    "trajectories": ("int", "number of trajectories (default: max(train, black-box train) + test)"),
    "train_trajectories": ("int", "physics-model training trajectories"),
    "test_trajectories": ("int", "test trajectories (the last ones)"),
    "blackbox_train_trajectories": ("int", "black-box training trajectories (the first ones)"),
    "physics_samples": ("int", "samples of the training data the physics model uses"),
    "fixed_step_dt": ("float", "RK4 step [s] of the fixed-step data set"),
    "fixed_step_rate": ("float", "output rate [Hz] of the fixed-step data (default 1 / dt)"),
    "fixed_step_trajectories": ("int", "trajectories of the fixed-step data set"),
    "fixed_step_train_trajectories": ("int", "of which for training"),
    "q0_low": ("nvec", "initial q, lower bounds"),
    "q0_high": ("nvec", "initial q, upper bounds"),
    "q0_points": (
        "nrows",
        "initial q of the first trajectories, one row each (e.g. configurations the matrix "
        "tables inspect that the drawn ones do not reach); their qd and inputs are still drawn",
    ),
    "qd0_low": ("nvec", "initial qd, lower bounds"),
    "qd0_high": ("nvec", "initial qd, upper bounds"),
    "signal": ("str", "zero | sinusoid | multisine | step | chirp"),
    "amplitude_low": ("mvec", ""),
    "amplitude_high": ("mvec", ""),
    "offset_low": ("mvec", ""),
    "offset_high": ("mvec", ""),
    "frequency_low": ("mvec", "[Hz]"),
    "frequency_high": ("mvec", "[Hz]"),
    "phase_low": ("mvec", "[rad]"),
    "phase_high": ("mvec", "[rad]"),
    "components": ("int", "multisine components"),
    "steps": ("int", "switches of a step signal"),
    "seed": ("int", "random seed"),
    "noise": ("float", "standard deviation of Gaussian measurement noise"),
    "rtol": ("float", "cvodes relative tolerance"),
    "atol": ("float", "cvodes absolute tolerance"),
}

SIGNAL_RANGE_KEYS = tuple(k for k, (kind, _) in DATA_KEYS.items() if kind == "mvec")


@dataclass(frozen=True)
class DataConfig:
    """A validated ``[data]`` table (defaults where the table is silent)."""

    integrator: str = "cvodes"
    rates: tuple[float, ...] = (100.0,)
    duration: float = 10.0
    settle: float = 0.0
    trajectories: int | None = None
    train_trajectories: int | None = None
    test_trajectories: int = 0
    blackbox_train_trajectories: int | None = None
    physics_samples: int | None = None
    fixed_step_dt: float | None = None
    fixed_step_rate: float | None = None
    fixed_step_trajectories: int | None = None
    fixed_step_train_trajectories: int | None = None
    q0_low: tuple[float, ...] = ()
    q0_high: tuple[float, ...] = ()
    q0_points: tuple[tuple[float, ...], ...] = ()
    qd0_low: tuple[float, ...] = ()
    qd0_high: tuple[float, ...] = ()
    signal: str = "zero"
    ranges: Mapping[str, Any] = field(default_factory=dict)
    components: int = 3
    steps: int = 1
    seed: int = 0
    noise: float = 0.0
    rtol: float = 1e-10
    atol: float = 1e-10

    @property
    def rate(self) -> float:
        return max(self.rates)

    def total_trajectories(self, integrator: str | None = None) -> int:
        """Trajectories to simulate: explicit, or the paper's train/black-box/test counts."""
        if (integrator or self.integrator) == "rk4" and self.fixed_step_trajectories:
            return self.fixed_step_trajectories
        if self.trajectories is not None:
            return self.trajectories
        train = max(self.train_trajectories or 0, self.blackbox_train_trajectories or 0)
        return max(1, train + self.test_trajectories)


def data_config(spec: ModelSpec, table: Mapping[str, Any] | None = None) -> DataConfig:
    """Validate ``table`` (default: the spec's ``[data]``) for the spec's n and m.

    Errors name the spec's file and the field, e.g. ``preset:task4: field 'data.q0_low': ...``.
    """
    raw = dict(spec.data if table is None else table)
    n, m = spec.n, spec.m
    src = spec.source

    def fail(key, msg):
        raise DataError(f"{src}: field 'data.{key}': {msg}")

    unknown = sorted(set(raw) - set(DATA_KEYS))
    if unknown:
        fail(unknown[0], f"unknown key (allowed: {', '.join(DATA_KEYS)})")
    out: dict[str, Any] = {}
    ranges: dict[str, Any] = {}
    for key, value in raw.items():
        kind = DATA_KEYS[key][0]
        if kind == "int":
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                fail(key, f"expected a non-negative integer, got {value!r}")
            out[key] = value
        elif kind == "float":
            if (
                isinstance(value, bool)
                or not isinstance(value, (int, float))
                or not np.isfinite(value)
            ):
                fail(key, f"expected a number, got {value!r}")
            if key == "settle" and value < 0:
                fail(key, f"must not be negative, got {value!r}")
            if value < 0 or (value == 0 and key not in ("noise", "settle")):
                fail(key, f"must be positive, got {value!r}")
            out[key] = float(value)
        elif kind == "str":
            if not isinstance(value, str):
                fail(key, f"expected a string, got {value!r}")
            options = INTEGRATORS if key == "integrator" else SIGNAL_KINDS
            if value not in options:
                fail(key, f"expected one of {', '.join(options)}, got {value!r}")
            out[key] = value
        elif kind == "nrows":
            rows = value if isinstance(value, list) else None
            if not rows or not all(
                isinstance(r, list)
                and len(r) == n
                and all(
                    isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v)
                    for v in r
                )
                for r in rows
            ):
                fail(key, f"expected a list of rows of {n} finite numbers, got {value!r}")
            out[key] = tuple(tuple(float(v) for v in r) for r in rows)
        else:
            vals = value if isinstance(value, list) else [value]
            if not vals or not all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v)
                for v in vals
            ):
                fail(key, f"expected a list of finite numbers, got {value!r}")
            if kind == "nvec" and len(vals) != n:
                fail(key, f"expected {n} entries (one per coordinate), got {len(vals)}")
            if kind == "mvec" and m and len(vals) not in (1, m):
                fail(key, f"expected {m} entries (one per input), got {len(vals)}")
            if kind == "floats" and any(v <= 0 for v in vals):
                fail(key, f"rates must be positive, got {vals}")
            if kind == "mvec":
                ranges[key] = [float(v) for v in vals]
            else:
                out[key] = tuple(float(v) for v in vals)
    if "rate" in out and "rates" in out:
        fail("rates", "give either 'rate' or 'rates', not both")
    if "rate" in out:
        out["rates"] = (out.pop("rate"),)
    for a, b in (("q0_low", "q0_high"), ("qd0_low", "qd0_high")):
        if a in out and b in out and any(h < lo for lo, h in zip(out[a], out[b], strict=True)):
            fail(b, f"must not be below {a}")
        if (a in out) != (b in out):
            fail(b if a in out else a, f"give both {a} and {b}")
    for lo_key in [k for k in ranges if k.endswith("_low")]:
        hi_key = lo_key[:-4] + "_high"
        if hi_key in ranges:
            lo = np.broadcast_to(ranges[lo_key], (max(m, 1),))
            hi = np.broadcast_to(ranges[hi_key], (max(m, 1),))
            if np.any(hi < lo):
                fail(hi_key, f"must not be below {lo_key}")
    return DataConfig(ranges=ranges, **out)


# --------------------------------------------------------------------------------------------
# Arrays


@dataclass
class DatasetArrays:
    """The arrays and meta of a dataset file (flat over samples, see the module docstring)."""

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    p: np.ndarray
    u: np.ndarray
    traj: np.ndarray
    meta: dict

    def arrays(self) -> dict[str, np.ndarray]:
        return {k: getattr(self, k) for k in ARRAY_KEYS}

    @property
    def trajectory_ids(self) -> np.ndarray:
        return np.unique(self.traj)

    def __len__(self) -> int:
        return len(self.t)


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
    if total < 1:
        raise DataError(f"trajectories: must be at least 1, got {total}")
    seed = cfg.seed if seed is None else int(seed)
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
    kind = signal or cfg.signal
    if kind not in SIGNAL_KINDS:
        raise DataError(f"signal: expected one of {', '.join(SIGNAL_KINDS)}, got {kind!r}")
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
    )


def make_dataset(
    model: str | Path | ModelSpec | None = None,
    *,
    plan: DatasetPlan | None = None,
    fns: Mapping | None = None,
    compile: bool = True,
    cache: str | os.PathLike | None = None,
    progress: Callable[[int], None] | None = None,
    **options,
) -> DatasetArrays:
    """Simulate a model's data set (Section III-B) and return its arrays and meta.

    Either ``plan`` (from :func:`plan_dataset`) or ``model`` with the keyword ``options`` of
    :func:`plan_dataset`. ``fns`` overrides the model's functions (else
    :func:`symbolic.functions.functions`, compiled to C with :func:`symbolic.codegen.compiled`
    when ``compile``; ``cache`` is the compiled-code cache directory). ``progress`` is called
    with the number of trajectories finished.
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
    if fns is None:
        t0 = time.perf_counter()
        from .functions import functions

        fns = functions(spec)
        timings["functions"] = time.perf_counter() - t0
        if compile:
            from .codegen import compile_functions

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
    res = simulate(fns, x0, sigs, run, progress=progress)
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
        "seed": seed,
        "seeding": "trajectory k: numpy.random.default_rng([seed, k]) draws x0, then the signal",
        "noise": noise_meta,
        "splits": paper_splits(cfg, K, integ),
        "physics_samples": cfg.physics_samples,
        "rates": sorted(set(cfg.rates) | {sim.rate}) if integ == "cvodes" else [sim.rate],
        "max_mass_condition": res.info.get("max_mass_condition"),
        "compiled": is_compiled,
        "compiled_from_cache": from_cache,
        "package_version": _version("softpinn"),
        "casadi_version": _version("casadi"),
        "numpy_version": np.__version__,
        "timings_s": timings,
    }
    return DatasetArrays(meta=meta, **arrays)


def _version(dist: str) -> str | None:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return None


# --------------------------------------------------------------------------------------------
# Files


def write_dataset(path: str | os.PathLike, data: DatasetArrays, *, force: bool = False) -> Path:
    """Write ``data`` to ``path`` (``.npz``) atomically; refuse to overwrite without ``force``."""
    path = Path(path)
    if path.suffix != ".npz":
        raise DataError(f"--out {path}: a dataset file must end in .npz")
    if path.exists() and not force:
        raise DataError(f"--out {path}: file exists (use --force to overwrite)")
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}-", suffix=".npz", dir=path.parent)
    os.close(fd)
    try:
        with open(tmp, "wb") as fh:
            np.savez(
                fh,
                **{k: np.ascontiguousarray(v) for k, v in data.arrays().items()},
                meta=np.array(json.dumps(data.meta)),
            )
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return path


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def read_dataset(path: str | os.PathLike) -> DatasetArrays:
    """Read a dataset file (numpy only; the learning side has its own validating loader)."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"dataset file {path}: no such file")
    with np.load(path, allow_pickle=False) as z:
        missing = [k for k in (*ARRAY_KEYS, "meta") if k not in z.files]
        if missing:
            raise DataError(f"dataset file {path}: missing key(s) {', '.join(missing)}")
        arrays = {k: np.asarray(z[k]) for k in ARRAY_KEYS}
        meta = json.loads(str(z["meta"].item()))
    return DatasetArrays(meta=meta, **arrays)


# --------------------------------------------------------------------------------------------
# Resampling and splitting


def select_trajectories(
    data: DatasetArrays, ids: Sequence[int], *, renumber: bool = False
) -> DatasetArrays:
    """The samples of the trajectories ``ids`` (in that order); meta records the selection."""
    ids = [int(i) for i in ids]
    known = set(data.trajectory_ids.tolist())
    missing = [i for i in ids if i not in known]
    if missing:
        raise DataError(f"trajectories {missing} are not in the data set (it has {sorted(known)})")
    rows = (
        np.concatenate([np.flatnonzero(data.traj == i) for i in ids])
        if ids
        else np.zeros(0, dtype=int)
    )
    out = {k: getattr(data, k)[rows] for k in ARRAY_KEYS}
    if renumber:
        mapping = {old: new for new, old in enumerate(ids)}
        out["traj"] = np.array([mapping[int(i)] for i in out["traj"]], dtype=np.int64)
    meta = dict(data.meta)
    meta["selected_trajectories"] = ids
    if renumber and "signals" in meta:
        meta["signals"] = [data.meta["signals"][i] for i in ids]
        meta["initial_states"] = [data.meta["initial_states"][i] for i in ids]
        meta["trajectories"] = len(ids)
    return DatasetArrays(meta=meta, **out)


def resample(data: DatasetArrays, rate: float) -> DatasetArrays:
    """Keep every k-th sample so that the output rate becomes ``rate`` [Hz].

    The data set's rate must be a whole multiple of ``rate`` (the samples are exact states of the
    variable-step solution at the new rate's times, as the paper's 1000/100/50 Hz data).
    """
    src = float(data.meta.get("rate", 0.0))
    if not (rate > 0 and np.isfinite(rate)):
        raise DataError(f"rate: must be positive, got {rate}")
    ratio = src / rate
    if src <= 0 or ratio < 1 - 1e-9 or abs(ratio - round(ratio)) > 1e-9 * ratio:
        raise DataError(f"rate: {rate:g} Hz must divide the data set's rate {src:g} Hz")
    k = int(round(ratio))
    rows = np.concatenate([np.flatnonzero(data.traj == i)[::k] for i in data.trajectory_ids])
    meta = dict(data.meta)
    meta["rate"] = float(rate)
    meta["resampled_from_rate"] = src
    meta["samples_per_trajectory"] = int(len(rows) // max(len(data.trajectory_ids), 1))
    meta["simulation"] = dict(meta.get("simulation", {}), rate=float(rate))
    return DatasetArrays(meta=meta, **{key: getattr(data, key)[rows] for key in ARRAY_KEYS})


def split(data: DatasetArrays, name: str) -> DatasetArrays:
    """One of the paper's splits recorded in meta: ``train``, ``test`` or ``blackbox_train``."""
    splits = data.meta.get("splits", {})
    if name not in splits:
        raise DataError(f"split: expected one of {', '.join(splits)}, got {name!r}")
    return select_trajectories(data, splits[name])


def take_samples(data: DatasetArrays, count: int | None) -> DatasetArrays:
    """The first ``count`` samples in file order (whole trajectories first, the last one cut),
    e.g. the paper's ``physics_samples``; None keeps everything."""
    if count is None or count >= len(data):
        return data
    if count < 2:
        raise DataError(f"physics_samples: must be at least 2, got {count}")
    out = {k: getattr(data, k)[:count] for k in ARRAY_KEYS}
    meta = dict(data.meta, samples_kept=int(count))
    return DatasetArrays(meta=meta, **out)


def with_overrides(cfg: DataConfig, **kwargs) -> DataConfig:
    """A copy of ``cfg`` with fields replaced (values already validated by the caller)."""
    return replace(cfg, **{k: v for k, v in kwargs.items() if v is not None})


def signals_of(data: DatasetArrays) -> list[Signal]:
    """The input signals recorded in a data set's meta."""
    return [signal_from_dict(d) for d in data.meta.get("signals", [])]
