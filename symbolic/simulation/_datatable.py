"""The ``[data]`` table of a spec (``docs/spec.md``): how to generate data for a robot, after
the paper (Section III-B, Table III). :func:`data_config` validates it into a
:class:`DataConfig`; unknown keys, wrong types and bad values are refused with a message naming
the file and the field."""


from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from softpinn.errors import UserError
from softpinn.symbolic.simulation._signals import KINDS as SIGNAL_KINDS
from softpinn.symbolic.simulation._sim_config import INTEGRATORS
from softpinn.symbolic.spec._model_spec import ModelSpec


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
            if key == "seed" and value > 2**32 - 1:
                fail(key, f"expected an integer from 0 to 2**32 - 1, got {value!r}")
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



def with_overrides(cfg: DataConfig, **kwargs) -> DataConfig:
    """A copy of ``cfg`` with fields replaced (values already validated by the caller)."""
    return replace(cfg, **{k: v for k, v in kwargs.items() if v is not None})

