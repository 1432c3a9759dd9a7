"""Equations of motion M qdd + C qd + G + D qd = A u (eq. 4): the symbolic model of a spec.

:func:`derive` turns a :class:`~symbolic.spec._model_spec.ModelSpec` into a :class:`SymbolicModel`:
a list of energy *parts* (lumped closed forms, or a plate density to integrate over zeta by
Gauss-Legendre quadrature, one per PCC segment), the constant damping matrix D and the input matrix
A(q). It does no file I/O and builds no numeric code; :mod:`symbolic.model._functions` wraps the
parts into CasADi Functions (mapping each plate density over the quadrature nodes).
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from softpinn.symbolic.derivation import _kinematics as kin
from softpinn.symbolic.derivation._energies import (
    DEFAULT_ORDER,
    LumpedTerms,
    PlateTerms,
    Terms,
    check_order,
    gauss_legendre,
)
from softpinn.symbolic.derivation._hoisted import HoistedPlate, SegmentMoments
from softpinn.symbolic.spec._model_spec import ModelSpec


@dataclass
class Part:
    """One source of energy: ``terms`` in the model's symbols; ``nodes``/``weights`` are the
    quadrature rule in zeta for a plate density (None for a closed form); ``hoisted``, for a
    spatial segment, the faster densities of M, G and C qd."""

    name: str
    terms: Terms
    nodes: np.ndarray | None = None
    weights: np.ndarray | None = None
    hoisted: HoistedPlate | None = None
    moments: SegmentMoments | None = None


class SymbolicModel:
    """SX symbols ``q``, ``qd``, ``zeta``; energy ``parts``; ``D`` (DM) and ``A`` (SX in q)."""

    def __init__(self, spec: ModelSpec, order: int = DEFAULT_ORDER, hoist: bool = True):
        self.spec = spec
        self.hoist = hoist
        self.n, self.m = spec.n, spec.m
        self.order = check_order(order)
        self.q = ca.SX.sym("q", self.n)
        self.qd = ca.SX.sym("qd", self.n)
        self.zeta = ca.SX.sym("zeta")
        self.parts = self._parts()

    def _parts(self) -> list[Part]:
        s = self.spec
        parts = [Part("lumped", LumpedTerms(s, self.q, self.qd))]
        if s.kind in ("spatial-pcc", "planar-pcc"):
            nodes, weights = gauss_legendre(self.order)
            for i in range(len(s.segments)):
                terms = PlateTerms(s, i, self.q, self.qd, self.zeta)
                fast = s.kind == "spatial-pcc" and self.hoist
                parts.append(Part(f"seg{i + 1}", terms, nodes, weights,
                                  HoistedPlate(s, i) if fast else None,
                                  SegmentMoments(s, i) if fast else None))
        return parts

    # ---------------------------------------------------------------- damping and actuation

    @property
    def D(self) -> ca.DM:
        """Constant damping matrix (eq. 4; eq. 25 for the mass-spring-damper chain)."""
        s = self.spec
        if s.kind in ("spatial-pcc", "planar-pcc"):
            return ca.DM(np.diag(np.concatenate([seg.damping for seg in s.segments])))
        if s.kind == "double-pendulum":
            return ca.DM(np.diag(s.joint_damping))
        D = np.zeros((s.n, s.n))
        b = s.dampers
        for i in range(s.n - 1):
            e = np.zeros(s.n)
            e[i], e[i + 1] = 1.0, -1.0
            D += b[i] * np.outer(e, e)
        D[-1, -1] += b[-1]
        return ca.DM(D)

    @property
    def A(self) -> ca.SX:
        """Input matrix A(q) (n x m) for the spec's actuation."""
        s, q = self.spec, self.q
        a = s.actuation
        if not isinstance(a, str):
            return ca.SX(ca.DM(np.array(a, dtype=float)))
        if a == "none":
            return ca.SX(s.n, 0)
        if a == "generalized":
            return ca.SX.eye(s.n)
        if a == "tendon":
            return -ca.jacobian(kin.tendon_lengths(s, q), q).T
        assert a == "tip-wrench", a
        return ca.horzcat(*(tip_wrench_matrix(s, q, self.qd, i) for i in range(len(s.segments))))


def tip_wrench_matrix(spec: ModelSpec, q, qd, i: int):
    """A_i = [-Jw_i^T R_i e_x, -Jw_i^T R_i e_y, Jv_i^T R_i e_z] at the tip of segment ``i``
    (before the Rz(pi / a_dof) turn): torques about the tip frame's x and y axes, force along
    its tangent. Jw^T R = Jb^T with the body Jacobian Jb = R^T Jw."""
    R, p = kin.spatial_tip(spec, q, i)
    Jv = ca.jacobian(p, q)
    Jb = ca.jacobian(kin.body_angular_velocity(R, q, qd), qd)
    Jvb = R.T @ Jv
    return ca.horzcat(-Jb[0, :].T, -Jb[1, :].T, Jvb[2, :].T)


# ------------------------------------------------------------------- the equations themselves
# Shared by every model (and every CasADi type: SX, MX): the terms come from the energy parts,
# ``solve(M, b)`` is a symmetric positive definite solve (symbolic.linalg).


def forward_dynamics(M, Cqd, G, D, qd, A, u, solve):
    """Eq. 4 solved for the accelerations: qdd = M^-1 (A u - C qd - G - D qd)."""
    rhs = -Cqd - G - D @ qd
    if A is not None:
        rhs = rhs + A @ u
    return solve(M, rhs)


def inverse_dynamics(M, qdd, Cqd, G, D, qd):
    """Eq. 4's left side: the generalised force A u = M qdd + C qd + G + D qd."""
    return M @ qdd + Cqd + G + D @ qd


def hamiltonian_field(M, p, G, D, A, u, solve, dTdq):
    """Eq. 7: qdot = dH/dp = M^-1 p, pdot = -dH/dq - D qdot + A u, where -dH/dq = dT/dq - G at
    fixed qdot (``dTdq(qdot)`` gives the kinetic term's partial derivative in q)."""
    qdot = solve(M, p)
    pdot = dTdq(qdot) - G - D @ qdot
    if A is not None:
        pdot = pdot + A @ u
    return qdot, pdot


def derive(spec: ModelSpec, order: int = DEFAULT_ORDER, hoist: bool = True) -> SymbolicModel:
    """The symbolic model of ``spec`` (quadrature ``order`` for the zeta integrals; ``hoist``: use
    :class:`~symbolic.derivation._hoisted.HoistedPlate` for M, G and C qd of spatial segments)."""
    return SymbolicModel(spec, order, hoist)
