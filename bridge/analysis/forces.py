"""Learned against true generalized forces along trajectory data.

The matrices of :mod:`bridge.analysis` are compared at configurations q alone. What the
training data see is their action on the data's own velocities and inputs: the potential
force ``G(q) = ∂V/∂q``, the damping force ``D(q) q̇`` (eq. 4), the input force ``A(q) u``
(eq. 5) and the net force ``A u − G − D q̇``: eq. 1's generalized force Q less the potential
force, all that moves the arm beside its inertia (eqs. 6 and 7 carry the same terms).
:func:`compare_forces` evaluates these four at data samples for both models and reports the
relative error of each.

Why: when the data excite two terms together, say inputs that hold the arm near equilibrium so
that ``A u ≈ G`` all along, the one-step losses of eqs. 8-9 fix their difference far better
than either term, and a network can carry a shared error in G and A that its loss barely sees.
``cancellation`` measures this: ``‖e_net‖ / sqrt(Σ ‖e_term‖²)``, the net force's error against
the terms' errors added as if independent. Near 1 the errors are unrelated; near 0 they cancel
along the data, and the terms are not separately determined by these data.

For a Hamiltonian network (eq. 7) the learned terms are compared directly; for a Lagrangian one
(eq. 6) learned ≈ α true (Tables V, VI), so the learned terms are divided by the fitted α
(``scale = 1/α``).

The same comparison in the ``"acceleration"`` frame multiplies every term by M(q)⁻¹ first:
``M⁻¹G``, ``M⁻¹D q̇``, ``M⁻¹A u`` and ``M⁻¹(A u − G − D q̇)``, the accelerations each force
gives. These need no transform: a Lagrangian network whose matrices are the true ones through
any invertible P(q) (``M = P M̂``, ``D = P D̂``, ``G = P Ĝ``, ``A = P Â``; Section IV, Tables I
and VIII) has ``M̂⁻¹X̂ = M⁻¹X`` for each of them, so they compare every model with the truth
where no scalar α fits, as in Tasks 4 and 5. numpy only; the matrices come from
:mod:`bridge.analysis`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from softpinn.bridge.analysis.matrices import MatrixStack, check_pair
from softpinn.errors import UserError

#: The force terms in report order; ``net = A u − G − D q̇``.
TERMS = ("G", "D_qd", "A_u", "net")
LABELS = {"G": "G", "D_qd": "D q̇", "A_u": "A u", "net": "A u − G − D q̇"}
#: ``"force"``: the terms as they are; ``"acceleration"``: each multiplied by M(q)⁻¹.
FRAMES = ("force", "acceleration")
FRAME_LABELS = {
    "force": LABELS,
    "acceleration": {"G": "M⁻¹G", "D_qd": "M⁻¹D q̇", "A_u": "M⁻¹A u",
                     "net": "M⁻¹(A u − G − D q̇)", "qdd": "q̈ (C q̇ too)"},
}  # fmt: skip


@dataclass(frozen=True, eq=False)
class ForceComparison:
    """What :func:`compare_forces` found over ``samples`` data samples.

    Attributes:
        samples: the number of (q, q̇, u) samples.
        frame: ``"force"`` or ``"acceleration"`` (every term multiplied by M(q)⁻¹).
        scale: the learned terms were multiplied by this before comparing (1, or 1/α).
        rms: per term, the root-mean-square norm of the true force over the samples.
        error: per term, ``‖scale F̂ − F‖ / ‖F‖`` over all samples (None where ``F = 0``).
        cancellation: ``‖e_net‖ / sqrt(Σ_terms ‖e_term‖²)`` (None when every term is exact to
            round-off, 1e-12 relative).
        alignment: cosine between the true ``G`` and ``A u`` stacked over the samples: near 1
            when the inputs hold the arm near equilibrium (None without inputs).
        message: one line saying what the numbers mean.
        meta: where the samples came from (data file, trajectories, seed).
        qdd_per_coordinate: with ``"qdd"``, its relative error in each coordinate of q: a
            small overall error can hide a large one in a coordinate of small accelerations.
        terms: per term, the true and the scaled learned force at each sample, (N, n) each
            (for plots; not in :meth:`to_dict`). In the acceleration frame, ``"qdd"`` (the
            whole q̈) when the models gave it; it is not counted in ``cancellation``.
    """

    samples: int
    scale: float
    rms: dict[str, float]
    error: dict[str, float | None]
    cancellation: float | None
    alignment: float | None
    message: str
    meta: dict[str, Any] = field(default_factory=dict)
    frame: str = "force"
    qdd_per_coordinate: list[float | None] | None = None
    terms: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict, repr=False)

    def to_dict(self) -> dict[str, Any]:
        return {
            "samples": self.samples,
            "frame": self.frame,
            "scale": self.scale,
            "rms": dict(self.rms),
            "error": dict(self.error),
            "cancellation": self.cancellation,
            "alignment": self.alignment,
            "message": self.message,
            "meta": dict(self.meta),
            "qdd_per_coordinate": self.qdd_per_coordinate,
        }


def force_terms(
    stack: MatrixStack, qd: np.ndarray, u: np.ndarray | None, frame: str = "force"
) -> dict[str, np.ndarray]:
    """``G``, ``D q̇``, ``A u`` and the net force ``A u − G − D q̇`` at each sample, (N, n) each.
    A matrix the stack lacks (no D, or no inputs) contributes zero. In the ``"acceleration"``
    frame each is multiplied by the stack's M(q)⁻¹ (the stack needs ``M`` or ``M_inv``)."""
    if frame not in FRAMES:
        raise UserError(f"frame: expected one of {list(FRAMES)}, got {frame!r}")
    if frame == "acceleration":
        if not stack.has("M"):
            raise UserError(f"frame: the acceleration frame needs {stack.name}.M or M_inv")
        Minv = stack.mass_inverse()
        return {k: np.einsum("kij,kj->ki", Minv, v) for k, v in force_terms(stack, qd, u).items()}
    zero = np.zeros((stack.N, stack.n))
    G = stack.G if stack.G is not None else zero
    Dq = np.einsum("kij,kj->ki", stack.D, qd) if stack.D is not None else zero
    if stack.A is not None and u is not None and u.shape[1] > 0:
        Au = np.einsum("kij,kj->ki", stack.A, u)
    else:
        Au = zero
    return {"G": G, "D_qd": Dq, "A_u": Au, "net": Au - G - Dq}


def compare_forces(
    true: MatrixStack,
    learned: MatrixStack,
    qd: Any,
    u: Any = None,
    *,
    scale: float = 1.0,
    frame: str = "force",
    qdd: tuple[Any, Any] | None = None,
    meta: dict[str, Any] | None = None,
) -> ForceComparison:
    """Compare the force terms of two stacks evaluated at the same N data configurations, with
    the samples' velocities ``qd`` (N, n) and inputs ``u`` (N, m) (None or m = 0: no inputs).
    ``scale`` multiplies the learned terms (1 for a Hamiltonian network, 1/α for a Lagrangian
    one). ``frame="acceleration"`` compares ``M⁻¹`` times each term instead, which any P(q)
    relating the two models leaves alone (use ``scale=1`` there); ``qdd``, the true and the
    learned q̈ (N, n) each at the samples, adds the whole acceleration, Coriolis and
    centrifugal terms included, as the term ``"qdd"`` (acceleration frame only)."""
    check_pair(true, learned)
    N, n = true.N, true.n
    qd = _samples(qd, "qd", N, n)
    m = true.m if true.A is not None else 0
    if u is not None:
        u = _samples(u, "u", N, m)
    if not np.isfinite(scale) or scale == 0:
        raise UserError(f"scale: expected a finite non-zero number, got {scale}")
    ft, fl = force_terms(true, qd, u, frame), force_terms(learned, qd, u, frame)
    if qdd is not None:
        if frame != "acceleration":
            raise UserError("qdd: the whole acceleration is compared in the acceleration frame")
        ft["qdd"], fl["qdd"] = (_samples(a, f"qdd[{i}]", N, n) for i, a in enumerate(qdd))
    err, rms, e2, terms = {}, {}, {}, {}
    for key in ft:
        e = scale * fl[key] - ft[key]
        norm = float(np.linalg.norm(ft[key]))
        e2[key] = float(np.sum(e * e))
        rms[key] = float(np.sqrt(np.mean(np.sum(ft[key] ** 2, axis=1))))
        err[key] = float(np.sqrt(e2[key]) / norm) if norm > 0 else None
        terms[key] = (ft[key], scale * fl[key])
    per_coord = None
    if qdd is not None:
        tq, lq = terms["qdd"]
        per_coord = [float(a / b) if b > 0 else None
                     for a, b in zip(np.linalg.norm(lq - tq, axis=0), np.linalg.norm(tq, axis=0),
                                     strict=True)]  # fmt: skip
    parts = e2["G"] + e2["D_qd"] + e2["A_u"]
    # errors at round-off (relative 1e-12 of the terms) say nothing about cancelling
    size = sum(float(np.sum(ft[k] ** 2)) for k in ("G", "D_qd", "A_u"))
    cancellation = float(np.sqrt(e2["net"] / parts)) if parts > 1e-24 * size else None
    g, au = ft["G"].ravel(), ft["A_u"].ravel()
    den = float(np.linalg.norm(g) * np.linalg.norm(au))
    alignment = float(g @ au / den) if den > 0 else None
    return ForceComparison(
        samples=N, scale=float(scale), rms=rms, error=err, cancellation=cancellation,
        alignment=alignment, message=_message(cancellation, alignment, frame),
        meta=dict(meta or {}), frame=frame, qdd_per_coordinate=per_coord, terms=terms,
    )  # fmt: skip


def _samples(x: Any, name: str, N: int, cols: int) -> np.ndarray:
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise UserError(f"{name}: expected a numeric array, got {type(x).__name__}") from exc
    if a.shape != (N, cols):
        raise UserError(f"{name}: expected shape ({N}, {cols}) (one row per sample), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise UserError(f"{name}: contains NaN or inf")
    return a


def _message(cancellation, alignment, frame: str = "force") -> str:
    what = "force" if frame == "force" else "acceleration"
    G, Au = FRAME_LABELS[frame]["G"], FRAME_LABELS[frame]["A_u"]
    if cancellation is None:
        return f"every {what} term matches the true one exactly along the data"
    if cancellation >= 0.5:
        return (
            "the terms' errors do not cancel along the data: the data determine each term about "
            "as well as their sum"
        )
    line = (
        f"the terms' errors cancel along the data: the net {what}'s error is {cancellation:.2f} "
        "of what the terms' errors add up to if unrelated, so these data fix the sum better "
        "than each term"
    )
    if alignment is not None and alignment > 0.9:
        line += (
            f"; the true {G} and {Au} are aligned ({alignment:.2f}): the inputs hold the arm near "
            "equilibrium, so G and A can share an error the loss barely sees"
        )
    return line


def data_samples(
    data: Any, trajectories: Any = None, *, count: int = 2000, seed: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
    """Up to ``count`` samples (q, q̇, u) drawn without replacement (seeded) from the given
    trajectories of a :class:`learn._data.Dataset` (None: all); returns them and a meta dict."""
    if count < 1:
        raise UserError(f"samples: expected a positive count, got {count}")
    ids = np.unique(data.traj) if trajectories is None else np.asarray(trajectories, int)
    missing = sorted(set(ids.tolist()) - set(np.unique(data.traj).tolist()))
    if missing:
        raise UserError(f"trajectories: {missing} are not in the data set {data.path}")
    pool = np.flatnonzero(np.isin(data.traj, ids))
    rng = np.random.default_rng(seed)
    idx = np.sort(rng.choice(pool, size=min(count, len(pool)), replace=False))
    meta = {"data": str(data.path), "sha256": data.sha256, "trajectories": ids.tolist(),
            "pool": int(len(pool)), "seed": seed}
    return data.q[idx], data.qd[idx], data.u[idx], meta


def markdown_lines(d: dict[str, Any] | None, *, heading: str | None = "") -> list[str]:
    """Report lines for a :meth:`ForceComparison.to_dict` (as stored in ``analysis.json``),
    under ``heading`` (``""``: "## Forces along the data" or "## Accelerations along the
    data" by the comparison's frame; None: no heading)."""
    if not d:
        return []
    frame = d.get("frame", "force")
    labels = FRAME_LABELS[frame]
    if heading == "":
        heading = "## Forces along the data" if frame == "force" else (
            "## Accelerations along the data")
    meta = d.get("meta", {})
    where = f" of `{Path(meta['data']).name}`" if meta.get("data") else ""
    traj = meta.get("trajectories")
    if traj:
        where += f" (trajectories {_ranges(traj)})"
    scaled = "" if d["scale"] == 1 else f"; learned terms × {d['scale']:.4g} (1/α)"
    what = "Force terms" if frame == "force" else (
        "Acceleration terms (M(q)⁻¹ times each force: the same for a learned model whose "
        "matrices are the true ones through any P(q))")
    lines = [heading, ""] if heading else []
    lines += [
        f"{what} along {d['samples']} data samples{where}{scaled}; relative error "
        "‖F̂ − F‖/‖F‖ over all of them:",
        "", f"| {frame} | true rms | relative error |", "|---|---|---|",
    ]  # fmt: skip
    for key in TERMS + (("qdd",) if "qdd" in d["error"] else ()):
        e = d["error"].get(key)
        cell = "—" if e is None else f"{100 * e:.3g} %"
        lines.append(f"| {labels[key]} | {d['rms'][key]:.3g} | {cell} |")
    coords = d.get("qdd_per_coordinate")
    if coords:
        cells = ", ".join("—" if e is None else f"{100 * e:.3g} %" for e in coords)
        lines += ["", f"q̈'s relative error per coordinate of q: {cells}."]
    c, a = d.get("cancellation"), d.get("alignment")
    extra = [f"cancellation ‖e_net‖/√Σ‖e_term‖² = {c:.3g}" if c is not None else None,
             f"alignment of the true {labels['G']} and {labels['A_u']} = {a:.3g}"
             if a is not None else None]
    extra = [x for x in extra if x]
    lines += ["", (("; ".join(extra) + ". ") if extra else "") + d["message"][0].upper()
              + d["message"][1:] + ".", ""]
    return lines


def _ranges(ids) -> str:
    ids = sorted(int(i) for i in ids)
    out, start = [], ids[0]
    for a, b in zip(ids, ids[1:] + [None], strict=True):
        if b != a + 1:
            out.append(f"{start}" if start == a else f"{start}-{a}")
            start = b
    return ", ".join(out)
