"""Static equilibria of a model as extra labels (Section VI-B, "additional labels").

At rest under a constant input u*, eq. 4 with q̇ = q̈ = 0 reads

    G(q*) = A(q*) u*,

so a pair (q*, u*) tells a network how the potential force and the input force balance, and
f* = G(q*) = A(q*) u* is the generalized force there (the "measured force" label a force/torque
sensor at rest would give). :func:`equilibria` draws K constant inputs uniformly in a box
(:func:`input_box`: by default the box the spec's ``[data]`` input signals stay in), solves
G(q) - A(q) u = 0 by Newton's method from q = 0 (CasADi ``rootfinder`` 'newton', exact Jacobian)
and keeps an equilibrium only when

* the residual ‖G(q*) - A(q*) u*‖∞ is at most ``tol`` (1e-10 by default), and
* it is stable: the stiffness K = ∂(G - A u*)/∂q at q* has eigenvalues of positive real part and
  the linearised dynamics [[0, I], [-M⁻¹K, -M⁻¹D]] are Hurwitz (every eigenvalue's real part
  < 0), so the arm would actually come to rest there.

Inputs whose Newton iteration does not converge, or whose equilibrium is unstable, are skipped and
replaced by further draws (up to ``max_draws`` in all); what was skipped is counted in the
result's ``info``. Everything is seeded: draw k uses
``numpy.random.default_rng([seed, STREAM, k])`` (a stream of its own: trajectory k of a data set
with the same seed uses ``[seed, k]``, its noise ``[seed, 2**31 - 1]``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np

from softpinn.symbolic.model._functions import functions
from softpinn.symbolic.simulation._datatable import DataError, data_config
from softpinn.symbolic.simulation._signals import DEFAULT_RANGES, _range
from softpinn.symbolic.spec._model_spec import ModelSpec
from softpinn.symbolic.spec._spec import load_spec

#: How the equilibria were drawn and checked, recorded in a dataset's meta["equilibria"].
METHOD = ("constant inputs uniform in the input box; Newton (casadi rootfinder 'newton') on "
          "G(q) - A(q) u = 0 from q = 0; kept when the residual is <= tol and the stiffness "
          "dG/dq - d(A u)/dq has eigenvalues of positive real part with Hurwitz linearised "
          "dynamics")


#: the second entry of the equilibria's seed sequence (see the module docstring)
STREAM = 2**31 - 2


@dataclass
class Equilibria:
    """K equilibria: ``q`` (K, n), ``u`` (K, m), ``force`` (K, n) = G(q*) = A(q*) u*, the
    largest residual ‖G - A u‖∞ per point (``residual``, (K,)), the smallest real part of the
    stiffness eigenvalues (``stiffness_min``, (K,)) and ``info`` (the box, draws, skips)."""

    q: np.ndarray
    u: np.ndarray
    force: np.ndarray
    residual: np.ndarray
    stiffness_min: np.ndarray
    info: dict[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.q.shape[0])


def input_box(spec: ModelSpec, data: Mapping[str, Any] | None = None
              ) -> tuple[np.ndarray, np.ndarray]:
    """The box of constant inputs (low, high), each (m,), that the spec's input signals stay in:
    offset range widened by the largest amplitude (times the number of components for a
    multisine); the zero signal gives the box [0, 0]."""
    cfg = data_config(spec, data)
    m = spec.m
    if cfg.signal == "zero" or m == 0:
        return np.zeros(m), np.zeros(m)
    off_lo, off_hi = _range(cfg.ranges, "offset", m, DEFAULT_RANGES["offset"])
    _, amp_hi = _range(cfg.ranges, "amplitude", m, DEFAULT_RANGES["amplitude"])
    reach = amp_hi * (cfg.components if cfg.signal == "multisine" else 1)
    return off_lo - reach, off_hi + reach


class _Solver:
    """The Newton rootfinder of G(q) - A(q) u = 0 in q (u a parameter) and the checks."""

    def __init__(self, spec: ModelSpec, fns: Mapping[str, ca.Function] | None = None):
        if fns is None:
            fns = functions(spec)
        self.n, self.m = spec.n, spec.m
        q = ca.MX.sym("q", self.n)
        u = ca.MX.sym("u", self.m)
        G = fns["G"](q)
        r = G - ca.mtimes(fns["A"](q), u) if self.m else G
        self.residual = ca.Function("eq_residual", [q, u], [r, G])
        self.stiffness = ca.Function("eq_stiffness", [q, u], [ca.jacobian(r, q)])
        self.M, self.D = fns["M"], fns["D"]
        g = ca.Function("g", [q, u], [r])
        self.newton = ca.rootfinder("eq_newton", "newton", g,
                                    {"abstol": 1e-13, "max_iter": 100, "error_on_fail": False})

    def solve(self, u: np.ndarray, q0: np.ndarray) -> tuple[np.ndarray, bool]:
        sol = self.newton(ca.DM(q0), ca.DM(u))
        return np.asarray(sol, dtype=float).reshape(-1), bool(self.newton.stats()["success"])

    def check(self, q: np.ndarray, u: np.ndarray):
        r, G = self.residual(q, u)
        K = np.asarray(self.stiffness(q, u), dtype=float)
        M = np.asarray(self.M(q), dtype=float)
        D = np.asarray(self.D(q), dtype=float)
        n = self.n
        jac = np.block([[np.zeros((n, n)), np.eye(n)],
                        [-np.linalg.solve(M, K), -np.linalg.solve(M, D)]])
        k_min = float(np.min(np.linalg.eigvals(K).real))
        hurwitz = float(np.max(np.linalg.eigvals(jac).real))
        return (float(np.max(np.abs(np.asarray(r, dtype=float)))),
                np.asarray(G, dtype=float).reshape(-1), k_min, hurwitz)


def equilibria(model: str | Path | ModelSpec, count: int, *, seed: int = 0,
               low: Sequence[float] | None = None, high: Sequence[float] | None = None,
               q0: Sequence[float] | None = None, tol: float = 1e-10,
               max_draws: int | None = None, data: Mapping[str, Any] | None = None,
               fns: Mapping[str, ca.Function] | None = None) -> Equilibria:
    """``count`` stable static equilibria of a model under constant inputs drawn uniformly in
    [``low``, ``high``] (default :func:`input_box` of the ``data`` table, else the spec's
    ``[data]``), found by Newton's method from ``q0``
    (default q = 0). Raises :class:`DataError` when fewer than ``count`` are found in
    ``max_draws`` draws (default 4 * count + 10), saying how many were skipped and why."""
    spec = model if isinstance(model, ModelSpec) else load_spec(model)
    if isinstance(count, bool) or not isinstance(count, int) or count < 0:
        raise DataError(f"equilibria: expected a count >= 0, got {count!r}")
    n, m = spec.n, spec.m
    if low is None or high is None:
        box_lo, box_hi = input_box(spec, data)
        low = box_lo if low is None else low
        high = box_hi if high is None else high
    lo = np.asarray(low, dtype=float).reshape(-1)
    hi = np.asarray(high, dtype=float).reshape(-1)
    if lo.shape != (m,) or hi.shape != (m,) or np.any(hi < lo) or not (
            np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        raise DataError(f"equilibria: the input box must be two finite vectors of {m} entries "
                        f"with low <= high, got {lo.tolist()} and {hi.tolist()}")
    start = np.zeros(n) if q0 is None else np.asarray(q0, dtype=float).reshape(n)
    draws = 4 * count + 10 if max_draws is None else int(max_draws)
    solver = _Solver(spec, fns) if count else None
    qs, us, fs, res, kmin = [], [], [], [], []
    skipped = {"not_converged": 0, "residual": 0, "unstable": 0}
    k = -1
    for k in range(draws):
        if len(qs) == count:
            k -= 1
            break
        u = lo + (hi - lo) * np.random.default_rng([seed, STREAM, k]).uniform(size=m)
        q, ok = solver.solve(u, start)
        if not (ok and np.all(np.isfinite(q))):
            skipped["not_converged"] += 1
            continue
        r, G, k_min, hurwitz = solver.check(q, u)
        if not r <= tol:
            skipped["residual"] += 1
            continue
        if not (k_min > 0 and hurwitz < 0):
            skipped["unstable"] += 1
            continue
        qs.append(q)
        us.append(u)
        fs.append(G)
        res.append(r)
        kmin.append(k_min)
    if len(qs) < count:
        raise DataError(
            f"equilibria: found {len(qs)} of {count} stable equilibria in {draws} draws "
            f"(skipped: {skipped['not_converged']} did not converge, {skipped['residual']} "
            f"left a residual above {tol:g}, {skipped['unstable']} unstable); narrow the input "
            "box or start Newton elsewhere")
    info = {"count": count, "seed": seed, "input_low": lo.tolist(), "input_high": hi.tolist(),
            "q0": start.tolist(), "tol": tol, "draws": k + 1, "skipped": skipped,
            "max_residual": float(max(res)) if res else 0.0,
            "min_stiffness_eigenvalue": float(min(kmin)) if kmin else None,
            "seeding": f"draw k: numpy.random.default_rng([seed, {STREAM}, k]).uniform(size=m)",
            "method": METHOD}
    shape = lambda rows, w: np.asarray(rows, dtype=float).reshape(len(rows), w)
    return Equilibria(q=shape(qs, n), u=shape(us, m), force=shape(fs, n),
                      residual=np.asarray(res, dtype=float), stiffness_min=np.asarray(kmin),
                      info=info)


def attach(data, eq: Equilibria):
    """``data`` (a :class:`~symbolic.simulation._datafile.DatasetArrays`) with the equilibria as its
    optional arrays ``eq_q``, ``eq_u``, ``eq_force`` and ``meta["equilibria"]``."""
    meta = dict(data.meta, equilibria=eq.info)
    return dataclasses.replace(data, meta=meta, eq_q=eq.q, eq_u=eq.u, eq_force=eq.force)
