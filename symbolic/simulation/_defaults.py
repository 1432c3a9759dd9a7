"""Data defaults for a spec without a ``[data]`` table, from its physics (``docs/spec.md``).

Without them every trajectory would start at q = 0 with zero input: identical trajectories, and
an arm released far from its rest state (a hanging arm stretched by metres). Instead
:func:`physics_data_table` linearises the model about its rest state and scales everything to it:

1. the rest state: the equilibrium G(q) = 0 at zero input, found by Newton's method from q = 0;
   where a PCC segment is stretched or compressed there by more than a quarter of its length
   and the actuation can hold the straight arm at its rest length, the constant input that does
   (as the presets' offsets hold task 4's and task 5's hanging arms); no equilibrium, or one
   that cannot be held and stretches a segment by more than its length, is refused;
2. the stiffness K = d(G - A u_offset)/dq there (by central differences), the mass matrix M and
   the damping D; the arm must be stable (K's generalized eigenvalues with M positive), else
   the spec is refused with what to change;
3. a displacement scale per coordinate: bending 0.3 rad (d * 0.3 in the delta form), stretch 5 %
   of the rest length, pendulum angles 0.3 rad, masses 1 (in the coordinates' units);
4. initial q uniform within one scale of the rest state, q̇ within half a scale times each
   coordinate's frequency sqrt(K_ii / M_ii);
5. multisine inputs (3 components, random phases) from 0.2 f1 to 2 f1, f1 the lowest natural
   frequency, each input's amplitude such that the linearised steady response
   |(K - w^2 M + i w D)^-1 A| to all components together stays within the scales at every
   frequency of the band;
6. output rate a round number >= 20 times the highest input frequency and >= 5 times the
   highest natural frequency (10 Hz .. 1 kHz), duration three periods of the slowest input
   (10 .. 60 s), a settle time of five time constants of the fastest decaying mode (at most
   1 s), 10 trajectories of which the last 2 test.
"""

from __future__ import annotations

import math

import numpy as np

from softpinn.symbolic.model._true_model import TrueModel
from softpinn.symbolic.simulation._datatable import DataError
from softpinn.symbolic.spec._model_spec import ModelSpec

BEND = 0.3  # rad
STRETCH = 0.05  # of the rest length
MAX_REST_STRETCH = 0.25  # of the rest length
COMPONENTS = 3
TRAJECTORIES, TEST = 10, 2


def coordinate_scales(spec: ModelSpec) -> np.ndarray:
    """A displacement scale per coordinate (item 3 of the module docstring)."""
    if spec.kind == "spatial-pcc":
        out = []
        for seg in spec.segments:
            bend = BEND * seg.actuator_radius if spec.parameterization == "delta" else BEND
            out += [bend, bend, STRETCH * seg.length]
        return np.array(out)
    if spec.kind == "planar-pcc":
        return np.array([v for seg in spec.segments for v in (BEND, STRETCH * seg.length)])
    if spec.kind == "double-pendulum":
        return np.full(2, BEND)
    return np.ones(spec.n)


def _jacobian(f, q, scale):
    cols = []
    for i in range(len(q)):
        h = 1e-6 * max(scale[i], abs(q[i]))
        e = np.zeros_like(q)
        e[i] = h
        cols.append((f(q + e) - f(q - e)) / (2 * h))
    return np.stack(cols, 1)


def _newton(f, q, scale, tol):
    r = f(q)
    for _ in range(100):
        if np.max(np.abs(r)) <= tol:
            return q, True
        J = _jacobian(f, q, scale)
        step = np.linalg.lstsq(J, -r, rcond=None)[0]
        a = 1.0
        while a > 1e-4:
            cand = q + a * step
            rc = f(cand)
            if np.all(np.isfinite(rc)) and np.linalg.norm(rc) < np.linalg.norm(r):
                q, r = cand, rc
                break
            a /= 2
        else:
            return q, False
    return q, bool(np.max(np.abs(r)) <= tol)


def _stretch_ok(spec: ModelSpec, q, limit: float) -> bool:
    if spec.kind not in ("spatial-pcc", "planar-pcc"):
        return True
    per = 3 if spec.kind == "spatial-pcc" else 2
    return all(abs(q[per * i + per - 1]) <= limit * seg.length
               for i, seg in enumerate(spec.segments))


def _nice_up(x: float) -> float:
    """The smallest of 1, 2, 5 times a power of ten that is >= x."""
    e = math.floor(math.log10(x))
    for c in (1, 2, 5, 10):
        if c * 10**e >= x * (1 - 1e-12):
            return float(c * 10**e)
    raise AssertionError(x)


def _sig(x, digits=4):
    return float(f"{float(x):.{digits}g}")


def physics_data_table(spec: ModelSpec, tm=None) -> tuple[dict, str]:
    """A ``[data]`` table for ``spec`` scaled to its physics, and a one-line summary."""
    src, name = spec.source, spec.name
    if spec.kind == "spatial-pcc" and spec.parameterization == "phi-theta":
        raise DataError(
            f"{src}: no [data] table, and its defaults start near the straight arm, where "
            "phi-theta is singular: use parameterization = \"delta\" or add a [data] table "
            "(docs/spec.md)"
        )
    if tm is None:
        tm = TrueModel(spec, compiled=False)
    n, m = spec.n, spec.m
    names = spec.coordinate_names
    scale = coordinate_scales(spec)
    q0 = np.zeros(n)
    G0 = np.atleast_1d(tm.G(q0))
    Kd = np.abs(np.diag(_jacobian(lambda q: np.atleast_1d(tm.G(q)), q0, scale)))
    tol = 1e-10 * max(1.0, float(np.max(np.abs(G0))), float(np.max(Kd * scale)))
    offset = np.zeros(m)
    q_eq, ok = _newton(lambda q: np.atleast_1d(tm.G(q)), q0, scale, tol)
    q_eq = np.where(np.abs(q_eq) < 1e-9 * scale, 0.0, q_eq)
    held = False
    if not (ok and _stretch_ok(spec, q_eq, MAX_REST_STRETCH)):
        A0 = tm.A(q0).reshape(n, m)
        if m:
            offset = np.linalg.lstsq(A0, G0, rcond=None)[0]
        if m and np.max(np.abs(A0 @ offset - G0)) <= 1e-8 * max(1.0, np.max(np.abs(G0))):
            q_eq, held = q0, True
        elif ok and _stretch_ok(spec, q_eq, 1.0):
            offset = np.zeros(m)
        else:
            where = (f"gravity moves it to {_fmt(q_eq, names)}" if ok
                     else "Newton's method found no equilibrium")
            raise DataError(
                f"{src}: no [data] table, and the arm has no usable rest state at zero input "
                f"({where}; its actuation cannot hold it straight): raise the stiffness or "
                "add a [data] table with q0_low/q0_high and input offsets (docs/spec.md)"
            )

    def force(q):
        return np.atleast_1d(tm.G(q)) - tm.A(q).reshape(n, m) @ offset

    K = _jacobian(force, q_eq, scale)
    K = 0.5 * (K + K.T)
    M = np.atleast_2d(tm.M(q_eq))
    D = np.atleast_2d(tm.D(q_eq))
    Minv = np.linalg.inv(M)
    w2, vecs = np.linalg.eig(Minv @ K)
    w2 = w2.real
    if np.min(w2) <= 1e-12 * np.max(np.abs(w2)):
        k = int(np.argmin(w2))
        v = np.abs(vecs[:, k].real)
        raise DataError(
            f"{src}: no [data] table, and the arm is not stable at its rest state "
            f"{_fmt(q_eq, names)}: it gives way along {names[int(np.argmax(v))]} (gravity "
            "overcomes the stiffness there): raise that stiffness, or add a [data] table "
            "(docs/spec.md)"
        )
    omega = np.sqrt(np.sort(w2))
    f1, fmax = omega[0] / (2 * np.pi), omega[-1] / (2 * np.pi)
    lam = np.linalg.eigvals(np.block([[np.zeros((n, n)), np.eye(n)], [-Minv @ K, -Minv @ D]]))
    fast = float(np.max(-lam.real))
    f_lo, f_hi = 0.2 * f1, 2.0 * f1
    rate = min(1000.0, max(10.0, _nice_up(max(20 * f_hi, 5 * fmax))))
    duration = float(min(60.0, max(10.0, math.ceil(3 / f_lo))))
    settle = min(1.0, 5.0 / fast) if fast > 0 else 0.0
    settle = math.ceil(settle * rate - 1e-9) / rate
    qd_scale = 0.5 * scale * np.sqrt(np.abs(np.diag(K)) / np.diag(M))
    table: dict = {
        "rate": _sig(rate),
        "duration": duration,
        "settle": _sig(settle),
        "train_trajectories": TRAJECTORIES - TEST,
        "test_trajectories": TEST,
        "q0_low": [_sig(v) for v in q_eq - scale],
        "q0_high": [_sig(v) for v in q_eq + scale],
        "qd0_low": [_sig(-v) for v in qd_scale],
        "qd0_high": [_sig(v) for v in qd_scale],
        "seed": 0,
    }
    if m:
        A = tm.A(q_eq).reshape(n, m)
        gain = np.zeros((n, m))
        for f in np.geomspace(f_lo, f_hi, 60):
            w = 2 * np.pi * f
            H = np.linalg.solve(K - w * w * M + 1j * w * D, A)
            gain = np.maximum(gain, np.abs(H))
        with np.errstate(divide="ignore"):
            amp = np.min(np.where(gain > 0, scale[:, None] / gain, np.inf), axis=0)
        amp = np.where(np.isfinite(amp), amp, 0.0) / COMPONENTS
        table.update({
            "signal": "multisine",
            "components": COMPONENTS,
            "amplitude_low": [_sig(0.3 * a) for a in amp],
            "amplitude_high": [_sig(a) for a in amp],
            "offset_low": [_sig(o) for o in offset],
            "offset_high": [_sig(o) for o in offset],
            "frequency_low": _sig(f_lo),
            "frequency_high": _sig(f_hi),
            "phase_low": 0.0,
            "phase_high": _sig(2 * np.pi),
        })
    else:
        table["signal"] = "zero"
    rest = f"rest state {_fmt(q_eq, names)}" + (
        f" held by the constant input {_fmt(offset, [f'u{j}' for j in range(m)])}" if held
        else ""
    )
    summary = (
        f"{name}: no [data] table: defaults from its physics: {rest}; lowest natural frequency "
        f"{f1:.3g} Hz (highest {fmax:.3g} Hz); {TRAJECTORIES} trajectories (last {TEST} for "
        f"test) of {duration:g} s at {rate:g} Hz after {table['settle']:g} s settling, "
        "starting within one displacement scale of rest"
        + (f", multisine inputs {f_lo:.3g}-{f_hi:.3g} Hz" if m else ", no input")
        + " (softpinn init NAME writes a spec whose [data] table you can edit)"
    )
    return table, summary


def _fmt(v, names) -> str:
    return "[" + ", ".join(f"{k} = {x:.4g}" for k, x in zip(names, v, strict=True)) + "]"
