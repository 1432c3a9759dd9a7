"""The energy terms of spatial PCC segments with the base frame's motion hoisted out of the
zeta integral (eqs. 13-22): :class:`HoistedPlate` (per-node densities over the segment's own
coordinates and its base pose) and :class:`SegmentMoments` (M, G and C qd of a segment without
plate inertia from zeta-moments of its local kinematics). Both equal
:class:`symbolic.derivation._energies.PlateTerms` integrated over zeta (tested); they make the
functions of many segments small (:mod:`symbolic.model._functions`).
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from softpinn.symbolic.derivation import _kinematics as kin
from softpinn.symbolic.derivation._smooth import Jet
from softpinn.symbolic.spec._model_spec import ModelSpec


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
    (recursively, :func:`symbolic.derivation._kinematics.base_step_function`);
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


#: local zeta-moments of a segment (see :class:`SegmentMoments`), with their shapes
MOMENTS = {"P1": (3, 1), "P2": (3, 3), "Q1": (3, 3), "Q2": (9, 3), "Q3": (3, 3), "D1": (3, 1),
           "D2": (3, 3), "A1": (3, 1), "A2": (3, 3), "Q4": (9, 3), "A3": (3, 1)}


class SegmentMoments:
    """M, G and C qd of a spatial segment without plate inertia from zeta-moments of its
    local kinematics: only the local quantities are integrated, the base frame enters once.

    With p = p_l(zeta), J = dp_l/dq_i, p' = J qd_i, p'' = d/dt(J) qd_i (local, eq. 13) and the
    base quantities of :data:`symbolic.derivation._kinematics.BASE_FIELDS` (B_c = rows 3c..3c+2 of
    dR_b/dq_<, so Jv = [dt_b + sum_c B_c p_c, R_b J]), the moments

        P1 = int p, P2 = int p p^T, Q1 = int J, Q2_c = int p_c J, Q3 = int J^T J,
        D1 = int p', D2 = int p p'^T, A1 = int p'', A2 = int p p''^T, Q4_c = int p'_c J,
        A3 = int J^T p''

    give exactly (m the segment's mass, g gravity, X = R_b^T R_b'', Y = R_b^T R_b')

        M_<< = m (dt^T dt + sum_c P1_c (dt^T B_c + B_c^T dt) + sum_ce P2_ce B_c^T B_e)
        M_<i = m (dt^T R_b Q1 + sum_c B_c^T R_b Q2_c),   M_ii = m Q3
        G_<  = -m (dt^T g + sum_c P1_c B_c^T g),         G_i = -m Q1^T R_b^T g
        Cqd_< = m (dt^T (t'' + R_b'' P1 + 2 R_b' D1 + R_b A1)
                   + sum_c B_c^T (t'' P1_c + R_b'' P2[:, c] + 2 R_b' D2[c]^T + R_b A2[c]^T))
        Cqd_i = m (Q1^T R_b^T t'' + sum_c Q2_c^T X[:, c] + 2 sum_c Q4_c^T Y[:, c] + A3).

    These equal the integrals of :class:`HoistedPlate`'s densities (tested); the mapped
    density is the same small function for every segment.
    """

    NEEDS = {"M": ("P1", "P2", "Q1", "Q2", "Q3"), "G": ("P1", "Q1"),
             "Cqd": ("P1", "P2", "Q1", "Q2", "D1", "D2", "A1", "A2", "Q4", "A3")}
    NEEDS_FIRST = {"M": ("Q3",), "G": ("Q1",), "Cqd": ("A3",)}  # segment 1: no base motion

    def __init__(self, spec: ModelSpec, i: int):
        self.spec, self.i = spec, i
        self.k = 3 * i
        self.mass = spec.segments[i].mass
        self.g = ca.DM(spec.gravity)

    def supports(self, keys) -> bool:
        return self.spec.segments[self.i].radius == 0 and set(keys) <= {"M", "G", "Cqd"}

    def moment_names(self, keys) -> tuple[str, ...]:
        table = self.NEEDS if self.k else self.NEEDS_FIRST
        wanted = {name for key in keys for name in table[key]}
        return tuple(name for name in MOMENTS if name in wanted)

    def density_function(self, keys, name: str) -> ca.Function:
        """(q_i, qd_i, zeta, w) -> w times the integrands of the moments ``keys`` need."""
        seg = self.spec.segments[self.i]
        ql, qdl = ca.SX.sym("qi", 3), ca.SX.sym("qdi", 3)
        zeta, w = ca.SX.sym("zeta"), ca.SX.sym("w")
        jet = Jet()
        _, p = kin.segment_pose(ql, seg.length, seg.actuator_radius, self.spec.parameterization,
                                zeta, jet)
        J = jet.jacobian(p, ql)
        pd = jet.jtimes(p, ql, qdl)
        pdd = jet.jtimes(pd, ql, qdl)
        wp, wJ = w * p, w * J
        values = {
            "P1": lambda: wp, "P2": lambda: wp @ p.T, "Q1": lambda: wJ,
            "Q2": lambda: ca.vertcat(*(wp[c] * J for c in range(3))),
            "Q3": lambda: wJ.T @ J, "D1": lambda: w * pd, "D2": lambda: wp @ pd.T,
            "A1": lambda: w * pdd, "A2": lambda: wp @ pdd.T,
            "Q4": lambda: ca.vertcat(*(pd[c] * wJ for c in range(3))),
            "A3": lambda: wJ.T @ pdd,
        }
        names = self.moment_names(keys)
        outs = jet.finalize([values[n]() for n in names])
        return ca.Function(name, [ql, qdl, zeta, w], outs, ["qi", "qdi", "zeta", "w"],
                           list(names), {"cse": True})

    def assemble_function(self, keys, name: str) -> ca.Function:
        """(moments..., base...) -> the blocks ``keys`` over the first 3 (i + 1) coordinates."""
        k, m, g = self.k, self.mass, self.g
        names = self.moment_names(keys)
        mom = {n: ca.SX.sym(n, *MOMENTS[n]) for n in names}
        base = {f: ca.SX.sym(f, *s) for f, s in kin.base_shapes(k).items()} if k else {}
        out = {}
        if not k:
            if "M" in keys:
                out["M"] = m * mom["Q3"]
            if "G" in keys:
                out["G"] = -m * (mom["Q1"].T @ g)
            if "Cqd" in keys:
                out["Cqd"] = m * mom["A3"]
        else:
            dt, Rb = base["dtb"], base["Rb"]
            Bc = [base["dRb"][3 * c : 3 * c + 3, :] for c in range(3)]
            if "P1" in mom:
                P1 = mom["P1"]
            if "M" in keys:
                P2, Q1, Q2, Q3 = mom["P2"], mom["Q1"], mom["Q2"], mom["Q3"]
                Mll = dt.T @ dt
                for c in range(3):
                    cross = dt.T @ Bc[c]
                    Mll = Mll + P1[c] * (cross + cross.T)
                # sum_ce P2_ce B_c^T B_e = sum_c B_c^T W_c with W_c = sum_e P2_ce B_e
                for c in range(3):
                    Mll = Mll + Bc[c].T @ (P2[c, 0] * Bc[0] + P2[c, 1] * Bc[1] + P2[c, 2] * Bc[2])
                Mli = dt.T @ Rb @ Q1
                for c in range(3):
                    Mli = Mli + Bc[c].T @ Rb @ Q2[3 * c : 3 * c + 3, :]
                out["M"] = m * ca.blockcat([[Mll, Mli], [Mli.T, Q3]])
            if "G" in keys:
                Gl = dt.T @ g
                for c in range(3):
                    Gl = Gl + P1[c] * (Bc[c].T @ g)
                out["G"] = -m * ca.vertcat(Gl, mom["Q1"].T @ (Rb.T @ g))
            if "Cqd" in keys:
                P2, Q1, Q2 = mom["P2"], mom["Q1"], mom["Q2"]
                D1, D2, A1, A2, Q4, A3 = (mom[n] for n in ("D1", "D2", "A1", "A2", "Q4", "A3"))
                tdd, Rd, Rdd = base["tbdd"], base["Rbd"], base["Rbdd"]
                Cl = dt.T @ (tdd + Rdd @ P1 + 2 * Rd @ D1 + Rb @ A1)
                for c in range(3):
                    Cl = Cl + Bc[c].T @ (tdd * P1[c] + Rdd @ P2[:, c] + 2 * Rd @ D2[c, :].T
                                         + Rb @ A2[c, :].T)
                X, Y = Rb.T @ Rdd, Rb.T @ Rd
                Ci = Q1.T @ (Rb.T @ tdd) + A3
                for c in range(3):
                    Ci = Ci + Q2[3 * c : 3 * c + 3, :].T @ X[:, c] \
                        + 2 * Q4[3 * c : 3 * c + 3, :].T @ Y[:, c]
                out["Cqd"] = m * ca.vertcat(Cl, Ci)
        ins = [mom[n] for n in names] + [base[f] for f in kin.BASE_FIELDS if f in base]
        in_names = list(names) + [f for f in kin.BASE_FIELDS if f in base]
        return ca.Function(name, ins, [ca.densify(out[key]) for key in keys], in_names,
                           list(keys), {"cse": True})
