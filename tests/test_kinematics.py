"""PCC kinematics: eq. 13 as printed, delta = phi-theta, chaining (eq. 14), Jacobians (eq. 17),
the recursive base steps, tip-wrench and tendon actuation."""

from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest

from softpinn.symbolic.derivation import _kinematics as kin
from softpinn.symbolic.derivation._eom import tip_wrench_matrix
from softpinn.symbolic.spec._spec import spec_from_dict


def make_spec(nseg=2, param="delta", actuation="generalized", adof=4, d=0.5):
    seg = dict(length=0.2, mass=0.3, radius=0.03, actuator_radius=d, stiffness=[1.0] * 3,
               damping=[0.1] * 3)
    return spec_from_dict(dict(name="arm", kind="spatial-pcc", parameterization=param,
                               gravity=[0.0, 0.0, -9.81], actuators_per_segment=adof,
                               actuation=actuation, segment=[seg] * nseg))


def eq13(phi, theta, dL, L0=0.2, zeta=1.0):
    """Eq. 13 as printed, with theta -> zeta theta in the trigonometric terms."""
    lam = (L0 + dL) / theta
    c, s = math.cos(phi), math.sin(phi)
    ct, st = math.cos(zeta * theta), math.sin(zeta * theta)
    R = np.array([[c * c * (ct - 1) + 1, s * c * (ct - 1), st * c],
                  [s * c * (ct - 1), s * s * (ct - 1) + 1, st * s],
                  [-st * c, -st * s, ct]])
    p = np.array([lam * c * (1 - ct), lam * s * (1 - ct), lam * st])
    return R, p


def pose(qi, param, zeta, d=0.5):
    R, p = kin.segment_pose(ca.DM(qi), 0.2, d, param, zeta)
    return np.array(ca.evalf(R)), np.array(ca.evalf(p)).ravel()


@pytest.mark.parametrize("zeta", [1.0, 0.37])
def test_segment_pose_is_eq13_in_both_parameterizations(zeta):
    rng = np.random.default_rng(0)
    for _ in range(5):
        phi, theta = rng.uniform(-np.pi, np.pi), rng.uniform(0.05, 2 * np.pi)
        dL = rng.uniform(-0.05, 0.1)
        R0, p0 = eq13(phi, theta, dL, zeta=zeta)
        R1, p1 = pose([phi, theta, dL], "phi-theta", zeta)
        d = 0.5
        R2, p2 = pose([d * theta * math.cos(phi), d * theta * math.sin(phi), dL], "delta", zeta, d)
        for R, p in ((R1, p1), (R2, p2)):
            np.testing.assert_allclose(R, R0, atol=1e-14)
            np.testing.assert_allclose(p, p0, atol=1e-15)
        np.testing.assert_allclose(R2 @ R2.T, np.eye(3), atol=1e-14)


def test_straight_arm_along_z():
    R, p = pose([0.0, 0.0, 0.05], "delta", 0.5)
    np.testing.assert_array_equal(R, np.eye(3))
    np.testing.assert_allclose(p, [0, 0, 0.125], atol=0)
    R, p = pose([0.3, 0.0, 0.0], "phi-theta", 1.0)
    np.testing.assert_allclose(p, [0, 0, 0.2], atol=0)


def _numeric_chain(spec, q, i, zeta):
    """World pose of the plate at zeta of segment i, multiplied out in numpy (eq. 14)."""
    T = np.eye(4)
    turn = np.eye(4)
    a = math.pi / spec.actuators_per_segment
    turn[:2, :2] = [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
    for k in range(i + 1):
        R, p = pose(q[3 * k : 3 * k + 3], spec.parameterization, 1.0 if k < i else zeta)
        Tk = np.eye(4)
        Tk[:3, :3], Tk[:3, 3] = R, p
        T = T @ Tk @ (turn if k < i else np.eye(4))
    return T[:3, :3], T[:3, 3]


def test_chain_and_jacobians():
    spec = make_spec(3)
    q = ca.SX.sym("q", 9)
    rng = np.random.default_rng(1)
    q0 = rng.uniform(-0.6, 0.6, 9)
    R, p = kin.spatial_plate(spec, q, 2, 0.6)
    f = ca.Function("f", [q], [R, p])
    Rn, pn = _numeric_chain(spec, q0, 2, 0.6)
    np.testing.assert_allclose(np.array(f(q0)[0]), Rn, atol=1e-14)
    np.testing.assert_allclose(np.array(f(q0)[1]).ravel(), pn, atol=1e-14)
    # eq. 17: Jv = dp/dq and Jw = (dR/dq_j R^T)^vee against central differences
    Jv, Jw = kin.spatial_jacobians(R, p, q)
    J = ca.Function("J", [q], [Jv, Jw])
    Jv0, Jw0 = (np.array(x) for x in J(q0))
    h = 1e-6
    for j in range(9):
        e = np.zeros(9)
        e[j] = h
        Rp, pp = _numeric_chain(spec, q0 + e, 2, 0.6)
        Rm, pm = _numeric_chain(spec, q0 - e, 2, 0.6)
        np.testing.assert_allclose(Jv0[:, j], (pp - pm) / (2 * h), atol=1e-8)
        S = (Rp - Rm) / (2 * h) @ Rn.T
        np.testing.assert_allclose(Jw0[:, j], [S[2, 1], S[0, 2], S[1, 0]], atol=1e-8)
    # the body angular Jacobian is R^T Jw
    qd = ca.SX.sym("qd", 9)
    Jb = ca.jacobian(kin.body_angular_velocity(R, q, qd), qd)
    Jb0 = np.array(ca.Function("Jb", [q], [Jb])(q0))
    np.testing.assert_allclose(Jb0, Rn.T @ Jw0, atol=1e-13)


@pytest.mark.parametrize("param", ["delta", "phi-theta"])
def test_recursive_base_steps_equal_direct_derivatives(param):
    spec = make_spec(3, param)
    q, qd = ca.SX.sym("q", 9), ca.SX.sym("qd", 9)
    rng = np.random.default_rng(2)
    q0, qd0 = rng.uniform(-0.8, 0.8, 9), rng.uniform(-1, 1, 9)
    base = []
    for i in range(3):
        step = kin.base_step_function(spec, i, f"s{i}")
        base = step.call([ca.DM(q0[3 * i : 3 * i + 3]), ca.DM(qd0[3 * i : 3 * i + 3]), *base])
    # direct: the frame after segment 3 (incl. the turn), differentiated by CasADi AD
    Rb, tb = kin.spatial_base(spec, q, 3)
    Rbd, tbd = ca.jtimes(Rb, q, qd), ca.jtimes(tb, q, qd)
    direct = {"Rb": Rb, "tb": tb, "dtb": ca.jacobian(tb, q), "dRb": ca.jacobian(ca.vec(Rb), q),
              "tbd": tbd, "Rbd": Rbd, "Rbdd": ca.jtimes(Rbd, q, qd),
              "tbdd": ca.jtimes(tbd, q, qd), "dtbd": ca.jtimes(ca.jacobian(tb, q), q, qd)}
    f = ca.Function("d", [q, qd], list(direct.values()))
    got = dict(zip(kin.BASE_FIELDS, base, strict=True))
    for (name, _), want in zip(direct.items(), f(q0, qd0), strict=True):
        np.testing.assert_allclose(np.array(got[name]), np.array(want), atol=1e-12,
                                   err_msg=name)
    wb = kin.vee(Rb.T @ Rbd)
    g = ca.Function("w", [q, qd], [wb, ca.jacobian(wb, qd), ca.jtimes(wb, q, qd)])
    for name, want in zip(("wb", "Jwb", "wbd"), g(q0, qd0), strict=True):
        np.testing.assert_allclose(np.array(got[name]), np.array(want), atol=1e-12,
                                   err_msg=name)


def test_tip_wrench_is_virtual_work_of_tip_torque_and_force():
    """A_i u is the generalized force of torques u1, u2 about the tip frame's x and y axes and
    a force u3 along its tangent: tau = Jw^T R (-u1 e_x - u2 e_y) + Jv^T R e_z u3."""
    spec = make_spec(2, actuation="tip-wrench")
    q = ca.SX.sym("q", 6)
    qd = ca.SX.sym("qd", 6)
    A = ca.Function("A", [q], [tip_wrench_matrix(spec, q, qd, 1)])
    q0 = np.random.default_rng(3).uniform(-0.7, 0.7, 6)
    R, p = kin.spatial_tip(spec, q, 1)
    Jv, Jw = kin.spatial_jacobians(R, p, q)
    f = ca.Function("f", [q], [R, Jv, Jw])
    R0, Jv0, Jw0 = (np.array(x) for x in f(q0))
    want = np.column_stack([-Jw0.T @ R0[:, 0], -Jw0.T @ R0[:, 1], Jv0.T @ R0[:, 2]])
    np.testing.assert_allclose(np.array(A(q0)), want, atol=1e-13)


def _tendon_length_by_arc(spec, q0, i, j, samples=4001):
    """Length of tendon j of segment i as the arc length of the offset curve (eq. 13 in numpy,
    sampled densely)."""
    a = spec.actuators_per_segment
    total = 0.0
    rho = spec.segments[i].actuator_radius
    for k in range(i + 1):
        beta = 2 * math.pi * j / a + (i - k) * math.pi / a
        x, y, dL = q0[3 * k : 3 * k + 3]
        if spec.parameterization == "delta":
            d = spec.segments[k].actuator_radius
            phi, theta = math.atan2(y, x), math.hypot(x, y) / d
        else:
            phi, theta = x, y
        pts = []
        for z in np.linspace(0, 1, samples)[1:]:
            R, p = eq13(phi, theta, dL, zeta=z)
            pts.append(p + R @ [rho * math.cos(beta), rho * math.sin(beta), 0.0])
        pts = np.array([[rho * math.cos(beta), rho * math.sin(beta), 0.0], *pts])
        total += np.linalg.norm(np.diff(pts, axis=0), axis=1).sum()
    return total


@pytest.mark.parametrize("param", ["delta", "phi-theta"])
def test_tendon_lengths_are_arc_lengths(param):
    spec = make_spec(2, param, actuation="tendon", adof=3, d=0.02)
    q = ca.SX.sym("q", 6)
    lengths = ca.Function("l", [q], [kin.tendon_lengths(spec, q)])
    if param == "delta":
        q0 = np.array([0.01, 0.012, 0.02, -0.008, 0.015, -0.01])
    else:
        q0 = np.array([0.4, 0.6, 0.02, 2.0, 0.9, -0.01])
    got = np.array(lengths(q0)).ravel()
    assert got.shape == (6,)
    for i in range(2):
        for j in range(3):
            want = _tendon_length_by_arc(spec, q0, i, j)
            assert got[3 * i + j] == pytest.approx(want, rel=1e-7)
