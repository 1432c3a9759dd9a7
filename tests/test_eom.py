"""Equations of motion: closed forms of eqs. 25-26, Table VI, and structural properties
(M SPD, Mdot - 2C skew, inverse inverts forward, Hamiltonian form) for every kind."""

from __future__ import annotations

import numpy as np
import pytest

from softpinn.symbolic import TrueModel, UserError
from softpinn.symbolic.model._functions import functions


def test_mass_spring_damper_matches_eq25():
    tm = TrueModel("task1")
    m1, m2, k1, k2, b = 1.0, 1.8, 2.1, 4.6, 0.3
    q, qd = np.array([0.5, -0.8]), np.array([0.3, -0.2])
    K = np.array([[k1, -k1], [-k1, k1 + k2]])
    D = np.array([[b, -b], [-b, b]])
    np.testing.assert_allclose(tm.M(q), np.diag([m1, m2]), atol=1e-15)
    np.testing.assert_allclose(tm.G(q), K @ q, atol=1e-14)
    np.testing.assert_allclose(tm.D(q), D, atol=1e-15)
    assert tm.m == 0 and tm.A(q).shape == (2, 0)
    qdd = np.linalg.solve(np.diag([m1, m2]), -K @ q - D @ qd)
    np.testing.assert_allclose(tm.qdd(q, qd), qdd, atol=1e-14)
    assert tm.energy(q, qd) == pytest.approx(0.5 * qd @ np.diag([m1, m2]) @ qd + 0.5 * q @ K @ q)


def _pendulum_reference(q, qd, m1=1.0, m2=1.0, l1=1.0, l2=1.0, g=9.8):
    c, s = np.cos(q[0] - q[1]), np.sin(q[0] - q[1])
    M = np.array([[(m1 + m2) * l1**2, m2 * l1 * l2 * c], [m2 * l1 * l2 * c, m2 * l2**2]])
    # Coriolis/centrifugal forces of eq. 26's M (eq. 26's printed C matrix is inconsistent)
    Cqd = np.array([m2 * l1 * l2 * s * qd[1] ** 2, -m2 * l1 * l2 * s * qd[0] ** 2])
    G = np.array([(m1 + m2) * g * l1 * np.sin(q[0]), m2 * g * l2 * np.sin(q[1])])
    return M, Cqd, G


def test_double_pendulum_matches_eq26():
    tm = TrueModel("task2")
    rng = np.random.default_rng(2)
    for _ in range(3):
        q, qd = rng.uniform(-2, 2, 2), rng.uniform(-2, 2, 2)
        M, Cqd, G = _pendulum_reference(q, qd)
        np.testing.assert_allclose(tm.M(q), M, atol=1e-14)
        np.testing.assert_allclose(tm.Cqd(q, qd), Cqd, atol=1e-13)
        np.testing.assert_allclose(tm.G(q), G, atol=1e-13)
        np.testing.assert_allclose(tm.qdd(q, qd), np.linalg.solve(M, -Cqd - G), atol=1e-12)


TABLE_VI = [  # q, M12, G  (Table VI, mathematical model; row 4 prints G2 = 3.360 for -3.360)
    ([np.pi / 5, np.pi / 9], 0.961, [11.521, 3.352]),
    ([2.123, 0.01], -0.516, [16.687, 0.098]),
    ([-0.6, -2.3], -0.129, [-11.067, -7.308]),
    ([1.9, -0.35], -0.628, [18.548, -3.360]),
    ([np.pi / 3.3, 0.28], 0.783, [15.966, 2.708]),
]


@pytest.mark.parametrize("q, m12, G", TABLE_VI)
def test_double_pendulum_table_vi(q, m12, G):
    tm = TrueModel("task2")
    M = tm.M(np.array(q))
    # to the printed digits: within one unit of the last digit (the paper prints 18.548 for
    # 18.5475, so half a unit is not always kept)
    np.testing.assert_allclose(M, [[2.0, m12], [m12, 1.0]], atol=1e-3)
    np.testing.assert_allclose(tm.G(np.array(q)), G, atol=1e-3)


@pytest.mark.parametrize("name", ["task1", "task2", "task3", "task4"])
def test_structure(name):
    tm = TrueModel(name)
    rng = np.random.default_rng(0)
    q, qd = rng.uniform(-0.8, 0.8, tm.n), rng.uniform(-1, 1, tm.n)
    u = rng.uniform(-1, 1, tm.m)
    M = tm.M(q)
    np.testing.assert_allclose(M, M.T, atol=1e-15)
    assert np.linalg.eigvalsh(M).min() > 0
    np.testing.assert_allclose(tm.M_inv(q) @ M, np.eye(tm.n), atol=1e-10)
    C = tm.C(q, qd)
    np.testing.assert_allclose(C @ qd, tm.Cqd(q, qd), atol=1e-12 * max(1, np.abs(M).max()))
    qdd = tm.qdd(q, qd, u)
    np.testing.assert_allclose(tm.tau(q, qd, qdd), tm.A(q) @ u, atol=1e-10)
    p = tm.momentum(q, qd)
    qdot, pdot = tm.hamiltonian(q, p, u)
    np.testing.assert_allclose(qdot, qd, atol=1e-10)
    # pdot = d/dt (M qd) = Mdot qd + M qdd
    eps = 1e-6
    Mdot = (tm.M(q + eps * qd) - tm.M(q - eps * qd)) / (2 * eps)
    np.testing.assert_allclose(pdot, Mdot @ qd + M @ qdd, rtol=1e-6, atol=1e-7)
    xdot = tm.ode(np.concatenate([q, qd]), u)
    np.testing.assert_allclose(xdot, np.concatenate([qd, qdd]), atol=1e-12)
    assert tm.energy(q, qd) == pytest.approx(tm.kinetic(q, qd) + tm.potential(q))


def test_batched_equals_single():
    tm = TrueModel("task2")
    rng = np.random.default_rng(1)
    Q, QD = rng.normal(size=(4, 2)), rng.normal(size=(4, 2))
    Mb, Gb, Eb, Ab = tm.M(Q), tm.G(Q), tm.energy(Q, QD), tm.qdd(Q, QD)
    assert Mb.shape == (4, 2, 2) and Gb.shape == (4, 2) and Eb.shape == (4,)
    for k in range(4):
        np.testing.assert_allclose(Mb[k], tm.M(Q[k]), atol=0)
        np.testing.assert_allclose(Gb[k], tm.G(Q[k]), atol=0)
        np.testing.assert_allclose(Ab[k], tm.qdd(Q[k], QD[k]), atol=0)
        assert Eb[k] == tm.energy(Q[k], QD[k])


def test_function_names_and_signatures():
    fns = functions("task2")
    assert fns["forward"].name() == "task2_forward"
    assert fns["forward"].name_in() == ["q", "qd", "u"]
    assert fns["hamiltonian"].name_out() == ["qdot", "pdot"]
    assert functions("task2")["M"] is fns["M"]  # cached per spec


def test_wrong_length_is_a_user_error():
    tm = TrueModel("task2")
    with pytest.raises(UserError, match="q: expected length 2 .* got 3"):
        tm.M(np.zeros(3))
    with pytest.raises(UserError, match="qd: expected length 2"):
        tm.qdd(np.zeros(2), np.zeros(5))
    with pytest.raises(UserError, match="batch size"):
        tm.qdd(np.zeros((3, 2)), np.zeros((4, 2)))
