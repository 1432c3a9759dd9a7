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
  over the nodes (:mod:`symbolic.model._functions`). ``Cqd`` uses the rigid-body form
  m Jv^T (d/dt(Jv) qd) + Jb^T (I_b d/dt(omega_b) + omega_b x I_b omega_b), which equals
  Mdot qd - dT/dq without differentiating M.
* :class:`LumpedTerms`: closed-form M(q) and V(q): the mass-spring-damper (eq. 25), the double
  pendulum (eq. 26) and the elastic energy of the PCC segments (eq. 23).
"""

from __future__ import annotations

from functools import cached_property

import casadi as ca
import numpy as np

from softpinn.errors import UserError
from softpinn.symbolic.derivation import _kinematics as kin
from softpinn.symbolic.spec._model_spec import ModelSpec

#: Gauss-Legendre order for the zeta integrals: M, G and C qd within 2e-11 relative of order 40
#: for |theta| <= 2 pi (order 9: 6e-10; ``tests/test_energies.py`` checks 1e-10).
DEFAULT_ORDER = 10
#: the highest order accepted: order 40 is already exact to double precision for |theta| <= 2 pi
MAX_ORDER = 100


def check_order(order) -> int:
    """``order`` as an int, or a :class:`UserError` naming the field."""
    if (isinstance(order, bool) or not isinstance(order, (int, np.integer))
            or not 1 <= order <= MAX_ORDER):
        raise UserError(
            f"order: expected an integer from 1 to {MAX_ORDER} (Gauss-Legendre nodes per "
            f"segment; default {DEFAULT_ORDER}), got {order!r}"
        )
    return int(order)


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
