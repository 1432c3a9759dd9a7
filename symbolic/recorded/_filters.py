"""Smoothers for recorded trajectories, with the derivatives they define (``docs/import.md``).

:func:`parse_smoother` reads the ``--smooth`` text; :func:`smooth` returns the smoothed values
and their first and second time derivatives, along axis 0 of (N, k) arrays sampled at times t:

* ``none``: the samples as they are;
* ``movmean:W``: MATLAB's ``movmean(y, W)``: the mean over a window of W samples centred on each
  sample (for even W, W/2 before and W/2 - 1 after), shrunk at the ends;
* ``savgol:W:P``: Savitzky-Golay, the least-squares polynomial of degree P over the W samples
  around each sample (W odd), ends fitted by the first and last windows
  (``scipy.signal.savgol_filter``, mode ``interp``); on non-uniform times the same local fits are
  made in time;
* ``polyfit:DEG:W``: piecewise polynomials as the paper's use of MATLAB's ``polyfit``: a
  least-squares polynomial of degree DEG in t over each run of W consecutive samples (a short
  remainder joins the last run).

Savitzky-Golay and polyfit differentiate their polynomials; ``none`` and ``movmean`` have no
derivative of their own, and their velocities and accelerations are central differences of
``differences`` order: 2 (the default; ``numpy.gradient`` with the times t, 3 samples, second
order also on non-uniform times) or 4 (the derivatives at each sample of the quartic through the
5 samples around it: on uniform times the stencils (1, -8, 0, 8, -1) / 12h and (-1, 16, -30, 16,
-1) / 12h², on non-uniform times the same interpolation in time; the two samples at each end,
where the quartic would be one-sided and amplify noise up to 8 times, keep order 2's). Order 2
keeps
sin(ωh) / (ωh) of a sinusoid's velocity (91 % of a 0.6 Hz swing sampled at 5 Hz), order 4
(8 sin(ωh) - sin(2ωh)) / (6ωh) (99 %), at 1.34 times the noise (white noise σ on the samples:
0.71 σ/h against 0.95 σ/h on the velocities).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from softpinn.errors import UserError

METHODS = ("none", "movmean", "savgol", "polyfit")
USAGE = "none | movmean:W | savgol:W:P | polyfit:DEG:W"
#: The orders of the central differences for smoothers without a derivative of their own.
DIFFERENCES = (2, 4)


class FilterError(UserError):
    """A bad smoother setting, or data too short for it."""


@dataclass(frozen=True)
class Smoother:
    """A parsed ``--smooth`` setting: ``window`` samples, polynomial ``degree``."""

    method: str = "none"
    window: int = 0
    degree: int = 0
    differences: int = 2

    def __post_init__(self):
        if isinstance(self.differences, bool) or self.differences not in DIFFERENCES:
            raise FilterError(f"differences: expected one of {', '.join(map(str, DIFFERENCES))} "
                              f"(the order of the central differences), got "
                              f"{self.differences!r}")

    @property
    def has_derivative(self) -> bool:
        return self.method in ("savgol", "polyfit")

    @property
    def min_samples(self) -> int:
        """The fewest samples a trajectory needs for this smoother."""
        fewest = 5 if self.differences == 4 else 2
        if self.method == "savgol":
            return self.window
        if self.method == "polyfit":
            return self.degree + 1
        if self.method == "movmean":  # a longer window flattens the whole trajectory
            return max(self.window, fewest)
        return fewest

    def describe(self) -> dict:
        d = {"method": self.method, "text": str(self)}
        if self.method != "none":
            d["window_samples"] = self.window
        if self.method in ("savgol", "polyfit"):
            d["degree"] = self.degree
        if self.has_derivative:
            d["derivatives"] = "derivatives of the fitted polynomials"
        elif self.differences == 4:
            d["differences"] = 4
            d["derivatives"] = ("fourth-order central differences (the quartic through the 5 "
                                "samples around each)")
        else:
            d["differences"] = 2
            d["derivatives"] = "central differences (numpy.gradient with t)"
        return d

    @property
    def label(self) -> str:
        """The setting's text, with the differences' order where it is not the default 2 and
        the smoother uses differences (``none, differences 4``)."""
        if self.has_derivative or self.differences == 2:
            return str(self)
        return f"{self}, differences {self.differences}"

    def __str__(self) -> str:
        if self.method == "none":
            return "none"
        if self.method == "movmean":
            return f"movmean:{self.window}"
        if self.method == "savgol":
            return f"savgol:{self.window}:{self.degree}"
        return f"polyfit:{self.degree}:{self.window}"


def parse_smoother(text: str | Smoother, differences: int | None = None) -> Smoother:
    """``none``, ``movmean:W``, ``savgol:W:P`` or ``polyfit:DEG:W`` as a :class:`Smoother`;
    ``differences``: the order of the central differences where the smoother has no derivative
    of its own (2 or 4; None keeps a given Smoother's, 2 for a text)."""
    if isinstance(text, Smoother):
        if differences is None:
            return text
        return dataclasses.replace(text, differences=differences)
    sm = _parse(text)
    return sm if differences is None else dataclasses.replace(sm, differences=differences)


def _parse(text: str) -> Smoother:
    parts = str(text).strip().split(":")
    method, args = parts[0], parts[1:]
    if method not in METHODS:
        raise FilterError(f"smooth: expected {USAGE}, got {text!r}")
    counts = {"none": 0, "movmean": 1, "savgol": 2, "polyfit": 2}
    if len(args) != counts[method]:
        raise FilterError(f"smooth: expected {USAGE}, got {text!r}")
    try:
        nums = [int(a) for a in args]
    except ValueError:
        raise FilterError(f"smooth: {text!r}: window and degree must be integers") from None
    if method == "none":
        return Smoother()
    if method == "movmean":
        (w,) = nums
        if w < 1:
            raise FilterError(f"smooth: {text!r}: the window must be at least 1 sample")
        return Smoother("movmean", window=w)
    if method == "savgol":
        w, p = nums
        if w < 3 or w % 2 == 0:
            raise FilterError(f"smooth: {text!r}: the window must be an odd number >= 3")
        if not 0 <= p < w:
            raise FilterError(f"smooth: {text!r}: the degree must be in 0 .. window - 1")
        return Smoother("savgol", window=w, degree=p)
    deg, w = nums
    if deg < 0:
        raise FilterError(f"smooth: {text!r}: the degree must not be negative")
    if w < deg + 1:
        raise FilterError(f"smooth: {text!r}: a window of {w} samples cannot fit degree {deg} "
                          f"(needs at least {deg + 1})")
    return Smoother("polyfit", window=w, degree=deg)


# --------------------------------------------------------------------------------------------


def smooth(t, y, smoother: str | Smoother = "none"):
    """Smooth ``y`` (N, k) sampled at increasing times ``t`` (N,); returns ``(y, yd, ydd)``."""
    sm = parse_smoother(smoother)
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    squeeze = y.ndim == 1
    if squeeze:
        y = y[:, None]
    if len(t) < sm.min_samples:
        raise FilterError(f"smooth: {sm.label} needs at least {sm.min_samples} samples per "
                          f"trajectory, got {len(t)}")
    if sm.method == "none":
        out = _with_differences(t, y.copy(), sm.differences)
    elif sm.method == "movmean":
        out = _with_differences(t, movmean(y, sm.window), sm.differences)
    elif sm.method == "savgol":
        out = savgol(t, y, sm.window, sm.degree)
    else:
        out = polyfit_pieces(t, y, sm.degree, sm.window)
    return tuple(a[:, 0] for a in out) if squeeze else out


def _with_differences(t, y, order: int = 2):
    yd = gradient(t, y)
    ydd = gradient(t, yd)
    if order == 4 and len(t) >= 5:
        # inside, the quartic through the 5 samples around each (it passes through y); the
        # two samples at each end keep numpy.gradient's, where the quartic would be one-sided
        # and multiply the noise by up to 8 (the end sample: (-25, 48, -36, 16, -3) / 12h)
        fit = savgol(t, y, 5, 4) if is_uniform(t) else local_fits(t, y, 5, 4)
        yd[2:-2], ydd[2:-2] = fit[1][2:-2], fit[2][2:-2]
    return y, yd, ydd


def gradient(t, y):
    """Central differences in the interior, one-sided at the ends (``numpy.gradient``)."""
    if len(t) < 2:
        return np.zeros_like(y)
    return np.gradient(y, t, axis=0, edge_order=1 if len(t) < 3 else 2)


def movmean(y, window: int):
    """MATLAB's ``movmean(y, window)`` along axis 0 (centred; shrunk at the ends)."""
    y = np.asarray(y, dtype=float)
    N = len(y)
    before = window // 2 if window % 2 == 0 else (window - 1) // 2
    after = window - 1 - before
    idx = np.arange(N)
    lo = np.clip(idx - before, 0, N)
    hi = np.clip(idx + after + 1, 0, N)
    c = np.concatenate([np.zeros((1,) + y.shape[1:]), np.cumsum(y, axis=0)])
    return (c[hi] - c[lo]) / (hi - lo).reshape((-1,) + (1,) * (y.ndim - 1))


def is_uniform(t, rtol: float = 1e-9) -> bool:
    dt = np.diff(np.asarray(t, dtype=float))
    return len(dt) > 0 and bool(np.all(np.abs(dt - dt.mean()) <= rtol * abs(dt.mean())))


def savgol(t, y, window: int, degree: int):
    """Savitzky-Golay values and first two derivatives; scipy on uniform times, the same local
    polynomial fits made in time otherwise."""
    if is_uniform(t):
        from scipy.signal import savgol_filter  # deferred: scipy.signal is slow to import

        dt = float(np.mean(np.diff(t)))
        out = [savgol_filter(y, window, degree, deriv=k, delta=dt, axis=0, mode="interp")
               for k in range(3)]
        if degree < 2:  # the fitted polynomial's second derivative is 0 (scipy says so too)
            out[2] = np.zeros_like(y)
        return tuple(out)
    return local_fits(t, y, window, degree)


def local_fits(t, y, window: int, degree: int):
    """For each sample, the least-squares polynomial of ``degree`` in t over the ``window``
    samples around it (the first and last windows at the ends), evaluated with its first two
    derivatives at that sample: Savitzky-Golay in time."""
    t = np.asarray(t, dtype=float)
    N, half = len(t), window // 2
    start = np.clip(np.arange(N) - half, 0, N - window)
    rows = start[:, None] + np.arange(window)  # (N, W)
    out = [np.empty_like(y) for _ in range(3)]
    chunk = 4096
    for a in range(0, N, chunk):
        idx = rows[a : a + chunk]
        centre = t[a : a + chunk, None]
        scale = np.maximum(np.abs(t[idx] - centre).max(axis=1, keepdims=True), 1e-300)
        x = (t[idx] - centre) / scale  # in [-1, 1], the sample itself at 0
        V = x[..., None] ** np.arange(degree + 1)  # (B, W, P+1)
        coef = _lstsq(V, y[idx])
        s = scale[:, 0]
        out[0][a : a + chunk] = coef[:, 0]
        out[1][a : a + chunk] = coef[:, 1] / s[:, None] if degree >= 1 else 0.0
        out[2][a : a + chunk] = 2 * coef[:, 2] / s[:, None] ** 2 if degree >= 2 else 0.0
    return tuple(out)


def _lstsq(V, Y):
    """Batched least squares V c = Y: V (B, W, P), Y (B, W, k) -> c (B, P, k) (via QR)."""
    Q, R = np.linalg.qr(V)
    return np.linalg.solve(R, np.einsum("bwp,bwk->bpk", Q, Y))


def polyfit_pieces(t, y, degree: int, window: int):
    """Piecewise least-squares polynomials of ``degree`` in t over consecutive runs of
    ``window`` samples (a remainder shorter than ``degree + 1`` or half a window joins the last
    run); values and first two derivatives of each run's polynomial at its samples."""
    t = np.asarray(t, dtype=float)
    N = len(t)
    bounds = list(range(0, N, window)) + [N]
    if len(bounds) > 2 and bounds[-1] - bounds[-2] < max(degree + 1, window // 2):
        del bounds[-2]
    out = [np.empty_like(y) for _ in range(3)]
    P = np.polynomial.Polynomial
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        tt = t[a:b]
        deg = min(degree, b - a - 1)
        for j in range(y.shape[1]):
            p = P.fit(tt, y[a:b, j], deg)
            out[0][a:b, j] = p(tt)
            out[1][a:b, j] = p.deriv(1)(tt) if deg >= 1 else 0.0
            out[2][a:b, j] = p.deriv(2)(tt) if deg >= 2 else 0.0
    return tuple(out)


# --------------------------------------------------------------------------------------------


def resample_uniform(t, y, yd, ydd, rate: float):
    """Values at the uniform times t0, t0 + 1/rate, ... <= t_end: ``y`` and ``yd`` by cubic
    Hermite interpolation with the derivatives as slopes (exact for cubics, and consistent:
    the interpolated y's slope is the interpolated yd at the samples), ``ydd`` linearly."""
    t = np.asarray(t, dtype=float)
    count = int(np.floor((t[-1] - t[0]) * rate * (1 + 1e-12))) + 1
    tn = t[0] + np.arange(count) / rate
    tn[-1] = min(tn[-1], t[-1])
    k = np.clip(np.searchsorted(t, tn, side="right") - 1, 0, len(t) - 2)
    h = (t[k + 1] - t[k])[:, None]
    s = (tn - t[k])[:, None] / h

    def hermite(v, dv):
        h00 = 2 * s**3 - 3 * s**2 + 1
        h10 = s**3 - 2 * s**2 + s
        h01 = -2 * s**3 + 3 * s**2
        h11 = s**3 - s**2
        return h00 * v[k] + h10 * h * dv[k] + h01 * v[k + 1] + h11 * h * dv[k + 1]

    ydd_n = ydd[k] + s * (ydd[k + 1] - ydd[k])
    return tn, hermite(y, yd), hermite(yd, ydd), ydd_n
