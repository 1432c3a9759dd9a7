"""Plate energies (eqs. 18-24): quadrature order, the hoisted densities against the direct
ones, M and G against finite differences of an independent numpy implementation, structure
for 1-4 segments in both parameterizations, and smoothness of ``delta`` at zero curvature."""

from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest

from softpinn.symbolic import TrueModel
from softpinn.symbolic.derivation._eom import derive
from softpinn.symbolic.model._functions import _Builder, functions
from softpinn.symbolic.spec._spec import spec_from_dict


def make_spec(nseg, param="delta", radius=0.03, d=0.5, actuation="tip-wrench"):
    segs = [dict(length=0.2 + 0.02 * i, mass=0.3 - 0.05 * i, radius=radius, actuator_radius=d,
                 stiffness=[1.0, 1.5, 20.0], damping=[0.1, 0.1, 0.2]) for i in range(nseg)]
    return spec_from_dict(dict(name=f"arm{nseg}_{param.replace('-', '_')}", kind="spatial-pcc",
                               parameterization=param, gravity=[0.5, -1.0, -9.81],
                               actuation=actuation, segment=segs))


def random_q(spec, rng, low=0.2, high=2.0):
    """Random coordinates with |theta| in [low, high] for every segment."""
    q = []
    for seg in spec.segments:
        phi, theta = rng.uniform(-np.pi, np.pi), rng.uniform(low, high)
        dL = rng.uniform(-0.05, 0.05)
        if spec.parameterization == "delta":
            d = seg.actuator_radius
            q += [d * theta * math.cos(phi), d * theta * math.sin(phi), dL]
        else:
            q += [phi, theta, dL]
    return np.array(q)


# ------------------------------------------------------------------ independent reference


def _eq13(phi, theta, L, zeta):
    c, s = math.cos(phi), math.sin(phi)
    ct, st = math.cos(zeta * theta), math.sin(zeta * theta)
    lam = L / theta
    R = np.array([[c * c * (ct - 1) + 1, s * c * (ct - 1), st * c],
                  [s * c * (ct - 1), s * s * (ct - 1) + 1, st * s],
                  [-st * c, -st * s, ct]])
    return R, np.array([lam * c * (1 - ct), lam * s * (1 - ct), lam * st])


def _plates(spec, q, nodes):
    """World poses of the plates of every segment at the given zeta nodes (numpy, eqs. 13-14)."""
    a = math.pi / spec.actuators_per_segment
    turn = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
    Rb, tb = np.eye(3), np.zeros(3)
    out = []
    for i, seg in enumerate(spec.segments):
        x, y, dL = q[3 * i : 3 * i + 3]
        if spec.parameterization == "delta":
            phi, theta = math.atan2(y, x), math.hypot(x, y) / seg.actuator_radius
        else:
            phi, theta = x, y
        L = seg.length + dL
        out.append([(Rb @ R, tb + Rb @ p) for R, p in (_eq13(phi, theta, L, z) for z in nodes)])
        R1, p1 = _eq13(phi, theta, L, 1.0)
        Rb, tb = Rb @ R1 @ turn, tb + Rb @ p1
    return out


def reference_M_G(spec, q, h=1e-6, order=40):
    """M = sum m int (Jv^T Jv + Jb^T I Jb) and G = dV/dq, with Jacobians and G by central
    differences of positions, rotations and V; quadrature by numpy's Gauss-Legendre rule."""
    x, w = np.polynomial.legendre.leggauss(order)
    nodes, weights = (x + 1) / 2, w / 2
    n = len(q)
    g = np.array(spec.gravity)

    def V(qq):
        v = 0.5 * qq @ (np.concatenate([s.stiffness for s in spec.segments]) * qq)
        for seg, plates in zip(spec.segments, _plates(spec, qq, nodes), strict=True):
            v -= seg.mass * sum(wk * (p @ g) for wk, (_, p) in zip(weights, plates, strict=True))
        return v

    base = _plates(spec, q, nodes)
    plus, minus = [], []
    for j in range(n):
        e = np.zeros(n)
        e[j] = h
        plus.append(_plates(spec, q + e, nodes))
        minus.append(_plates(spec, q - e, nodes))
    M = np.zeros((n, n))
    for i, seg in enumerate(spec.segments):
        I = seg.radius**2 / 4 * np.diag([1.0, 1.0, 2.0])
        for k, wk in enumerate(weights):
            R = base[i][k][0]
            Jv = np.column_stack([(plus[j][i][k][1] - minus[j][i][k][1]) / (2 * h)
                                  for j in range(n)])
            Jb = []
            for j in range(n):
                S = R.T @ (plus[j][i][k][0] - minus[j][i][k][0]) / (2 * h)
                Jb.append([S[2, 1], S[0, 2], S[1, 0]])
            Jb = np.array(Jb).T
            M += seg.mass * wk * (Jv.T @ Jv + Jb.T @ I @ Jb)
    G = np.array([(V(q + h * e) - V(q - h * e)) / (2 * h) for e in np.eye(n)])
    return M, G


@pytest.mark.parametrize("param", ["delta", "phi-theta"])
def test_M_and_G_against_finite_differences_of_independent_energies(param):
    spec = make_spec(2, param)
    tm = TrueModel(spec)
    rng = np.random.default_rng(0)
    for _ in range(2):
        q = random_q(spec, rng)
        M, G = reference_M_G(spec, q)
        np.testing.assert_allclose(tm.M(q), M, rtol=0, atol=1e-6 * np.abs(M).max())
        np.testing.assert_allclose(tm.G(q), G, rtol=0, atol=1e-6 * np.abs(G).max())


# ------------------------------------------------------------------ quadrature and structure


def test_quadrature_order_is_converged_to_1e_10():
    """The default order against order 40, at |theta| up to 2 pi."""
    spec = make_spec(2)
    tm, ref = TrueModel(spec), TrueModel(spec, order=40)
    rng = np.random.default_rng(1)
    Q = np.array([random_q(spec, rng, 0.0, 2 * np.pi) for _ in range(8)])
    QD = rng.normal(size=Q.shape)
    for got, want in ((tm.M(Q), ref.M(Q)), (tm.G(Q), ref.G(Q)), (tm.Cqd(Q, QD), ref.Cqd(Q, QD))):
        assert np.abs(got - want).max() <= 1e-10 * np.abs(want).max()


@pytest.mark.parametrize("radius, nseg", [(0.0, 3), (0.04, 2)])
def test_hoisted_densities_equal_direct_ones(radius, nseg):
    spec = make_spec(nseg, "delta", radius=radius)
    fast, direct = _Builder(derive(spec)), _Builder(derive(spec, hoist=False))
    rng = np.random.default_rng(2)
    q, qd, u = random_q(spec, rng), rng.normal(size=spec.n), rng.normal(size=spec.n)
    for key, args in (("M", [q]), ("G", [q]), ("C", [q, qd]), ("Cqd", [q, qd]), ("A", [q]),
                      ("energy", [q, qd]), ("forward", [q, qd, u]), ("hamiltonian", [q, qd, u])):
        for a, b in zip(fast.build(key).call(args), direct.build(key).call(args), strict=True):
            a, b = np.array(a), np.array(b)
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-13 * max(1.0, np.abs(b).max()),
                                       err_msg=key)


CASES = [(1, "delta"), (1, "phi-theta"), (2, "delta"), (2, "phi-theta"), (3, "delta"),
         (3, "phi-theta"), (4, "delta"), (4, "phi-theta")]


@pytest.mark.parametrize("nseg, param", CASES)
def test_structure_for_1_to_4_segments(nseg, param):
    spec = make_spec(nseg, param)
    tm = TrueModel(spec)
    rng = np.random.default_rng(nseg)
    Q = np.array([random_q(spec, rng) for _ in range(2)])
    QD, U = rng.normal(size=Q.shape), rng.normal(size=(2, spec.m))
    M, C, Cqd = tm.M(Q), tm.C(Q, QD), tm.Cqd(Q, QD)
    qdd = tm.qdd(Q, QD, U)
    tau = tm.tau(Q, QD, qdd)
    A = tm.A(Q)
    eps = 1e-6
    for k in range(len(Q)):
        scale = np.abs(M[k]).max()
        np.testing.assert_allclose(M[k], M[k].T, atol=1e-15 * scale)
        assert np.linalg.eigvalsh(M[k]).min() > 0
        Mdot = (tm.M(Q[k] + eps * QD[k]) - tm.M(Q[k] - eps * QD[k])) / (2 * eps)
        S = Mdot - 2 * C[k]
        np.testing.assert_allclose(S, -S.T, atol=1e-7 * np.abs(Mdot).max())
        np.testing.assert_allclose(C[k] @ QD[k], Cqd[k], atol=1e-12 * np.abs(Cqd[k]).max())
        np.testing.assert_allclose(tau[k], A[k] @ U[k], atol=1e-10 * np.abs(tau[k]).max())


# ------------------------------------------------------------------ zero curvature


def test_delta_is_smooth_at_zero_curvature():
    spec = make_spec(2, "delta", radius=0.03)
    fns = functions(spec)
    q, qd, u = ca.MX.sym("q", 6), ca.MX.sym("qd", 6), ca.MX.sym("u", 6)
    qdd = fns["forward"](q, qd, u)
    Mq, Gq = fns["M"](q), fns["G"](q)
    f = ca.Function("f", [q, qd, u], [Mq, Gq, qdd, ca.jacobian(Mq, q), ca.jacobian(Gq, q),
                                      ca.jacobian(qdd, ca.vertcat(q, qd))])
    qd0, u0 = np.full(6, 0.3), np.full(6, 0.1)
    at0 = [np.array(x) for x in f(np.zeros(6), qd0, u0)]
    for x in at0:
        assert np.all(np.isfinite(x))
    # bending coordinates at 1e-9: values and first derivatives agree with those at 0
    small = np.array([1e-9, 0, 0, 0, 1e-9, 0])
    at9 = [np.array(x) for x in f(small, qd0, u0)]
    at8 = [np.array(x) for x in f(10 * small, qd0, u0)]
    for a, b, c in zip(at0, at9, at8, strict=True):
        assert np.all(np.isfinite(b))
        scale = max(1.0, np.abs(a).max())
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-8 * scale)
        # no cancellation noise: the change is linear in the offset (smooth, exact series)
        np.testing.assert_allclose(c - a, 10 * (b - a), rtol=0, atol=1e-3 * np.abs(c - a).max()
                                   + 1e-14 * scale)
    for q1 in ([1e-9, 1e-9, 1e-9, 1e-9, 1e-9, 1e-9], [0.02, 0.03, 0, 0.01, 0, 0]):
        assert all(np.all(np.isfinite(np.array(x))) for x in f(np.array(q1), qd0, u0))


def test_phi_theta_mass_matrix_loses_rank_at_zero_curvature():
    """The known singularity of the phi-theta parameterization (docs/pitfalls.md): the phi column
    vanishes at theta = 0 while values stay finite."""
    tm = TrueModel(make_spec(1, "phi-theta"))
    M = tm.M(np.array([0.4, 0.0, 0.0]))
    assert np.all(np.isfinite(M))
    assert np.abs(M[0]).max() < 1e-6 * np.abs(M).max()
