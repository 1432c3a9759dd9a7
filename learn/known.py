"""A known input matrix A(q) (the paper's first remedy for the ideal Lagrangian solution,
Section VI-B): fixed, never trained, so that A u pins the scale and frame of M, D and G in
eq. 6 (and eq. 7).

The known matrix travels in :class:`learn.model_config.ModelConfig` as data (``known_input``, JSON
text), so that a saved run rebuilds it from its ``config.json`` alone, without CasADi:

* ``{"kind": "constant", "value": [[...], ...]}``: a constant n x m matrix;
* ``{"kind": "program", "program": {...}}``: the exact A(q) of a symbolic model as CasADi's SX
  instruction list, written by :mod:`softpinn.bridge.exact.serialize` (format
  ``softpinn-program/1``: operation names, operand indices, constants, output sparsity),
  replayed here in ``jax.numpy`` with CasADi's semantics (those of
  :mod:`softpinn.bridge.exact.translate`).

:class:`KnownMatrix` holds either as a static field: the optimizer sees no parameter in it.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax.numpy as jnp
from jax import lax

from .errors import UserError

__all__ = ["PROGRAM_FORMAT", "KnownMatrix", "known_input_text", "parse_known_input"]

PROGRAM_FORMAT = "softpinn-program/1"

_UNARY: dict[str, Callable] = {
    "ASSIGN": lambda x: x, "NEG": lambda x: -x, "EXP": jnp.exp, "LOG": jnp.log,
    "SQRT": jnp.sqrt, "SQ": lambda x: x * x, "TWICE": lambda x: x + x, "SIN": jnp.sin,
    "COS": jnp.cos, "TAN": jnp.tan, "ASIN": jnp.arcsin, "ACOS": jnp.arccos, "ATAN": jnp.arctan,
    "FLOOR": jnp.floor, "CEIL": jnp.ceil, "FABS": jnp.abs, "SIGN": jnp.sign, "ERF": lax.erf,
    "INV": lambda x: 1.0 / x, "SINH": jnp.sinh, "COSH": jnp.cosh, "TANH": jnp.tanh,
    "ASINH": jnp.arcsinh, "ACOSH": jnp.arccosh, "ATANH": jnp.arctanh, "LOG1P": jnp.log1p,
    "EXPM1": jnp.expm1, "ERFINV": lax.erf_inv,
}
_BINARY: dict[str, Callable] = {
    "ADD": lambda x, y: x + y, "SUB": lambda x, y: x - y, "MUL": lambda x, y: x * y,
    "DIV": lambda x, y: x / y, "POW": jnp.power, "CONSTPOW": jnp.power, "ATAN2": jnp.arctan2,
    "FMIN": jnp.minimum, "FMAX": jnp.maximum, "FMOD": jnp.fmod,
    "REMAINDER": lambda x, y: x - y * jnp.round(x / y), "COPYSIGN": jnp.copysign,
    "HYPOT": jnp.hypot,
}
_COMPARE: dict[str, Callable] = {
    "LT": lambda x, y: x < y, "LE": lambda x, y: x <= y, "EQ": lambda x, y: x == y,
    "NE": lambda x, y: x != y, "AND": lambda x, y: (x != 0) & (y != 0),
    "OR": lambda x, y: (x != 0) | (y != 0),
}
_OTHER = {"CONST", "INPUT", "OUTPUT", "NOT", "IF_ELSE_ZERO"}
_KNOWN_OPS = set(_UNARY) | set(_BINARY) | set(_COMPARE) | _OTHER


def _const(c) -> float:
    if isinstance(c, str) and c in ("inf", "-inf", "nan"):
        return float(c)
    if isinstance(c, bool) or not isinstance(c, int | float):
        raise UserError(f"known input program: a CONST must be a number, got {c!r}")
    return float(c)


def _int_list(x, what: str) -> tuple[int, ...]:
    if not isinstance(x, list | tuple) or not all(
            isinstance(k, int) and not isinstance(k, bool) and k >= 0 for k in x):
        raise UserError(f"known input program: {what} must be a list of indices >= 0, got {x!r}")
    return tuple(x)


def _program(data: Any, n: int, m: int) -> tuple:
    """The program data checked and frozen into nested tuples (hashable, a static field):
    ``(code, (rows, cols, row, col))`` of a Function of q (nnz n) with one (n, m) output."""
    if not isinstance(data, dict) or data.get("format") != PROGRAM_FORMAT:
        raise UserError(f"known input program: expected program data of format "
                        f"{PROGRAM_FORMAT!r} (bridge.exact.serialize)")
    ins, outs, code = data.get("inputs"), data.get("outputs"), data.get("code")
    if not (isinstance(ins, list) and len(ins) == 1 and isinstance(ins[0], dict)
            and ins[0].get("nnz") == n):
        raise UserError(f"known input program: expected one input q of {n} values, got "
                        f"{[d.get('nnz') if isinstance(d, dict) else d for d in ins or []]}")
    if not (isinstance(outs, list) and len(outs) == 1 and isinstance(outs[0], dict)):
        raise UserError("known input program: expected one output A(q)")
    o = outs[0]
    if (o.get("rows"), o.get("cols")) != (n, m):
        raise UserError(f"known input: A(q) is {o.get('rows')} x {o.get('cols')}, the model "
                        f"needs n x m = {n} x {m}")
    row, col = _int_list(o.get("row"), "output rows"), _int_list(o.get("col"), "output cols")
    if len(row) != len(col) or any(r >= n for r in row) or any(c >= m for c in col):
        raise UserError("known input program: output sparsity out of range")
    if not isinstance(code, list):
        raise UserError("known input program: 'code' must be a list of instructions")
    frozen, nnz = [], len(row)
    defined: set[int] = set()
    for k, ins_ in enumerate(code):
        if not (isinstance(ins_, list | tuple) and len(ins_) == 4):
            raise UserError(f"known input program: instruction {k} must be [op, in, out, const]")
        op, i, out, c = ins_
        if op not in _KNOWN_OPS:
            raise UserError(f"known input program: instruction {k}: unknown operation {op!r}")
        i, out = _int_list(i, f"instruction {k} operands"), _int_list(out, f"instruction {k} "
                                                                          "results")
        if op == "INPUT":
            bad = len(i) != 2 or i[0] != 0 or i[1] >= n
        elif op == "OUTPUT":
            bad = len(out) != 2 or out[0] != 0 or out[1] >= nnz or i[0] not in defined
        else:
            arity = 0 if op == "CONST" else (1 if op in _UNARY or op == "NOT" else 2)
            bad = len(i) < arity or any(s not in defined for s in i[:arity]) or not out
        if bad:
            raise UserError(f"known input program: instruction {k} ({op}) has bad indices")
        if op != "OUTPUT":
            defined.add(out[0])
        frozen.append((op, i, out, _const(c) if op == "CONST" else None))
    return (tuple(frozen), (n, m, row, col))


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
        import numpy as np

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
        one, zero = jnp.asarray(1.0, dtype), jnp.asarray(0.0, dtype)
        outs = [zero] * len(row)
        w: dict[int, Any] = {}
        for op, i, o, c in code:
            if op in _BINARY:
                w[o[0]] = _BINARY[op](w[i[0]], w[i[1]])
            elif op in _UNARY:
                w[o[0]] = _UNARY[op](w[i[0]])
            elif op == "CONST":
                w[o[0]] = c
            elif op == "INPUT":
                w[o[0]] = q[i[1]]
            elif op == "OUTPUT":
                outs[o[1]] = w[i[0]]
            elif op in _COMPARE:
                w[o[0]] = jnp.where(_COMPARE[op](w[i[0]], w[i[1]]), one, zero)
            elif op == "NOT":
                w[o[0]] = jnp.where(w[i[0]] == 0, one, zero)
            else:  # IF_ELSE_ZERO
                w[o[0]] = jnp.where(w[i[0]] != 0, w[i[1]], zero)
        out = jnp.zeros((rows, cols), dtype)
        if row:
            vals = jnp.stack([jnp.asarray(v, dtype) for v in outs])
            out = out.at[jnp.asarray(row), jnp.asarray(col)].set(vals)
        return out
