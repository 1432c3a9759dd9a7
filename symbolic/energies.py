"""Kinetic and potential energies and the terms derived from them (eqs. 18-28).

Two kinds of energy source share one interface, :class:`Terms`, whose attributes are CasADi SX
expressions in the symbols ``q``, ``qd`` (computed lazily, only when asked for):

``M``      mass matrix (n x n)               ``V``     potential energy
``G``      dV/dq                             ``T``     kinetic energy 1/2 qd^T M qd
``Cqd``    Mdot qd - dT/dq                   ``dTdq``  dT/dq at fixed qd
``C``      Coriolis matrix from the Christoffel symbols of ``M`` (C qd = Cqd, Mdot - 2C skew)

* :class:`PlateTerms`: one thin plate at fraction ``zeta`` of a PCC segment (eqs. 18-22), or one
  point of a planar thin rod (eqs. 27-28). The segment's energies are the integrals over zeta in
  [0, 1], done by Gauss-Legendre quadrature (:func:`gauss_legendre`) by whoever maps these terms
  over the nodes (:mod:`symbolic.functions`). ``Cqd`` uses the rigid-body form
  m Jv^T (d/dt(Jv) qd) + Jb^T (I_b d/dt(omega_b) + omega_b x I_b omega_b), which equals
  Mdot qd - dT/dq without differentiating M.
* :class:`LumpedTerms`: closed-form M(q) and V(q): the mass-spring-damper (eq. 25), the double
  pendulum (eq. 26) and the elastic energy of the PCC segments (eq. 23).
"""

from __future__ import annotations

from functools import cached_property

import casadi as ca
import numpy as np

from . import kinematics as kin
from .smooth import Jet
from .spec import ModelSpec

#: Gauss-Legendre order for the zeta integrals; 1e-13 relative against order 40 for
#: |theta| <= 2 pi (``tests/test_energies.py``).
DEFAULT_ORDER = 10


def gauss_legendre(order: int) -> tuple[np.ndarray, np.ndarray]:
    """Nodes and weights of the ``order``-point Gauss-Legendre rule on [0, 1]."""
    x, w = np.polynomial.legendre.leggauss(order)
    return 0.5 * (x + 1.0), 0.5 * w


def christoffel_C(M, q, qd):
    """C(q, qd) with C_kj = sum_i Gamma_ijk qd_i = 1/2 (Mdot + d(M qd)/dq - d(M qd)/dq^T)."""
    J = ca.jacobian(M @ qd, q)
    return 0.5 * (ca.jtimes(M, q, qd) + J - J.T)


class Terms:
    """Energy terms in ``q`` and ``qd``; subclasses give ``M`` and ``V`` at least."""

    def __init__(self, q, qd):
        self.q, self.qd = q, qd

    @cached_property
    def G(self):
        return ca.gradient(self.V, self.q)

    @cached_property
    def T(self):
        return 0.5 * ca.dot(self.qd, self.M @ self.qd)

    @cached_property
    def dTdq(self):
        return ca.gradient(self.T, self.q)

    @cached_property
    def Cqd(self):
        return ca.jtimes(self.M @ self.qd, self.q, self.qd) - self.dTdq

    @cached_property
    def C(self):
        return christoffel_C(self.M, self.q, self.qd)


class LumpedTerms(Terms):
    """Closed-form energies: eq. 25, eq. 26, or the PCC elastic energy eq. 23 (M = 0)."""

    def __init__(self, spec: ModelSpec, q, qd):
        super().__init__(q, qd)
        self.spec = spec

    @cached_property
    def M(self):
        s, q = self.spec, self.q
        if s.kind == "mass-spring-damper":
            return ca.SX(ca.diag(ca.DM(s.masses)))
        if s.kind == "double-pendulum":
            (m1, m2), (l1, l2) = s.masses, s.lengths
            c = m2 * l1 * l2 * ca.cos(q[0] - q[1])
            return ca.vertcat(ca.horzcat((m1 + m2) * l1**2, c), ca.horzcat(c, m2 * l2**2))
        return ca.SX(s.n, s.n)

    @cached_property
    def V(self):
        s, q = self.spec, self.q
        if s.kind == "mass-spring-damper":
            k = s.springs
            V = 0.5 * k[-1] * q[-1] ** 2
            for i in range(s.n - 1):
                V += 0.5 * k[i] * (q[i] - q[i + 1]) ** 2
            return V
        if s.kind == "double-pendulum":
            (m1, m2), (l1, l2) = s.masses, s.lengths
            return -(m1 + m2) * s.g * l1 * ca.cos(q[0]) - m2 * s.g * l2 * ca.cos(q[1])
        K = np.concatenate([seg.stiffness for seg in s.segments])
        return 0.5 * ca.dot(q, ca.DM(K) * q)

    @cached_property
    def T(self):
        if self.spec.kind in ("spatial-pcc", "planar-pcc"):
            return ca.SX(0)
        return super().T

    @cached_property
    def Cqd(self):
        if self.spec.kind in ("mass-spring-damper", "spatial-pcc", "planar-pcc"):
            return ca.SX(self.spec.n, 1)
        return super().Cqd


class PlateTerms(Terms):
    """Energy densities of the plate at ``zeta`` of segment ``i`` (eqs. 18-22, 27-28), times m_i.

    Integrating them over zeta in [0, 1] gives the segment's M, V, G, ... .
    """

    def __init__(self, spec: ModelSpec, i: int, q, qd, zeta):
        super().__init__(q, qd)
        self.spec, self.i = spec, i
        self.mass = spec.segments[i].mass
        self.radius = spec.segments[i].radius if spec.kind == "spatial-pcc" else 0.0
        if spec.kind == "spatial-pcc":
            self.R, self.p = kin.spatial_plate(spec, q, i, zeta)
        else:
            self.R, self.p = None, kin.planar_plate(spec, q, i, zeta)
        self.g = ca.DM(spec.gravity)

    @property
    def rotational(self) -> bool:
        return self.radius > 0

    @cached_property
    def inertia(self):
        """Plate inertia per unit mass in its own frame: r^2 / 4 diag(1, 1, 2) (eq. 18)."""
        return ca.DM(np.diag([1.0, 1.0, 2.0]) * self.radius**2 / 4)

    @cached_property
    def Jv(self):
        return ca.jacobian(self.p, self.q)

    @cached_property
    def v(self):
        return ca.jtimes(self.p, self.q, self.qd)

    @cached_property
    def wb(self):
        return kin.body_angular_velocity(self.R, self.q, self.qd)

    @cached_property
    def Jb(self):
        """Body angular Jacobian R^T Jw (so Jw^T R I_b R^T Jw = Jb^T I_b Jb, eq. 20)."""
        return ca.jacobian(self.wb, self.qd)

    @cached_property
    def M(self):
        M = self.Jv.T @ self.Jv
        if self.rotational:
            M = M + self.Jb.T @ self.inertia @ self.Jb
        return self.mass * M

    @cached_property
    def V(self):
        return -self.mass * ca.dot(self.p, self.g)

    @cached_property
    def G(self):
        return -self.mass * (self.Jv.T @ self.g)

    @cached_property
    def T(self):
        T = ca.dot(self.v, self.v)
        if self.rotational:
            T = T + ca.dot(self.wb, self.inertia @ self.wb)
        return 0.5 * self.mass * T

    @cached_property
    def Cqd(self):
        acc = ca.jtimes(self.v, self.q, self.qd)  # d/dt(Jv) qd
        out = self.Jv.T @ acc
        if self.rotational:
            wb, I = self.wb, self.inertia
            wbd = ca.jtimes(wb, self.q, self.qd)
            out = out + self.Jb.T @ (I @ wbd + ca.cross(wb, I @ wb))
        return self.mass * out


class HoistedPlate:
    """The plate densities of spatial segment ``i`` with the motion of the segment's base frame
    hoisted out of the zeta integral.

    The plate at zeta sits at p = t_b + R_b p_l(zeta) with orientation R_b R_l(zeta), where
    (R_b, t_b) is the base pose of segment i (a function of q_1..q_{i-1}, eq. 14) and
    (R_l, p_l) the local plate pose (a function of q_i, eq. 13). Then

    * Jv = [dt_b/dq_< + dR_b/dq_< p_l,  R_b dp_l/dq_i],  v = t_b' + R_b' p_l + R_b p_l',
    * d/dt(Jv) qd = t_b'' + R_b'' p_l + 2 R_b' p_l' + R_b p_l''  (primes: derivatives along qd
      with qdd = 0), and d/dt(Jv) likewise,
    * M = m Jv^T Jv, G = -m Jv^T g, C qd = m Jv^T d/dt(Jv) qd, C = m Jv^T d/dt(Jv) (the
      Christoffel form for a point mass), dT/dq = m d/dt(Jv)^T v,

    plus the rotational terms of the plate inertia (eq. 18) with the body angular velocity
    omega = R_l^T omega_b + omega_l. The base quantities are computed once per evaluation
    (recursively, :func:`symbolic.kinematics.base_step_function`);
    :meth:`density_function` is the per-node density, whose size barely grows
    with i. The results equal those of :class:`PlateTerms` (tested).
    """

    BASE = kin.BASE_FIELDS

    def __init__(self, spec: ModelSpec, i: int):
        self.spec, self.i = spec, i
        seg = spec.segments[i]
        self.mass, self.radius = seg.mass, seg.radius
        self.k = 3 * i  # coordinates of the segments before this one
        self.g = ca.DM(spec.gravity)

    def supports(self, keys) -> bool:
        """Keys with a hoisted density."""
        return set(keys) <= {"M", "G", "Cqd", "V", "T", "C", "dTdq"}

    def density_function(self, keys: tuple[str, ...], name: str) -> ca.Function:
        """(q_i, qd_i, zeta, w, base...) -> w times the densities ``keys``, as blocks over the
        first 3 (i + 1) coordinates."""
        assert self.supports(keys), keys
        seg = self.spec.segments[self.i]
        k = self.k
        ql, qdl = ca.SX.sym("qi", 3), ca.SX.sym("qdi", 3)
        zeta, w = ca.SX.sym("zeta"), ca.SX.sym("w")
        jet = Jet()
        Rl, pl = kin.segment_pose(ql, seg.length, seg.actuator_radius,
                                  self.spec.parameterization, zeta, jet)
        base = {b: ca.SX.sym(b, *shape) for b, shape in kin.base_shapes(k).items()}
        x = _Lazy()
        x.Jl = lambda: jet.jacobian(pl, ql)
        x.pld = lambda: jet.jtimes(pl, ql, qdl)  # cheaper than Jl @ qdl once differentiated
        x.pldd = lambda: jet.jtimes(x.pld, ql, qdl)
        x.Jld = lambda: jet.jtimes(x.Jl, ql, qdl)

        if k:
            Rb = base["Rb"]
            x.Jv = lambda: ca.horzcat(base["dtb"] + kin.mix(base["dRb"], pl), Rb @ x.Jl)
            x.p = lambda: base["tb"] + Rb @ pl
            x.v = lambda: base["tbd"] + base["Rbd"] @ pl + Rb @ x.pld
            x.acc = lambda: (base["tbdd"] + base["Rbdd"] @ pl + 2 * base["Rbd"] @ x.pld
                             + Rb @ x.pldd)
            x.Jvd = lambda: ca.horzcat(
                base["dtbd"] + kin.mix(base["dRbd"], pl) + kin.mix(base["dRb"], x.pld),
                base["Rbd"] @ x.Jl + Rb @ x.Jld)
        else:
            x.Jv, x.p, x.v, x.acc, x.Jvd = (lambda: x.Jl), (lambda: pl), (lambda: x.pld), \
                (lambda: x.pldd), (lambda: x.Jld)
        m = self.mass
        out = {
            "M": lambda: m * (x.Jv.T @ x.Jv),
            "G": lambda: -m * (x.Jv.T @ self.g),
            "V": lambda: -m * ca.dot(x.p, self.g),
            "T": lambda: 0.5 * m * ca.dot(x.v, x.v),
            "Cqd": lambda: m * (x.Jv.T @ x.acc),
            "C": lambda: m * (x.Jv.T @ x.Jvd),
            "dTdq": lambda: m * (x.Jvd.T @ x.v),
        }
        results = {key: out[key]() for key in keys}
        if self.radius > 0:
            # body angular velocity omega = Jb qd of the plate; with Jbd = d/dt(Jb):
            # d omega/dq = Jbd + [omega]x Jb (from d_k Jb_j - d_j Jb_k = Jb_j x Jb_k), so
            # dT/dq = m (Jbd + [omega]x Jb)^T I omega and the Christoffel matrix is
            # C = m (Jb^T I Jbd + 1/2 Jb^T (I [omega]x + [omega]x I - [I omega]x) Jb).
            I = ca.DM(np.diag([1.0, 1.0, 2.0]) * self.radius**2 / 4)
            Rld = jet.jtimes(Rl, ql, qdl)
            wl = kin.vee(Rl.T @ Rld)
            Jwl = ca.jacobian(wl, qdl)  # linear in qdl: no chain rule through s
            wld = jet.jtimes(wl, ql, qdl)
            if k:
                Jb = ca.horzcat(Rl.T @ base["Jwb"], Jwl)
                omega = Rl.T @ base["wb"] + wl
                omegad = Rld.T @ base["wb"] + Rl.T @ base["wbd"] + wld
                Jbd = ca.horzcat(Rld.T @ base["Jwb"] + Rl.T @ base["Jwbd"],
                                 jet.jtimes(Jwl, ql, qdl))
            else:
                Jb, omega, omegad = Jwl, wl, wld
                Jbd = jet.jtimes(Jwl, ql, qdl)
            Iw = I @ omega
            if "C" in keys:
                W = ca.skew(omega)
                sym = I @ W + W @ I - ca.skew(Iw)
                results["C"] = results["C"] + m * (Jb.T @ I @ Jbd + 0.5 * Jb.T @ sym @ Jb)
            if "dTdq" in keys:
                results["dTdq"] = results["dTdq"] + m * ((Jbd + ca.skew(omega) @ Jb).T @ Iw)
            if "M" in keys:
                results["M"] = results["M"] + m * (Jb.T @ I @ Jb)
            if "Cqd" in keys:
                results["Cqd"] = results["Cqd"] + m * (
                    Jb.T @ (I @ omegad + ca.cross(omega, I @ omega)))
            if "T" in keys:
                results["T"] = results["T"] + 0.5 * m * ca.dot(omega, I @ omega)
        ins = [ql, qdl, zeta, w] + ([base[b] for b in self.BASE] if k else [])
        names = ["qi", "qdi", "zeta", "w"] + (list(self.BASE) if k else [])
        outs = jet.finalize([w * results[key] for key in keys])
        return ca.Function(name, ins, outs, names, list(keys), {"cse": True})


class _Lazy:
    """Attributes given as zero-argument callables, evaluated once on first access."""

    def __setattr__(self, name, fn):
        object.__setattr__(self, "_" + name, fn)

    def __getattr__(self, name):
        fn = object.__getattribute__(self, "_" + name)
        value = fn()
        object.__setattr__(self, name, value)
        return value
