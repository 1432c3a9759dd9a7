"""PCC kinematics in CasADi SX (Appendix A, eqs. 11-17; planar eq. 27).

Spatial segment i has q_i = [phi_i, theta_i, dL_i] (``phi-theta``) or q_i = [dx_i, dy_i, dL_i]
(``delta``, theta_i = sqrt(dx_i^2 + dy_i^2) / d_i, (cos phi_i, sin phi_i) = (dx_i, dy_i) / (d_i
theta_i)). Its transform is eq. 13; the plate at fraction zeta of the segment uses theta_i -> zeta
theta_i in the trigonometric terms with lambda_i = (L0_i + dL_i) / theta_i unchanged. Every term is
written with the entire functions of :mod:`symbolic.derivation._smooth`, so the ``delta`` form is
smooth at dx = dy = 0 (the ``phi-theta`` form is finite there but its Jacobian loses rank: the phi
column vanishes).

Segments are chained as in eq. 14: segment i sits behind the full transforms of segments
1..i-1, each followed by Rz(pi / a_dof). The arm starts straight along +z of the base frame.

Planar segments (eq. 27) have q_i = [theta_i, dL_i]; the straight arm points along +y and the
tangent turns towards +x as theta grows.
"""

from __future__ import annotations

import math

import casadi as ca

from softpinn.symbolic.derivation._smooth import Jet, cosc, sinc
from softpinn.symbolic.spec._model_spec import ModelSpec


def rot_z(angle: float) -> ca.DM:
    """Rotation about z by a constant angle (T_rz of eq. 12)."""
    c, s = math.cos(angle), math.sin(angle)
    return ca.DM([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def segment_pose(qi, length: float, d: float, parameterization: str, zeta=1.0, jet=None):
    """Rotation R (3x3) and position p (3x1) of the plate at ``zeta`` in the segment frame (eq. 13).

    ``qi`` is the SX 3-vector of the segment's coordinates, ``length`` its rest length L0 and ``d``
    its actuator radius (used by ``delta``). With a :class:`~symbolic.derivation._smooth.Jet`, cosc
    and sinc enter as the jet's symbols (differentiate with the jet, then finalize).
    """
    L = length + qi[2]

    def smooth_pair(s):
        if jet is None:
            return cosc(s), sinc(s)
        jet.bind(s)
        return jet.c1, jet.c2

    if parameterization == "delta":
        dx, dy = qi[0] / d, qi[1] / d  # theta (cos phi, sin phi)
        s = zeta**2 * (dx**2 + dy**2)  # (zeta theta)^2
        c1, c2 = smooth_pair(s)
        z2c1 = zeta**2 * c1
        R = ca.vertcat(
            ca.horzcat(1 - z2c1 * dx * dx, -z2c1 * dx * dy, zeta * c2 * dx),
            ca.horzcat(-z2c1 * dx * dy, 1 - z2c1 * dy * dy, zeta * c2 * dy),
            ca.horzcat(-zeta * c2 * dx, -zeta * c2 * dy, 1 - s * c1),
        )
        p = L * ca.vertcat(z2c1 * dx, z2c1 * dy, zeta * c2)
        return R, p
    if parameterization == "phi-theta":
        phi, theta = qi[0], qi[1]
        cp, sp = ca.cos(phi), ca.sin(phi)
        u = zeta * theta
        cu, su = ca.cos(u), ca.sin(u)
        R = ca.vertcat(
            ca.horzcat(cp * cp * (cu - 1) + 1, sp * cp * (cu - 1), su * cp),
            ca.horzcat(sp * cp * (cu - 1), sp * sp * (cu - 1) + 1, su * sp),
            ca.horzcat(-su * cp, -su * sp, cu),
        )
        # lambda (1 - cos u) = L zeta^2 theta cosc(u^2), lambda sin u = L zeta sinc(u^2)
        c1, c2 = smooth_pair(u * u)
        a = L * zeta * zeta * theta * c1
        p = ca.vertcat(a * cp, a * sp, L * zeta * c2)
        return R, p
    raise AssertionError(parameterization)


def spatial_segment_coords(q, i: int):
    return q[3 * i : 3 * i + 3]


def spatial_base(spec: ModelSpec, q, i: int):
    """Pose (R, t) of the base frame of segment ``i`` (0-based) in the world frame (eq. 14)."""
    R = ca.SX.eye(3)
    t = ca.SX.zeros(3, 1)
    turn = rot_z(math.pi / spec.actuators_per_segment)
    for k in range(i):
        seg = spec.segments[k]
        Rk, pk = segment_pose(spatial_segment_coords(q, k), seg.length, seg.actuator_radius,
                              spec.parameterization)
        t = t + R @ pk
        R = R @ Rk @ turn
    return R, t


def spatial_plate(spec: ModelSpec, q, i: int, zeta):
    """World pose (R, p) of the plate at ``zeta`` of segment ``i`` (eqs. 14, 21)."""
    Rb, tb = spatial_base(spec, q, i)
    seg = spec.segments[i]
    Rl, pl = segment_pose(spatial_segment_coords(q, i), seg.length, seg.actuator_radius,
                          spec.parameterization, zeta)
    return Rb @ Rl, tb + Rb @ pl


def spatial_tip(spec: ModelSpec, q, i: int):
    """World pose (R, p) of the tip of segment ``i``, before the Rz(pi / a_dof) turn."""
    return spatial_plate(spec, q, i, 1.0)


def vee(S):
    """The vector of a skew-symmetric 3x3 matrix."""
    return ca.vertcat(S[2, 1], S[0, 2], S[1, 0])


def body_angular_velocity(R, q, qd):
    """omega_b = (R^T dR/dt)^vee, linear in qd; R^T J_w of eq. 17 is its Jacobian in qd."""
    Rdot = ca.jtimes(R, q, qd)
    S = R.T @ Rdot
    return 0.5 * (vee(S) - vee(S.T))


def spatial_jacobians(R, p, q):
    """Linear and (world) angular Jacobians of a pose (eqs. 15-17): Jv = dp/dq,
    Jw[:, j] = (dR/dq_j R^T)^vee."""
    Jv = ca.jacobian(p, q)
    cols = []
    for j in range(q.numel()):
        dR = ca.jacobian(ca.vec(R), q[j]).reshape((3, 3))
        S = dR @ R.T
        cols.append(0.5 * (vee(S) - vee(S.T)))
    return Jv, ca.horzcat(*cols)


def rot_cw(angle):
    """Planar rotation turning +y towards +x by ``angle``."""
    c, s = ca.cos(angle), ca.sin(angle)
    return ca.vertcat(ca.horzcat(c, s), ca.horzcat(-s, c))


def planar_plate(spec: ModelSpec, q, i: int, zeta):
    """Position (2x1) of the point at ``zeta`` of planar segment ``i`` (eq. 27, chained)."""
    angle = 0
    t = ca.SX.zeros(2, 1)
    for k in range(i + 1):
        seg = spec.segments[k]
        theta, dL = q[2 * k], q[2 * k + 1]
        z = 1.0 if k < i else zeta
        s = (z * theta) ** 2
        L = seg.length + dL
        # Psi = [L (1 - cos(z theta)) / theta, L sin(z theta) / theta]  (eq. 27)
        local = L * ca.vertcat(z * z * theta * cosc(s), z * sinc(s))
        t = t + (rot_cw(angle) @ local if k else local)
        angle = angle + theta
    return t


def tendon_lengths(spec: ModelSpec, q):
    """Lengths of the a_dof tendons of every segment (tendon j of segment i at angle 2 pi j / a_dof
    and radius d_i in segment i's frame, running from the robot base to the tip of segment i;
    through segment k < i it sits at angle 2 pi j / a_dof + (i - k) pi / a_dof)."""
    a = spec.actuators_per_segment
    out = []
    for i, segi in enumerate(spec.segments):
        for j in range(a):
            length = 0
            for k in range(i + 1):
                segk = spec.segments[k]
                beta = 2 * math.pi * j / a + (i - k) * math.pi / a
                qk = spatial_segment_coords(q, k)
                rho = segi.actuator_radius
                if spec.parameterization == "delta":
                    bend = (rho / segk.actuator_radius) * (qk[0] * math.cos(beta)
                                                          + qk[1] * math.sin(beta))
                else:
                    bend = rho * qk[1] * ca.cos(qk[0] - beta)
                length = length + segk.length + qk[2] - bend
            out.append(length)
    return ca.vertcat(*out)


#: Names of the base-frame quantities passed between segments (all along qd, with qdd = 0):
#: pose, Jacobians in q_<, velocities, their time derivatives and bias accelerations, and the
#: body angular velocity, its Jacobian and bias acceleration.
BASE_FIELDS = ("Rb", "tb", "dtb", "dRb", "tbd", "Rbd", "dtbd", "dRbd", "Rbdd", "tbdd", "wb",
               "Jwb", "wbd", "Jwbd")


def base_shapes(k: int) -> dict[str, tuple[int, int]]:
    """Shapes of the :data:`BASE_FIELDS` for a base frame that depends on k coordinates."""
    return {"Rb": (3, 3), "tb": (3, 1), "dtb": (3, k), "dRb": (9, k), "tbd": (3, 1),
            "Rbd": (3, 3), "dtbd": (3, k), "dRbd": (9, k), "Rbdd": (3, 3), "tbdd": (3, 1),
            "wb": (3, 1), "Jwb": (3, k), "wbd": (3, 1), "Jwbd": (3, k)}


def mix(D, p):
    """sum_c D[3c:3c+3, :] p_c, i.e. the columns dR/dq_j (stored as vec(dR), 9 x k) applied
    to the vector p."""
    out = 0
    for c in range(3):
        out = out + D[3 * c : 3 * c + 3, :] * p[c]
    return out


def base_step_function(spec: ModelSpec, i: int, name: str,
                       fields: tuple[str, ...] = BASE_FIELDS) -> ca.Function:
    """One step of the recursion over segments (eq. 14): (q_i, qd_i, base_i) -> base_{i+1}.

    base_i are the :data:`BASE_FIELDS` of segment i's base frame (in q_1..q_{i-1}); base_{i+1}
    is the frame after segment i's full transform and the Rz(pi / a_dof) turn. Every derivative
    is assembled by the chain rule from the base quantities and the local transform of segment
    i, so the size of a step grows only linearly with the number of preceding coordinates.
    Segment 0 has no base input (the base frame is the world frame). ``fields`` selects the
    outputs (the frame after the last segment is needed only for the tip-wrench matrix).
    """
    seg = spec.segments[i]
    k = 3 * i
    ql, qdl = ca.SX.sym("qi", 3), ca.SX.sym("qdi", 3)
    if k:
        base = {f: ca.SX.sym(f, *s) for f, s in base_shapes(k).items()}
    else:
        base = {f: ca.SX(*s) for f, s in base_shapes(0).items()}
        base["Rb"] = ca.SX.eye(3)
    jet = Jet()
    Rl, pl = segment_pose(ql, seg.length, seg.actuator_radius, spec.parameterization, 1.0, jet)
    Rz = rot_z(math.pi / spec.actuators_per_segment)
    Jl = jet.jacobian(pl, ql)
    pld = jet.jtimes(pl, ql, qdl)
    pldd = jet.jtimes(pld, ql, qdl)
    Jld = jet.jtimes(Jl, ql, qdl)
    dRl = jet.jacobian(ca.vec(Rl), ql)
    Rld = jet.jtimes(Rl, ql, qdl)
    Rldd = jet.jtimes(Rld, ql, qdl)
    dRld = jet.jtimes(dRl, ql, qdl)
    wl = vee(Rl.T @ Rld)  # local body angular velocity, linear in qdl
    Jwl = ca.jacobian(wl, qdl)
    wld = jet.jtimes(wl, ql, qdl)
    Jwld = jet.jtimes(Jwl, ql, qdl)
    RzT = ca.DM(Rz).T
    Rb, Rbd, Rbdd = base["Rb"], base["Rbd"], base["Rbdd"]
    I3 = ca.DM.eye(3)
    RlRz, RldRz = Rl @ Rz, Rld @ Rz
    R = Rb @ RlRz
    Rd = Rbd @ RlRz + Rb @ RldRz
    Rdd = (Rbdd @ Rl + 2 * Rbd @ Rld + Rb @ Rldd) @ Rz
    # vec(X Rl Rz) = kron((Rl Rz)^T, I) vec(X);  vec(Rb Y Rz) = kron(Rz^T, Rb) vec(Y)
    dR = ca.horzcat(ca.kron(RlRz.T, I3) @ base["dRb"], ca.kron(ca.DM(Rz).T, Rb) @ dRl)
    dRd = ca.horzcat(ca.kron(RlRz.T, I3) @ base["dRbd"] + ca.kron(RldRz.T, I3) @ base["dRb"],
                     ca.kron(ca.DM(Rz).T, Rbd) @ dRl + ca.kron(ca.DM(Rz).T, Rb) @ dRld)
    out = {
        "Rb": R,
        "tb": base["tb"] + Rb @ pl,
        "dtb": ca.horzcat(base["dtb"] + mix(base["dRb"], pl), Rb @ Jl),
        "dRb": dR,
        "tbd": base["tbd"] + Rbd @ pl + Rb @ pld,
        "Rbd": Rd,
        "dtbd": ca.horzcat(base["dtbd"] + mix(base["dRbd"], pl) + mix(base["dRb"], pld),
                           Rbd @ Jl + Rb @ Jld),
        "dRbd": dRd,
        "Rbdd": Rdd,
        "tbdd": base["tbdd"] + Rbdd @ pl + 2 * Rbd @ pld + Rb @ pldd,
        # body angular velocity: omega' = (Rl Rz)^T omega_b + Rz^T omega_l
        "wb": RlRz.T @ base["wb"] + RzT @ wl,
        "Jwb": ca.horzcat(RlRz.T @ base["Jwb"], RzT @ Jwl),
        "wbd": RldRz.T @ base["wb"] + RlRz.T @ base["wbd"] + RzT @ wld,
        "Jwbd": ca.horzcat(RldRz.T @ base["Jwb"] + RlRz.T @ base["Jwbd"], RzT @ Jwld),
    }
    ins = [ql, qdl] + ([base[f] for f in BASE_FIELDS] if k else [])
    names = ["qi", "qdi"] + (list(BASE_FIELDS) if k else [])
    outs = jet.finalize([ca.densify(out[f]) for f in fields])
    return ca.Function(name, ins, outs, names, [f + "_next" for f in fields], {"cse": True})
