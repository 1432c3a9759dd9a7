"""A known input matrix A(q) (the paper's first remedy for the ideal Lagrangian solution,
Section VI-B): fixed, never trained, so that A u pins the scale and frame of M, D and G in
eq. 6 (and eq. 7).

The known matrix travels in :class:`learn._model_config.ModelConfig` as data (``known_input``, JSON
text), so that a saved run rebuilds it from its ``config.json`` alone, without CasADi:

* ``{"kind": "constant", "value": [[...], ...]}``: a constant n x m matrix;
* ``{"kind": "program", "program": {...}}``: the exact A(q) of a symbolic model as CasADi's SX
  instruction list, written by :mod:`softpinn.bridge.exact.serialize` (format
  ``softpinn-program/1``: operation names, operand indices, constants, output sparsity),
  replayed in ``jax.numpy`` by :mod:`learn._sx_replay` with CasADi's semantics.

:class:`KnownMatrix` holds either as a static field: the optimizer sees no parameter in it.
"""

from __future__ import annotations

import json
import math
from typing import Any

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from softpinn.errors import UserError
from softpinn.learn._sx_replay import PROGRAM_FORMAT, check_program, run_program

__all__ = ["PROGRAM_FORMAT", "KnownMatrix", "known_input_text", "parse_known_input"]


def _program(data: Any, n: int, m: int) -> tuple:
    """The program data checked (:func:`learn._sx_replay.check_program`) and frozen: ``(code,
    (rows, cols, row, col))`` of a Function of q (nnz n) with one (n, m) output."""
    what = "known input program"
    if isinstance(data, dict) and isinstance(data.get("inputs"), list):
        ins = data["inputs"]
        if not (len(ins) == 1 and isinstance(ins[0], dict) and ins[0].get("nnz") == n):
            raise UserError(f"{what}: expected one input q of {n} values, got "
                            f"{[d.get('nnz') if isinstance(d, dict) else d for d in ins]}")
    code, _, outs = check_program(data, what)
    if len(outs) != 1:
        raise UserError(f"{what}: expected one output A(q)")
    rows, cols, row, col = outs[0]
    if (rows, cols) != (n, m):
        raise UserError(f"known input: A(q) is {rows} x {cols}, the model needs n x m = "
                        f"{n} x {m}")
    return (code, (n, m, row, col))


def parse_known_input(text: str, n: int, m: int) -> tuple[str, Any]:
    """``known_input`` text checked against n x m: ``("constant", rows)`` with rows a tuple of
    tuples of floats, or ``("program", frozen program)``. Mistakes raise a :class:`UserError`."""
    try:
        d = json.loads(text)
    except (TypeError, ValueError) as err:
        raise UserError(f"known_input must be JSON text, got {str(text)[:40]!r} ({err})") from None
    kind = d.get("kind") if isinstance(d, dict) else None
    if kind == "constant":
        v = d.get("value")
        try:
            rows = tuple(tuple(float(x) for x in r) for r in v)
        except (TypeError, ValueError):
            raise UserError("known input: 'value' must be an n x m list of numbers") from None
        shape = (len(rows), len(rows[0]) if rows else m)
        if shape != (n, m) or any(len(r) != m for r in rows):
            raise UserError(f"known input: the constant matrix is {shape[0]} x {shape[1]}, the "
                            f"model needs n x m = {n} x {m}")
        if not all(math.isfinite(x) for r in rows for x in r):
            raise UserError("known input: the constant matrix holds NaN or inf")
        return "constant", rows
    if kind == "program":
        return "program", _program(d.get("program"), n, m)
    raise UserError(f"known input: expected {{'kind': 'constant' | 'program', ...}}, got "
                    f"kind {kind!r}")


def known_input_text(value: Any) -> str:
    """Canonical ``known_input`` text of a constant matrix (an n x m array-like) or of program
    data (a dict of format ``softpinn-program/1``): compact JSON with sorted keys, so that
    equal matrices give equal configurations."""
    if isinstance(value, dict) and value.get("format") == PROGRAM_FORMAT:
        d = {"kind": "program", "program": value}
    else:
        a = np.asarray(value, dtype=np.float64)
        if a.ndim != 2:
            raise UserError(f"known input: expected an n x m matrix, got shape {a.shape}")
        d = {"kind": "constant", "value": a.tolist()}
    return json.dumps(d, sort_keys=True, separators=(",", ":"), allow_nan=False)


class KnownMatrix(eqx.Module):
    """A fixed input matrix A(q) (n x m): a constant or a replayed instruction program. Its
    data are a static field, so it has no parameters (nothing for the optimizer to move)."""

    kind: str = eqx.field(static=True)
    data: Any = eqx.field(static=True)
    shape: tuple[int, int] = eqx.field(static=True)

    def __init__(self, text: str, n: int, m: int):
        self.kind, self.data = parse_known_input(text, n, m)
        self.shape = (int(n), int(m))

    def to_data(self) -> dict[str, Any]:
        """The JSON-ready data this matrix was built from (``{"kind": "constant", "value"}``
        or ``{"kind": "program", "program"}``), e.g. for the CasADi exporter."""
        if self.kind == "constant":
            return {"kind": "constant", "value": [list(r) for r in self.data]}
        code, (rows, cols, row, col) = self.data

        def const(c):
            return c if c is None or math.isfinite(c) else str(c)

        return {"kind": "program", "program": {
            "format": PROGRAM_FORMAT, "name": "A", "inputs": [{"name": "q", "nnz": rows}],
            "outputs": [{"name": "A", "rows": rows, "cols": cols, "row": list(row),
                         "col": list(col)}],
            "code": [[op, list(i), list(o), const(c)] for op, i, o, c in code]}}

    def __call__(self, q):
        q = jnp.asarray(q)
        dtype = q.dtype if jnp.issubdtype(q.dtype, jnp.floating) else jnp.float64
        if self.kind == "constant":
            return jnp.asarray(self.data, dtype).reshape(self.shape)
        return self._replay(jnp.reshape(q, (-1,)).astype(dtype), dtype)

    def _replay(self, q, dtype):
        code, (rows, cols, row, col) = self.data
        return run_program((code, (rows,), ((rows, cols, row, col),)), [q], dtype)[0]
