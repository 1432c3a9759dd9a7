"""Learned against true matrices along one-dimensional sweeps of q through the data.

A scatter of entries (``scatter.png``) says how close the learned matrices are over all
configurations; a sweep says *where* they part: one coordinate runs over the range the
configurations cover while the others stay at their median, and the entries of M (or M⁻¹ for
a Hamiltonian model), D, G and A are drawn as curves, true solid and learned dashed. The learned
side is compared as the report's headline transform says: directly for a Hamiltonian model
(Table VII), through the one scalar α of Tables V-VI for a Lagrangian one (learned ≈ α true, so
``c = 1/α`` times the learned matrices; M⁻¹ scales by α).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from softpinn.bridge.analysis.matrices import MatrixStack

#: Points along each sweep, and the most coordinates swept (those the data move most).
POINTS = 41
MAX_COORDINATES = 3


@dataclass(frozen=True, eq=False)
class Sweep:
    """One coordinate swept: ``q`` (P, n) the points, ``values`` its values (P,), the true and
    the (scaled) learned matrices there."""

    coordinate: int
    name: str  # the coordinate's name with its unit, e.g. "theta1 [rad]"
    q: np.ndarray
    true: MatrixStack
    learned: MatrixStack

    @property
    def values(self) -> np.ndarray:
        return self.q[:, self.coordinate]

    def to_dict(self) -> dict[str, Any]:
        side = lambda s: {k: getattr(s, k) for k in s.present}  # noqa: E731
        return {"coordinate": self.coordinate, "name": self.name, "q": self.q,
                "true": side(self.true), "learned": side(self.learned)}


@dataclass(frozen=True, eq=False)
class Sweeps:
    """The sweeps of one analysis and how the learned side was put beside the true one."""

    sweeps: tuple[Sweep, ...]
    transform: str  # "direct" or "alpha"
    scale: float  # c: the learned matrices drawn are c times the learned ones (M⁻¹: 1/c)
    kind: str | None = None  # the learned model's kind: a Hamiltonian network learns M⁻¹

    @property
    def mass_key(self) -> str:
        """The mass-like matrix the network learns: M⁻¹ (Hamiltonian) or M."""
        return "M_inv" if self.kind == "hamiltonian" else "M"

    def to_dict(self) -> dict[str, Any]:
        return {"transform": self.transform, "scale": self.scale, "kind": self.kind,
                "sweeps": [s.to_dict() for s in self.sweeps]}


def sweep_points(q: np.ndarray, *, points: int = POINTS,
                 max_coordinates: int = MAX_COORDINATES) -> list[tuple[int, np.ndarray]]:
    """(coordinate, (points, n) configurations) for the coordinates the configurations ``q``
    (N, n) spread most over (none that never moves), in the coordinates' order, each running
    from its smallest to its largest value with the others at their median."""
    q = np.asarray(q, float)
    spread = np.ptp(q, axis=0)
    order = [int(j) for j in np.argsort(-spread, kind="stable") if spread[j] > 0]
    centre = np.median(q, axis=0)
    out = []
    for j in sorted(order[:max_coordinates]):  # the widest, in the coordinates' order
        line = np.repeat(centre[None, :], points, axis=0)
        line[:, j] = np.linspace(q[:, j].min(), q[:, j].max(), points)
        out.append((j, line))
    return out


def headline(kind: str | None, results: Mapping[str, Any]) -> tuple[str, float]:
    """The transform a report leads with and the scale c it puts on the learned matrices:
    ("direct", 1) for a Hamiltonian model or when α was not fitted, else ("alpha", 1/α)."""
    alpha = results.get("alpha")
    if kind == "hamiltonian" or alpha is None or not np.isfinite(alpha.scale_all or np.nan):
        return "direct", 1.0
    return "alpha", float(alpha.scale_all)


def scaled(stack: MatrixStack, c: float) -> MatrixStack:
    """``c`` times every matrix of the stack (M⁻¹ by 1/c): P X̂ for P = c I."""
    if c == 1.0:
        return stack
    out = {}
    for k in stack.present:
        v = np.asarray(getattr(stack, k), float)
        out[k] = v / c if k == "M_inv" else c * v
    return MatrixStack.from_mapping(out, name=stack.name)


def compute_sweeps(true_at: Callable[[np.ndarray], MatrixStack],
                   learned_at: Callable[[np.ndarray], MatrixStack], q: np.ndarray,
                   kind: str | None, results: Mapping[str, Any], *,
                   names: Sequence[str] | None = None, units: Sequence[str] | None = None,
                   points: int = POINTS) -> Sweeps | None:
    """Both models' matrices (``true_at(q)``, ``learned_at(q)`` for configurations (P, n))
    along :func:`sweep_points` of ``q``; None when no coordinate moves (a single
    configuration)."""
    lines = sweep_points(q, points=points)
    if not lines:
        return None
    transform, c = headline(kind, results)
    names = list(names) if names is not None else [f"q[{j}]" for j in range(q.shape[1])]
    units = list(units) if units is not None else [""] * len(names)
    sweeps = []
    for j, line in lines:
        label = f"{names[j]} [{units[j]}]" if units[j] else names[j]
        sweeps.append(Sweep(j, label, line, true_at(line), scaled(learned_at(line), c)))
    return Sweeps(tuple(sweeps), transform, c, kind)
