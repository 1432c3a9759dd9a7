"""The backbone curve of a PCC arm: points along every segment for a configuration q, from the
kinematics of eqs. 13-14 (spatial, chained segment frames) and eq. 27 (planar).

``backbone(spec)`` is a CasADi Function ``q -> P`` with ``P`` of shape (dim, K): dim 3 for a
spatial arm (world frame of eq. 14), 2 for a planar one; column 0 is the base, the last column
the tip, ``points_per_segment`` columns per segment after the base. ``backbone_points`` evaluates
it on many configurations at once.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from softpinn.errors import UserError
from softpinn.symbolic.derivation._kinematics import planar_plate, spatial_plate
from softpinn.symbolic.spec._model_spec import ModelSpec

PCC_KINDS = ("planar-pcc", "spatial-pcc")


def backbone(spec: ModelSpec, points_per_segment: int = 16) -> ca.Function:
    """The backbone Function of ``spec`` (see the module); only PCC arms have one."""
    if spec.kind not in PCC_KINDS:
        raise UserError(f"model: {spec.name} is a {spec.kind}, not a PCC arm: it has no backbone "
                        "to draw")
    if not (isinstance(points_per_segment, int) and points_per_segment >= 1):
        raise UserError(f"points_per_segment: expected an integer >= 1, got "
                        f"{points_per_segment!r}")
    q = ca.SX.sym("q", spec.n)
    zetas = np.linspace(0.0, 1.0, points_per_segment + 1)[1:]
    if spec.kind == "planar-pcc":
        cols = [ca.SX.zeros(2, 1)]
        cols += [planar_plate(spec, q, i, float(z)) for i in range(len(spec.segments))
                 for z in zetas]
    else:
        cols = [ca.SX.zeros(3, 1)]
        cols += [spatial_plate(spec, q, i, float(z))[1] for i in range(len(spec.segments))
                 for z in zetas]
    return ca.Function("backbone", [q], [ca.horzcat(*cols)], ["q"], ["points"])


def backbone_points(spec: ModelSpec, q, points_per_segment: int = 16) -> np.ndarray:
    """Backbone points of configurations ``q`` (n,) or (T, n): (dim, K) or (T, dim, K)."""
    q = np.asarray(q, dtype=float)
    single = q.ndim == 1
    q2 = np.atleast_2d(q)
    if q2.ndim != 2 or q2.shape[1] != spec.n:
        raise UserError(f"q: expected {spec.n} numbers per configuration for {spec.name}, got "
                        f"shape {q.shape}")
    if not np.all(np.isfinite(q2)):
        raise UserError("q: holds NaN or inf")
    f = backbone(spec, points_per_segment)
    out = np.asarray(f.map(len(q2))(q2.T))  # (dim, K * T)
    dim, k = f.size_out(0)
    pts = out.reshape(dim, len(q2), k).transpose(1, 0, 2)
    return pts[0] if single else pts
