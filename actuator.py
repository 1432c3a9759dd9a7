"""Actuator dynamics between the commands a user records and the forces that reach the arm
(issue 43, item 2): per input a dead time ``delay`` [s] and then a first-order lag
``time_constant`` [s],

    τ ẏ(t) = u(t - d) - y(t),    y the input the arm feels (eq. 4's u),

as a pneumatic chamber fills after a transport delay, or a tendon motor follows its set point.
The actuator does not depend on the arm, so its states are a function of the command history
alone: training, prediction and the baselines pass the recorded commands through
:meth:`Actuator.apply` (exact for commands linear between samples), and the networks learn the
arm from (q, q̇, y). Before the first sample the command is taken as held at its first value and
the actuator as settled (y = u), as a recording that starts at rest.

Where the recorded u already is the actuator's output (measured pressures or tensions), the
actuator is the identity (``none``); commands need one.

Text form (``softpinn train --actuator``, a spec's ``[actuator]`` table): ``TAU:DELAY``, each a
number for every input or a comma-separated list with one per input, e.g. ``0.2:0.15`` or
``0.2,0.2,0.3:0.1,0.1,0.15``; ``none`` for the identity.

This module imports numpy only (a leaf that symbolic, learn and bridge share).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from softpinn.errors import UserError

#: the longest time constant and dead time accepted [s]: beyond these the "actuator" is a
#: mistake of units (milliseconds given as seconds)
MAX_SECONDS = 60.0


def _values(raw, m: int | None, what: str) -> tuple[float, ...]:
    if isinstance(raw, str):
        parts = [p.strip() for p in raw.split(",")]
        try:
            vals = [float(p) for p in parts]
        except ValueError:
            raise UserError(f"actuator: {what} must be a number of seconds or a comma-separated "
                            f"list with one per input, got {raw!r}") from None
    elif isinstance(raw, int | float) and not isinstance(raw, bool):
        vals = [float(raw)]
    elif isinstance(raw, Sequence) and not isinstance(raw, str) and raw and all(
            isinstance(v, int | float) and not isinstance(v, bool) for v in raw):
        vals = [float(v) for v in raw]
    else:
        raise UserError(f"actuator: {what} must be a number of seconds or a list with one per "
                        f"input, got {raw!r}")
    bad = [v for v in vals if not (math.isfinite(v) and 0 <= v <= MAX_SECONDS)]
    if bad:
        raise UserError(f"actuator: {what} must be between 0 and {MAX_SECONDS:g} s, got {bad[0]!r}")
    if m is not None and len(vals) not in (1, m):
        raise UserError(f"actuator: {what} has {len(vals)} values; the data have {m} inputs "
                        "(give one value for all, or one per input)")
    return tuple(vals)


@dataclass(frozen=True)
class Actuator:
    """Per input a first-order lag ``time_constant`` and a dead time ``delay`` [s] (one value:
    every input). ``source`` says where the values came from (``given``, ``data``: the dataset's
    metadata, ``identified``: :func:`softpinn.learn.identify_actuator`)."""

    time_constant: tuple[float, ...] = (0.0,)
    delay: tuple[float, ...] = (0.0,)
    source: str = "given"

    def __post_init__(self):
        tau = _values(list(self.time_constant), None, "time_constant")
        delay = _values(list(self.delay), None, "delay")
        if len(tau) != len(delay) and 1 not in (len(tau), len(delay)):
            raise UserError(f"actuator: {len(tau)} time constants but {len(delay)} delays")
        object.__setattr__(self, "time_constant", tau)
        object.__setattr__(self, "delay", delay)

    @classmethod
    def parse(cls, text: str, m: int | None = None, *, source: str = "given") -> Actuator:
        """``TAU:DELAY`` (see the module's doc) or ``none``."""
        text = str(text).strip()
        if text.lower() == "none":
            return cls(source=source)
        if text.count(":") != 1:
            raise UserError(f"actuator: expected TAU:DELAY in seconds (e.g. 0.2:0.15, lists "
                            f"with one value per input allowed) or none, got {text!r}")
        tau, delay = text.split(":")
        return cls(_values(tau, m, "time constant"), _values(delay, m, "delay"), source)

    @classmethod
    def from_dict(cls, d: Mapping, m: int | None = None, *, source: str = "given") -> Actuator:
        """From ``{"time_constant": ..., "delay": ...}`` (a spec's ``[actuator]`` table, a
        dataset's ``meta["actuator"]``); unknown keys are refused."""
        if not isinstance(d, Mapping):
            raise UserError(f"actuator: expected a table with time_constant and delay, got {d!r}")
        unknown = sorted(set(d) - {"time_constant", "delay", "source"})
        if unknown:
            raise UserError(f"actuator: unknown key(s) {', '.join(unknown)} (expected "
                            "time_constant, delay)")
        return cls(_values(d.get("time_constant", 0.0), m, "time_constant"),
                   _values(d.get("delay", 0.0), m, "delay"), str(d.get("source", source)))

    def to_dict(self) -> dict:
        return {"time_constant": list(self.time_constant), "delay": list(self.delay),
                "source": self.source}

    def text(self) -> str:
        """The text form, ``none`` for the identity."""
        if self.is_identity:
            return "none"
        f = lambda v: ",".join(f"{x:g}" for x in v)
        return f"{f(self.time_constant)}:{f(self.delay)}"

    def describe(self) -> str:
        """One phrase for notes and reports."""
        if self.is_identity:
            return "none (u reaches the arm as recorded)"
        one = lambda v, unit: (f"{v[0]:g} {unit}" if len(set(v)) == 1
                               else ", ".join(f"{x:g}" for x in v) + f" {unit}")
        return (f"lag {one(self.time_constant, 's')} after a dead time "
                f"{one(self.delay, 's')} ({self.source})")

    @property
    def is_identity(self) -> bool:
        return not any(self.time_constant) and not any(self.delay)

    def per_input(self, m: int) -> tuple[np.ndarray, np.ndarray]:
        """(tau, delay), each (m,)."""
        tau, delay = (np.broadcast_to(np.asarray(v, float), (m,)).copy() if len(v) in (1, m)
                      else None for v in (self.time_constant, self.delay))
        if tau is None or delay is None:
            raise UserError(f"actuator {self.text()}: has values for "
                            f"{max(len(self.time_constant), len(self.delay))} inputs, the data "
                            f"have {m}")
        return tau, delay

    def apply(self, t: np.ndarray, u: np.ndarray) -> np.ndarray:
        """The actuator's output y (T, m) at the times ``t`` (T,) of one trajectory under the
        commands ``u`` (T, m), linear between samples."""
        t = np.asarray(t, float)
        u = np.asarray(u, float)
        if self.is_identity:
            return u.copy()
        tau, delay = self.per_input(u.shape[1])
        return np.stack([lag(t, delayed(t, u[:, j], delay[j]), tau[j])
                         for j in range(u.shape[1])], axis=1)

    def apply_trajectories(self, t: np.ndarray, u: np.ndarray, traj: np.ndarray) -> np.ndarray:
        """:meth:`apply` on every trajectory of a dataset's rows (contiguous per ``traj``)."""
        out = np.array(u, dtype=float, copy=True)
        if self.is_identity:
            return out
        for tid in np.unique(traj):
            rows = np.flatnonzero(traj == tid)
            out[rows] = self.apply(t[rows], u[rows])
        return out


def delayed(t: np.ndarray, c: np.ndarray, d: float) -> np.ndarray:
    """c(t - d), linear between samples, held at c[0] before the first sample."""
    return c.copy() if d == 0 else np.interp(t - d, t, c)


def lag(t: np.ndarray, c: np.ndarray, tau: float) -> np.ndarray:
    """y with τ ẏ = c - y, y[0] = c[0], exact for c linear between the samples ``t``."""
    if tau == 0 or len(t) < 2:
        return c.copy()
    h = np.diff(t)
    a = np.exp(-h / tau)
    b1 = 1 - tau / h * (1 - a)  # the weight of the step's end value (first-order hold)
    b0 = 1 - a - b1
    drive = b0 * c[:-1] + b1 * c[1:]
    if np.allclose(h, h[0], rtol=1e-9, atol=0):  # uniform: an IIR filter
        from scipy.signal import lfilter  # noqa: PLC0415 (scipy only where filtering runs)

        y, _ = lfilter([1.0], [1.0, -a[0]], drive, zi=[a[0] * c[0]])
        return np.concatenate([[c[0]], y])
    y = np.empty_like(c)
    y[0] = c[0]
    for k in range(len(h)):
        y[k + 1] = a[k] * y[k] + drive[k]
    return y
