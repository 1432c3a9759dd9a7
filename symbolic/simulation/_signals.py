"""Input signals u(t): known functions of time, exact inside the integrator.

Every signal is a frozen value with two faces of one formula:

* ``signal.symbolic(t, p)`` builds a CasADi expression of the time ``t`` and of the signal's
  parameter vector ``p`` (``signal.params()``), so the integrator evaluates u(t) exactly at every
  internal step (no zero-order hold, no interpolation). Signals of equal ``structure()`` share one
  symbolic expression and differ only in ``p``, which lets many trajectories run in one mapped
  integrator;
* ``signal(t)`` evaluates the same formula with numpy on an array of times, giving (T, m).

Kinds (``m`` inputs, each formula per input j):

* ``zero``: u = 0;
* ``sinusoid``: u_j = offset_j + amplitude_j sin(2 pi frequency_j t + phase_j), the paper's motor
  signals (Section III-B);
* ``multisine``: u_j = offset_j + sum_k amplitude_kj sin(2 pi frequency_kj t + phase_kj);
* ``step``: u_j = levels_0j + sum_k (levels_kj - levels_(k-1)j) [t >= times_(k-1)];
* ``chirp``: u_j = offset_j + amplitude_j sin(2 pi (f0_j t + (f1_j - f0_j) t^2 / (2 T)) + phase_j),
  a linear sweep from f0 to f1 over T seconds.

:func:`sample_signal` draws a signal's parameters uniformly in ranges (a ``[data]`` table's
``amplitude_low``/``amplitude_high`` and so on) with a numpy ``Generator``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any, ClassVar

import casadi as ca
import numpy as np

from softpinn.errors import UserError

KINDS = ("zero", "sinusoid", "multisine", "step", "chirp")
TWO_PI = 2.0 * np.pi


def _vec(x, m: int, name: str) -> tuple[float, ...]:
    a = np.asarray(x, dtype=float).reshape(-1)
    if a.size == 1 and m != 1:
        a = np.full(m, float(a[0]))
    if a.size != m:
        raise UserError(f"signal field '{name}': expected {m} values (one per input), got {a.size}")
    if not np.all(np.isfinite(a)):
        raise UserError(f"signal field '{name}': values must be finite, got {a.tolist()}")
    return tuple(float(v) for v in a)


def _mat(x, rows: int, m: int, name: str) -> tuple[tuple[float, ...], ...]:
    a = np.asarray(x, dtype=float)
    if a.ndim == 1 and rows == 1:
        a = a[None, :]
    if a.shape != (rows, m):
        raise UserError(f"signal field '{name}': expected shape ({rows}, {m}), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise UserError(f"signal field '{name}': values must be finite")
    return tuple(tuple(float(v) for v in row) for row in a)


class Signal:
    """Base class: a known input u(t) in R^m."""

    kind: ClassVar[str] = ""
    m: int

    def params(self) -> np.ndarray:
        """The parameter vector p fed to :meth:`symbolic`."""
        raise NotImplementedError

    def structure(self) -> tuple:
        """Signals with equal structure share one symbolic expression (differ only in p)."""
        return (self.kind, self.m)

    def symbolic(self, t, p):
        """u(t) as a CasADi (m, 1) expression of time ``t`` and parameters ``p``."""
        raise NotImplementedError

    def __call__(self, t) -> np.ndarray:
        """u at the times ``t`` (any shape (T,)), as a (T, m) array."""
        raise NotImplementedError

    def to_dict(self) -> dict[str, Any]:
        d = {"kind": self.kind}
        d.update({k: _plain(v) for k, v in asdict(self).items()})
        return d

    def function(self) -> ca.Function:
        """u as a casadi Function ``u(t, p) -> u``."""
        t = ca.MX.sym("t")
        p = ca.MX.sym("p", len(self.params()))
        return ca.Function(f"u_{self.kind}", [t, p], [self.symbolic(t, p)], ["t", "p"], ["u"])


def _plain(v):
    if isinstance(v, tuple):
        return [_plain(x) for x in v]
    return v


@dataclass(frozen=True)
class Zero(Signal):
    m: int
    kind: ClassVar[str] = "zero"

    def params(self):
        return np.zeros(0)

    def symbolic(self, t, p):
        return ca.MX.zeros(self.m, 1) if isinstance(t, ca.MX) else ca.SX.zeros(self.m, 1)

    def __call__(self, t):
        return np.zeros((np.asarray(t).size, self.m))


@dataclass(frozen=True)
class Sinusoid(Signal):
    amplitude: tuple[float, ...]
    frequency: tuple[float, ...]
    phase: tuple[float, ...]
    offset: tuple[float, ...]
    kind: ClassVar[str] = "sinusoid"

    def __post_init__(self):
        m = len(self.amplitude)
        for name in ("amplitude", "frequency", "phase", "offset"):
            object.__setattr__(self, name, _vec(getattr(self, name), m, name))

    @property
    def m(self):
        return len(self.amplitude)

    def params(self):
        return np.concatenate([self.amplitude, self.frequency, self.phase, self.offset])

    def symbolic(self, t, p):
        m = self.m
        a, f, ph, off = (p[i * m : (i + 1) * m] for i in range(4))
        return off + a * ca.sin(TWO_PI * f * t + ph)

    def __call__(self, t):
        t = np.asarray(t, dtype=float).reshape(-1, 1)
        a, f, ph, off = (
            np.asarray(x) for x in (self.amplitude, self.frequency, self.phase, self.offset)
        )
        return off + a * np.sin(TWO_PI * f * t + ph)


@dataclass(frozen=True)
class Multisine(Signal):
    amplitude: tuple[tuple[float, ...], ...]  # (K, m)
    frequency: tuple[tuple[float, ...], ...]  # (K, m)
    phase: tuple[tuple[float, ...], ...]  # (K, m)
    offset: tuple[float, ...]  # (m,)
    kind: ClassVar[str] = "multisine"

    def __post_init__(self):
        a = np.atleast_2d(np.asarray(self.amplitude, dtype=float))
        k, m = a.shape
        for name in ("amplitude", "frequency", "phase"):
            object.__setattr__(self, name, _mat(getattr(self, name), k, m, name))
        object.__setattr__(self, "offset", _vec(self.offset, m, "offset"))

    @property
    def m(self):
        return len(self.offset)

    @property
    def components(self):
        return len(self.amplitude)

    def structure(self):
        return (self.kind, self.m, self.components)

    def params(self):
        return np.concatenate(
            [np.ravel(self.amplitude), np.ravel(self.frequency), np.ravel(self.phase), self.offset]
        )

    def symbolic(self, t, p):
        m, k = self.m, self.components
        km = k * m
        u = p[3 * km : 3 * km + m]
        for c in range(k):
            s = slice(c * m, (c + 1) * m)
            a, f, ph = p[s], p[km:][s], p[2 * km :][s]
            u = u + a * ca.sin(TWO_PI * f * t + ph)
        return u

    def __call__(self, t):
        t = np.asarray(t, dtype=float).reshape(-1, 1, 1)
        a, f, ph = (np.asarray(x)[None] for x in (self.amplitude, self.frequency, self.phase))
        return np.asarray(self.offset) + np.sum(a * np.sin(TWO_PI * f * t + ph), axis=1)


@dataclass(frozen=True)
class Step(Signal):
    times: tuple[float, ...]  # (S,) switching times, increasing
    levels: tuple[tuple[float, ...], ...]  # (S + 1, m) value before the first and after each
    kind: ClassVar[str] = "step"

    def __post_init__(self):
        times = np.asarray(self.times, dtype=float).reshape(-1)
        if np.any(np.diff(times) < 0) or not np.all(np.isfinite(times)):
            raise UserError(
                f"signal field 'times': must be finite and increasing, got {times.tolist()}"
            )
        lv = np.atleast_2d(np.asarray(self.levels, dtype=float))
        object.__setattr__(self, "times", tuple(float(x) for x in times))
        object.__setattr__(self, "levels", _mat(lv, len(times) + 1, lv.shape[1], "levels"))

    @property
    def m(self):
        return len(self.levels[0])

    def structure(self):
        return (self.kind, self.m, len(self.times))

    def params(self):
        return np.concatenate([self.times, np.ravel(self.levels)])

    def symbolic(self, t, p):
        s, m = len(self.times), self.m
        lv = p[s:]
        u = lv[0:m]
        for k in range(s):
            u = u + (lv[(k + 1) * m : (k + 2) * m] - lv[k * m : (k + 1) * m]) * (t >= p[k])
        return u

    def __call__(self, t):
        t = np.asarray(t, dtype=float).reshape(-1)
        lv = np.asarray(self.levels)
        idx = np.searchsorted(np.asarray(self.times), t, side="right")
        return lv[idx]


@dataclass(frozen=True)
class Chirp(Signal):
    amplitude: tuple[float, ...]
    f0: tuple[float, ...]
    f1: tuple[float, ...]
    sweep_time: float
    phase: tuple[float, ...]
    offset: tuple[float, ...]
    kind: ClassVar[str] = "chirp"

    def __post_init__(self):
        m = len(np.atleast_1d(self.amplitude))
        for name in ("amplitude", "f0", "f1", "phase", "offset"):
            object.__setattr__(self, name, _vec(getattr(self, name), m, name))
        if not self.sweep_time > 0:
            raise UserError(f"signal field 'sweep_time': must be positive, got {self.sweep_time}")
        object.__setattr__(self, "sweep_time", float(self.sweep_time))

    @property
    def m(self):
        return len(self.amplitude)

    def params(self):
        return np.concatenate(
            [self.amplitude, self.f0, self.f1, self.phase, self.offset, [self.sweep_time]]
        )

    def symbolic(self, t, p):
        m = self.m
        a, f0, f1, ph, off = (p[i * m : (i + 1) * m] for i in range(5))
        big_t = p[5 * m]
        return off + a * ca.sin(TWO_PI * (f0 * t + (f1 - f0) * t**2 / (2 * big_t)) + ph)

    def __call__(self, t):
        t = np.asarray(t, dtype=float).reshape(-1, 1)
        a, f0, f1, ph, off = (
            np.asarray(x) for x in (self.amplitude, self.f0, self.f1, self.phase, self.offset)
        )
        return off + a * np.sin(TWO_PI * (f0 * t + (f1 - f0) * t**2 / (2 * self.sweep_time)) + ph)


_CLASSES = {c.kind: c for c in (Zero, Sinusoid, Multisine, Step, Chirp)}


def signal_from_dict(d: Mapping[str, Any]) -> Signal:
    """Rebuild a signal from :meth:`Signal.to_dict` (as stored in a dataset's ``meta``)."""
    d = dict(d)
    kind = d.pop("kind", None)
    if kind not in _CLASSES:
        raise UserError(f"signal field 'kind': expected one of {', '.join(KINDS)}, got {kind!r}")
    try:
        return _CLASSES[kind](**d)
    except TypeError as exc:
        raise UserError(f"signal of kind {kind!r}: {exc}") from None


def _range(
    ranges: Mapping[str, Any], name: str, m: int, default: tuple[float, float]
) -> tuple[np.ndarray, np.ndarray]:
    lo = ranges.get(f"{name}_low", default[0])
    hi = ranges.get(f"{name}_high", default[1])
    lo = np.asarray(_vec(lo, m, f"{name}_low"))
    hi = np.asarray(_vec(hi, m, f"{name}_high"))
    if np.any(hi < lo):
        raise UserError(
            f"signal field '{name}_high': must not be below {name}_low, got "
            f"{hi.tolist()} < {lo.tolist()}"
        )
    return lo, hi


#: Ranges used when a ``[data]`` table gives none.
DEFAULT_RANGES = {
    "amplitude": (0.0, 1.0),
    "offset": (0.0, 0.0),
    "frequency": (0.1, 1.0),
    "phase": (0.0, 0.0),
}


def sample_signal(
    kind: str,
    m: int,
    rng: np.random.Generator,
    ranges: Mapping[str, Any] | None = None,
    *,
    duration: float = 10.0,
    components: int = 3,
    steps: int = 1,
) -> Signal:
    """Draw one signal of ``kind`` with parameters uniform in ``ranges``.

    ``ranges`` maps ``amplitude_low``/``_high``, ``offset_*``, ``frequency_*`` and ``phase_*`` to
    scalars or per-input lists (defaults :data:`DEFAULT_RANGES`). ``step`` draws ``steps``
    switching times uniform in [0, duration] and levels offset + amplitude * U(-1, 1) per
    segment; ``chirp`` sweeps from ``frequency_low`` to ``frequency_high`` over ``duration``
    (amplitude, offset and phase drawn). With m = 0 every kind is the zero signal.
    """
    ranges = dict(ranges or {})
    if kind not in KINDS:
        raise UserError(f"signal: expected one of {', '.join(KINDS)}, got {kind!r}")
    if kind == "zero" or m == 0:
        return Zero(m)

    def draw(name, shape=None):
        lo, hi = _range(ranges, name, m, DEFAULT_RANGES[name])
        size = (m,) if shape is None else (shape, m)
        return lo + (hi - lo) * rng.uniform(size=size)

    if kind == "sinusoid":
        return Sinusoid(
            amplitude=draw("amplitude"),
            frequency=draw("frequency"),
            phase=draw("phase"),
            offset=draw("offset"),
        )
    if kind == "multisine":
        return Multisine(
            amplitude=draw("amplitude", components),
            frequency=draw("frequency", components),
            phase=draw("phase", components),
            offset=draw("offset"),
        )
    if kind == "step":
        times = np.sort(rng.uniform(0.0, duration, size=steps))
        off = draw("offset")
        amp = draw("amplitude", steps + 1)
        levels = off + amp * rng.uniform(-1.0, 1.0, size=(steps + 1, m))
        return Step(times=times, levels=levels)
    lo, hi = _range(ranges, "frequency", m, DEFAULT_RANGES["frequency"])
    return Chirp(
        amplitude=draw("amplitude"),
        f0=lo,
        f1=hi,
        sweep_time=duration,
        phase=draw("phase"),
        offset=draw("offset"),
    )
