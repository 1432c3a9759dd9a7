"""The planar thin-rod PCC model (eqs. 27-28, task 3) against a SymPy closed-form derivation.

SymPy integrates the energies over zeta exactly; its Piecewise theta = 0 branch is wrong for
this model (docs/pitfalls.md), so the comparison is at theta != 0, evaluated in 50-digit arithmetic
to keep the closed forms free of cancellation."""

from __future__ import annotations

import mpmath
import numpy as np
import pytest
import sympy as sp

from softpinn.symbolic import TrueModel


@pytest.fixture(scope="module")
def closed_form():
    theta, dL, z = sp.symbols("theta dL zeta", real=True)
    thd, dLd = sp.symbols("thetadot dLdot", real=True)
    L0, m, g, k1, k2 = 1, 1, sp.Rational(981, 100), 10, 10
    q, qd = sp.Matrix([theta, dL]), sp.Matrix([thd, dLd])
    psi = sp.Matrix([(L0 + dL) * (1 - sp.cos(z * theta)) / theta,
                     (L0 + dL) * sp.sin(z * theta) / theta])  # eq. 27
    J = psi.jacobian(q)

    def integral(expr):
        out = sp.integrate(sp.expand(expr), (z, 0, 1), conds="none")
        return sp.piecewise_fold(out).args[0][0] if isinstance(out, sp.Piecewise) else out

    M = sp.Matrix(2, 2, lambda i, j: m * integral((J[:, i].T @ J[:, j])[0]))
    V = -g * m * integral(psi[1]) + k1 * theta**2 / 2 + k2 * dL**2 / 2  # eq. 28
    G = sp.Matrix([V]).jacobian(q).T
    T = (qd.T @ M @ qd)[0] / 2
    Mdot = sp.Matrix(2, 2, lambda i, j: (sp.Matrix([M[i, j]]).jacobian(q) @ qd)[0])
    Cqd = Mdot @ qd - sp.Matrix([T]).jacobian(q).T
    return sp.lambdify((theta, dL, thd, dLd), [M, G, Cqd], modules="mpmath")


@pytest.mark.parametrize("q", [[0.3, 0.3], [1.5, 1.0], [-2.0, -0.2], [0.05, 0.1], [4.0, 0.4]])
def test_planar_equals_sympy(closed_form, q):
    tm = TrueModel("task3")
    qd = np.array([0.7, -0.4])
    with mpmath.workdps(50):
        M, G, Cqd = (np.array(x.tolist(), dtype=float) for x in
                     closed_form(mpmath.mpf(q[0]), mpmath.mpf(q[1]), mpmath.mpf(qd[0]),
                                 mpmath.mpf(qd[1])))
    q = np.array(q)
    np.testing.assert_allclose(tm.M(q), M, rtol=0, atol=1e-10 * np.abs(M).max())
    np.testing.assert_allclose(tm.G(q), G.ravel(), rtol=0, atol=1e-10 * np.abs(G).max())
    np.testing.assert_allclose(tm.Cqd(q, qd), Cqd.ravel(), rtol=0,
                               atol=1e-10 * np.abs(Cqd).max())
    u = np.array([0.8])
    qdd = np.linalg.solve(M, np.array([1.0, 0.0]) * u[0] - Cqd.ravel() - G.ravel() - 0.4 * qd)
    np.testing.assert_allclose(tm.qdd(q, qd, u), qdd, rtol=1e-10, atol=1e-10)
