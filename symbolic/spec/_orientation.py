"""Tip orientation <-> bending configuration of a one-segment spatial PCC arm (eq. 13).

An IMU on the tip plate measures the plate's orientation. Eq. 13's tip rotation is

    R(phi, theta) = exp(theta [(-sin phi, cos phi, 0)]x),

a rotation by theta about a horizontal axis: its third column, the tip tangent, is
(sin theta cos phi, sin theta sin phi, cos theta). The tangent alone therefore gives theta in
[0, pi] and phi exactly, hence the delta form's dx = d theta cos phi = d (theta / sin theta) R02
and dy = d (theta / sin theta) R12, which stay smooth at theta = 0 (theta / sin theta -> 1). The
stretch dL does not change the rotation: orientation cannot observe it. A measured rotation may
hold a twist psi about the tangent that PCC does not have (R = R(phi, theta) Rz(psi));
:func:`bending_from_rotation` reports it, as a check of the sensor's frame.

Conventions (``docs/import.md``): rotations map tip-frame vectors to base-frame vectors (the
IMU's reading relative to the arm's base, identity for the straight arm, tip z along the
tangent); quaternions are (w, x, y, z), Hamilton's; roll, pitch, yaw are the z-y-x angles,
R = Rz(yaw) Ry(pitch) Rx(roll).
"""

from __future__ import annotations

import numpy as np

from softpinn.errors import UserError

#: bending angles closer than this to pi cannot be told apart by orientation (phi undefined)
THETA_MAX = np.pi - 1e-6


def quaternion_to_matrix(quat) -> np.ndarray:
    """Rotation matrices (N, 3, 3) of quaternions (N, 4) ordered (w, x, y, z); each quaternion
    is normalised first (its sign does not matter)."""
    q = np.asarray(quat, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    R = np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )
    return R


def matrix_to_quaternion(R) -> np.ndarray:
    """Unit quaternions (N, 4), (w, x, y, z) with w >= 0, of rotation matrices (N, 3, 3)."""
    R = np.asarray(R, dtype=float)
    tr = np.trace(R, axis1=-2, axis2=-1)
    diag = np.stack([tr, R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]], -1)
    out = np.empty(R.shape[:-2] + (4,))
    k = np.argmax(diag, axis=-1)  # Shepperd: divide by the largest of 4 w^2, 4 x^2, ...
    r = R
    cand = [
        np.stack([1 + tr, r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0],
                  r[..., 1, 0] - r[..., 0, 1]], -1),
        np.stack([r[..., 2, 1] - r[..., 1, 2], 1 + 2 * r[..., 0, 0] - tr,
                  r[..., 0, 1] + r[..., 1, 0], r[..., 0, 2] + r[..., 2, 0]], -1),
        np.stack([r[..., 0, 2] - r[..., 2, 0], r[..., 0, 1] + r[..., 1, 0],
                  1 + 2 * r[..., 1, 1] - tr, r[..., 1, 2] + r[..., 2, 1]], -1),
        np.stack([r[..., 1, 0] - r[..., 0, 1], r[..., 0, 2] + r[..., 2, 0],
                  r[..., 1, 2] + r[..., 2, 1], 1 + 2 * r[..., 2, 2] - tr], -1),
    ]
    for i, c in enumerate(cand):
        sel = k == i
        out[sel] = c[sel]
    out /= np.linalg.norm(out, axis=-1, keepdims=True)
    out *= np.where(out[..., :1] < 0, -1.0, 1.0)
    return out


def rpy_to_matrix(rpy) -> np.ndarray:
    """R = Rz(yaw) Ry(pitch) Rx(roll) (N, 3, 3) of angles (N, 3) ordered roll, pitch, yaw."""
    a = np.asarray(rpy, dtype=float)
    cr, cp, cy = np.cos(a[..., 0]), np.cos(a[..., 1]), np.cos(a[..., 2])
    sr, sp, sy = np.sin(a[..., 0]), np.sin(a[..., 1]), np.sin(a[..., 2])
    return np.stack(
        [
            np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], -1),
            np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], -1),
            np.stack([-sp, cp * sr, cp * cr], -1),
        ],
        -2,
    )


def matrix_to_rpy(R) -> np.ndarray:
    """Roll, pitch, yaw (N, 3) with pitch in [-pi/2, pi/2] of rotation matrices (N, 3, 3)."""
    R = np.asarray(R, dtype=float)
    pitch = np.arcsin(np.clip(-R[..., 2, 0], -1.0, 1.0))
    roll = np.arctan2(R[..., 2, 1], R[..., 2, 2])
    yaw = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    return np.stack([roll, pitch, yaw], -1)


def pcc_rotation(phi, theta) -> np.ndarray:
    """Eq. 13's tip rotation (N, 3, 3) at bending direction ``phi`` and angle ``theta``."""
    phi, theta = np.broadcast_arrays(np.asarray(phi, float), np.asarray(theta, float))
    cp, sp, ct, st = np.cos(phi), np.sin(phi), np.cos(theta), np.sin(theta)
    return np.stack(
        [
            np.stack([cp * cp * (ct - 1) + 1, sp * cp * (ct - 1), st * cp], -1),
            np.stack([sp * cp * (ct - 1), sp * sp * (ct - 1) + 1, st * sp], -1),
            np.stack([-st * cp, -st * sp, ct], -1),
        ],
        -2,
    )


def bending_from_rotation(R, parameterization: str, actuator_radius: float):
    """The bending coordinates of a one-segment PCC arm whose tip rotation is ``R`` (N, 3, 3).

    Returns ``(bend, theta, twist)``: ``bend`` (N, 2) is (dx, dy) for ``delta`` (with the
    actuator radius d) or (phi, theta) for ``phi-theta`` (phi in (-pi, pi]; unwrap it along
    time), ``theta`` (N,) the bending angle in [0, pi], ``twist`` (N,) the rotation about the
    tangent that eq. 13 does not have (0 for an exact PCC rotation).
    """
    R = np.asarray(R, dtype=float)
    t = R[..., :, 2] / np.linalg.norm(R[..., :, 2], axis=-1, keepdims=True)  # tip tangent
    s = np.hypot(t[..., 0], t[..., 1])  # sin theta
    theta = np.arctan2(s, t[..., 2])
    phi = np.arctan2(t[..., 1], t[..., 0])
    # the twist: R(phi, theta)^T R = Rz(psi)
    Rp = pcc_rotation(phi, theta)
    Z = np.einsum("...ji,...jk->...ik", Rp, R)
    twist = np.arctan2(Z[..., 1, 0] - Z[..., 0, 1], Z[..., 0, 0] + Z[..., 1, 1])
    if parameterization == "delta":
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(s > 0, theta / np.where(s > 0, s, 1.0), 1.0)  # theta / sin theta
        bend = actuator_radius * ratio[..., None] * t[..., :2]
    elif parameterization == "phi-theta":
        bend = np.stack([phi, theta], -1)
    else:
        raise UserError(f"parameterization: expected delta or phi-theta, got {parameterization!r}")
    return bend, theta, twist


def rotation_of_bending(bend, parameterization: str, actuator_radius: float) -> np.ndarray:
    """The inverse of :func:`bending_from_rotation`: eq. 13's tip rotation (N, 3, 3) of the
    bending coordinates (N, 2), (dx, dy) or (phi, theta)."""
    b = np.asarray(bend, dtype=float)
    if parameterization == "delta":
        ux, uy = b[..., 0] / actuator_radius, b[..., 1] / actuator_radius
        theta = np.hypot(ux, uy)
        phi = np.arctan2(uy, ux)
    else:
        phi, theta = b[..., 0], b[..., 1]
    return pcc_rotation(phi, theta)
