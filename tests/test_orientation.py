"""Tip orientation <-> bending of a one-segment PCC arm (symbolic/spec/_orientation.py), checked
against the project's forward kinematics (symbolic/derivation/_kinematics.py, eq. 13):
q -> tip rotation ->
quaternion or roll-pitch-yaw -> q to 1e-9, at random q and near the straight arm."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from softpinn.symbolic.derivation import _kinematics as kin
from softpinn.symbolic.spec import _orientation as ori


def fk_rotation(q, param: str, d: float) -> np.ndarray:
    """The tip rotation of one segment from the project's kinematics (CasADi, evaluated)."""
    qs = ca.SX.sym("q", 3)
    R, _ = kin.segment_pose(qs, 0.2, d, param)
    f = ca.Function("R", [qs], [R])
    return np.stack([np.array(f(np.asarray(qi, dtype=float))) for qi in q])


def random_delta_q(rng, count: int, d: float) -> np.ndarray:
    """Bending angles from 0 to 3 rad in all directions, and near theta = 0 (down to 0 itself)."""
    theta = np.r_[rng.uniform(0.0, 3.0, count), 0.0, 1e-15, 1e-12, 1e-9, 1e-6, 1e-4, 1e-2]
    phi = rng.uniform(-np.pi, np.pi, len(theta))
    dL = rng.uniform(-0.05, 0.1, len(theta))
    return np.stack([d * theta * np.cos(phi), d * theta * np.sin(phi), dL], 1)


@pytest.mark.parametrize("d", [1.0, 0.015])
@pytest.mark.parametrize("via", ["matrix", "quaternion", "rpy"])
def test_delta_round_trip_through_the_forward_kinematics(d, via):
    rng = np.random.default_rng(17)
    q = random_delta_q(rng, 40, d)
    R = fk_rotation(q, "delta", d)
    np.testing.assert_allclose(R, ori.rotation_of_bending(q[:, :2], "delta", d), atol=1e-14)
    if via == "quaternion":
        quat = ori.matrix_to_quaternion(R)
        np.testing.assert_allclose(np.linalg.norm(quat, axis=1), 1.0, atol=1e-15)
        R = ori.quaternion_to_matrix(quat)
    elif via == "rpy":
        R = ori.rpy_to_matrix(ori.matrix_to_rpy(R))
    bend, theta, twist = ori.bending_from_rotation(R, "delta", d)
    np.testing.assert_allclose(bend, q[:, :2], rtol=0, atol=1e-9 * d)
    np.testing.assert_allclose(theta, np.hypot(q[:, 0], q[:, 1]) / d, atol=1e-9)
    np.testing.assert_allclose(twist, 0.0, atol=1e-9)


def test_near_straight_the_map_is_smooth_and_exact():
    d = 0.02
    for theta in (0.0, 1e-300, 1e-12, 1e-8):
        q = np.array([[d * theta * 0.6, -d * theta * 0.8, 0.0]])
        bend, _, _ = ori.bending_from_rotation(fk_rotation(q, "delta", d), "delta", d)
        np.testing.assert_allclose(bend, q[:, :2], rtol=1e-12, atol=1e-300)


def test_phi_theta_round_trip():
    rng = np.random.default_rng(3)
    phi = rng.uniform(-np.pi + 1e-3, np.pi, 50)
    theta = rng.uniform(1e-3, 3.0, 50)
    q = np.stack([phi, theta, np.zeros(50)], 1)
    R = fk_rotation(q, "phi-theta", 1.0)
    for R2 in (R, ori.quaternion_to_matrix(ori.matrix_to_quaternion(R)),
               ori.rpy_to_matrix(ori.matrix_to_rpy(R))):
        bend, _, twist = ori.bending_from_rotation(R2, "phi-theta", 1.0)
        np.testing.assert_allclose(bend, q[:, :2], atol=1e-9)
        np.testing.assert_allclose(twist, 0.0, atol=1e-9)


def test_stretch_does_not_change_the_rotation():
    q = np.array([[0.3, -0.2, 0.0], [0.3, -0.2, 0.08]])
    R = fk_rotation(q, "delta", 1.0)
    np.testing.assert_array_equal(R[0], R[1])


def test_a_twist_about_the_tangent_is_reported_and_does_not_move_the_bending():
    q = np.array([[0.4, 0.1, 0.0]])
    R = fk_rotation(q, "delta", 1.0)
    c, s = np.cos(0.3), np.sin(0.3)
    Rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    bend, _, twist = ori.bending_from_rotation(R @ Rz, "delta", 1.0)
    np.testing.assert_allclose(bend, q[:, :2], atol=1e-12)
    np.testing.assert_allclose(twist, [0.3], atol=1e-12)


def test_conventions():
    # roll about x, pitch about y, yaw about z, R = Rz(yaw) Ry(pitch) Rx(roll)
    np.testing.assert_allclose(ori.rpy_to_matrix([[0.0, 0.0, np.pi / 2]])[0] @ [1, 0, 0],
                               [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(ori.rpy_to_matrix([[np.pi / 2, 0.0, 0.0]])[0] @ [0, 1, 0],
                               [0, 0, 1], atol=1e-15)
    # quaternion (w, x, y, z): a quarter turn about y takes z to x; the sign does not matter
    h = np.sqrt(0.5)
    for quat in ([h, 0.0, h, 0.0], [-h, 0.0, -h, 0.0]):
        np.testing.assert_allclose(ori.quaternion_to_matrix([quat])[0] @ [0, 0, 1], [1, 0, 0],
                                   atol=1e-15)
    # an arm bent towards +x (phi = 0) tilts its tip about +y: pitch = theta
    R = ori.rotation_of_bending([[0.5, 0.0]], "delta", 1.0)
    np.testing.assert_allclose(ori.matrix_to_rpy(R), [[0.0, 0.5, 0.0]], atol=1e-15)


def test_quaternions_round_trip_in_every_branch():
    rng = np.random.default_rng(5)
    quat = rng.normal(size=(200, 4))
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    quat *= np.sign(quat[:, :1])
    R = ori.quaternion_to_matrix(quat)
    np.testing.assert_allclose(np.einsum("nij,nkj->nik", R, R), np.broadcast_to(np.eye(3),
                               R.shape), atol=1e-14)
    np.testing.assert_allclose(ori.matrix_to_quaternion(R), quat, atol=1e-14)
