"""True and learned matrices stacked over a batch of configurations, checked.

:class:`MatrixStack` holds any of ``M``, ``M_inv``, ``D`` (N, n, n), ``G`` (N, n) and
``A`` (N, n, m) at the same N configurations q; the helpers check that two stacks (true and
learned) and a q batch fit together, choose the matrices both sides carry and weigh them for
the joint fits of :mod:`bridge.transforms`. Mistakes raise :class:`errors.UserError`
with the field, the expected and the received value. numpy only.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from softpinn.errors import UserError

#: Order of the blocks in the joint equation ``P [M^ D^ A^ G^] ~= [M D A G]``.
BLOCKS = ("M", "D", "A", "G")
#: Every matrix a stack may carry.
MATRICES = ("M", "M_inv", "D", "G", "A")
WEIGHTINGS = ("frobenius", "none")


def _as_float_array(x: Any, where: str) -> np.ndarray:
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise UserError(f"{where}: expected a numeric array, got {type(x).__name__}") from exc
    return a


@dataclass(frozen=True, eq=False)
class MatrixStack:
    """True or learned matrices at N configurations (any subset of :data:`MATRICES`).

    Shapes: ``M``, ``M_inv``, ``D``: (N, n, n); ``G``: (N, n); ``A``: (N, n, m). ``name`` is used
    in error messages (``"true"``, ``"learned"``).
    """

    M: np.ndarray | None = None
    M_inv: np.ndarray | None = None
    D: np.ndarray | None = None
    G: np.ndarray | None = None
    A: np.ndarray | None = None
    name: str = "matrices"

    def __post_init__(self):
        present = [k for k in MATRICES if getattr(self, k) is not None]
        if not present:
            raise UserError(f"{self.name}: no matrices given; expected some of {list(MATRICES)}")
        N = n = None
        for key in present:
            a = _as_float_array(getattr(self, key), f"{self.name}.{key}")
            want = 2 if key == "G" else 3
            if a.ndim != want:
                shape = "(N, n)" if key == "G" else "(N, n, m)" if key == "A" else "(N, n, n)"
                raise UserError(
                    f"{self.name}.{key}: expected shape {shape}, got {a.shape} ({a.ndim}-d)"
                )
            if N is None:
                N, n = a.shape[0], a.shape[1]
            if a.shape[0] != N:
                raise UserError(
                    f"{self.name}.{key}: expected N = {N} configurations (as {present[0]}), "
                    f"got {a.shape[0]}"
                )
            if a.shape[1] != n:
                raise UserError(
                    f"{self.name}.{key}: expected n = {n} rows (as {present[0]}), got {a.shape[1]}"
                )
            if key in ("M", "M_inv", "D") and a.shape[2] != n:
                raise UserError(f"{self.name}.{key}: expected square (N, {n}, {n}), got {a.shape}")
            if not np.all(np.isfinite(a)):
                raise UserError(f"{self.name}.{key}: contains NaN or inf")
            object.__setattr__(self, key, a)
        if N == 0:
            raise UserError(f"{self.name}: expected at least one configuration, got N = 0")

    @classmethod
    def from_mapping(cls, mapping: Mapping[str, Any], *, name: str = "matrices") -> MatrixStack:
        """Build from a dict such as ``model.matrices(q)`` batched; keys outside
        :data:`MATRICES` (``energy``, ``C``...) are ignored."""
        return cls(**{k: mapping[k] for k in MATRICES if mapping.get(k) is not None}, name=name)

    @property
    def present(self) -> tuple[str, ...]:
        return tuple(k for k in MATRICES if getattr(self, k) is not None)

    @property
    def N(self) -> int:
        return getattr(self, self.present[0]).shape[0]

    @property
    def n(self) -> int:
        return getattr(self, self.present[0]).shape[1]

    @property
    def m(self) -> int | None:
        return None if self.A is None else self.A.shape[2]

    def has(self, key: str) -> bool:
        """Whether matrix ``key`` is available (``M`` and ``M_inv`` stand in for each other)."""
        if key in ("M", "M_inv"):
            return self.M is not None or self.M_inv is not None
        return getattr(self, key) is not None

    def mass(self) -> np.ndarray:
        """M(q), solved from ``M_inv`` when only that was given."""
        if self.M is not None:
            return self.M
        return _batched_inverse(self.M_inv)

    def mass_inverse(self) -> np.ndarray:
        """M(q)^-1, solved from ``M`` when only that was given."""
        if self.M_inv is not None:
            return self.M_inv
        return _batched_inverse(self.M)

    def block(self, key: str) -> np.ndarray:
        """Matrix ``key`` as an (N, n, c) stack (``G`` as one column)."""
        if key == "M":
            return self.mass()
        if key == "M_inv":
            return self.mass_inverse()
        a = getattr(self, key)
        return a[:, :, None] if key == "G" else a


def as_stack(x: MatrixStack | Mapping[str, Any], name: str) -> MatrixStack:
    if isinstance(x, MatrixStack):
        return x
    if isinstance(x, Mapping):
        return MatrixStack.from_mapping(x, name=name)
    raise UserError(f"{name}: expected a MatrixStack or a dict of arrays, got {type(x).__name__}")


def _batched_inverse(a: np.ndarray) -> np.ndarray:
    eye = np.broadcast_to(np.eye(a.shape[-1]), a.shape)
    return np.linalg.solve(a, eye)


def check_pair(true: MatrixStack, learned: MatrixStack) -> None:
    """Both stacks at the same N configurations, with the same n (and m where both have A)."""
    if learned.n != true.n:
        raise UserError(
            f"learned matrices: n = {learned.n} coordinates does not match the true n = {true.n}"
        )
    if learned.N != true.N:
        raise UserError(
            f"learned matrices: N = {learned.N} configurations does not match the true "
            f"N = {true.N}; evaluate both at the same q"
        )
    if true.A is not None and learned.A is not None and true.m != learned.m:
        raise UserError(f"learned.A: m = {learned.m} inputs does not match the true m = {true.m}")


def check_q(q: Any, N: int, n: int) -> np.ndarray:
    """q as an (N, n) float array; a UserError names the expected and received shape."""
    a = _as_float_array(q, "q")
    if a.ndim == 1 and N == 1:
        a = a[None, :]
    if a.ndim != 2 or a.shape[1] != n:
        got = a.shape[-1] if a.ndim >= 1 else "a scalar"
        raise UserError(
            f"q: expected length n = {n} per configuration, got {got} (shape {a.shape})"
        )
    if a.shape[0] != N:
        raise UserError(f"q: expected N = {N} configurations (as the matrices), got {a.shape[0]}")
    if not np.all(np.isfinite(a)):
        raise UserError("q: contains NaN or inf")
    return a


def common_blocks(true: MatrixStack, learned: MatrixStack, blocks: Sequence[str] | None):
    """The blocks both sides carry (in :data:`BLOCKS` order), or the requested ones, checked."""
    if blocks is None:
        # a true block that is zero everywhere (D of an undamped system) carries no information
        # on P beyond P X̂ ≈ 0, and has no relative residual: it is left out unless requested
        out = tuple(
            k
            for k in BLOCKS
            if true.has(k)
            and learned.has(k)
            and true.block(k).shape[2] > 0
            and np.any(true.block(k) != 0)
        )
        if not out:
            raise UserError(
                f"no matrix is given on both sides: true has {list(true.present)}, "
                f"learned has {list(learned.present)}"
            )
        return out
    if isinstance(blocks, str):
        blocks = (blocks,)
    for k in blocks:
        if k not in BLOCKS:
            raise UserError(f"blocks: unknown matrix {k!r}; expected some of {list(BLOCKS)}")
        for side in (true, learned):
            if not side.has(k):
                raise UserError(f"blocks: {k} requested but {side.name} has {list(side.present)}")
    if not blocks:
        raise UserError(f"blocks: expected at least one of {list(BLOCKS)}, got none")
    return tuple(blocks)


def block_weights(
    true: MatrixStack,
    learned: MatrixStack,
    blocks: Sequence[str],
    weighting: str | Mapping[str, float],
) -> dict[str, float]:
    """Weight of each block in a joint fit.

    ``"frobenius"`` (default) divides each block by the Frobenius norm of the true block over
    all q, so that a small matrix (Task 4's M ~ 1e-3) weighs as much as a large one (G ~ 1);
    ``"none"`` weighs every entry alike; a dict gives explicit weights.
    """
    if isinstance(weighting, Mapping):
        w = {}
        for k in blocks:
            if k not in weighting:
                raise UserError(f"weighting: no weight for {k}; got keys {sorted(weighting)}")
            v = float(weighting[k])
            if not (math.isfinite(v) and v > 0):
                raise UserError(f"weighting[{k!r}]: expected a positive number, got {v}")
            w[k] = v
        return w
    if weighting == "none":
        return {k: 1.0 for k in blocks}
    if weighting == "frobenius":
        w = {}
        for k in blocks:
            norm = float(np.linalg.norm(true.block(k)))
            if norm == 0.0:
                norm = float(np.linalg.norm(learned.block(k)))
            w[k] = 1.0 / norm if norm > 0.0 else 1.0
        return w
    raise UserError(
        f"weighting: expected one of {list(WEIGHTINGS)} or a dict of weights, got {weighting!r}"
    )


def stacked_blocks(side: MatrixStack, blocks, weights, rows: slice | np.ndarray = slice(None)):
    """``[w_M M, w_D D, w_A A, w_G G]`` side by side: (N, n, sum of the blocks' columns)."""
    return np.concatenate([weights[k] * side.block(k)[rows] for k in blocks], axis=2)


def subset(side: MatrixStack, mask: np.ndarray) -> MatrixStack:
    """The stack at the configurations selected by a boolean mask (or index array)."""
    return MatrixStack(
        **{k: getattr(side, k)[mask] for k in side.present},
        name=side.name,
    )
