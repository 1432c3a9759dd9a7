"""CasADi SX instruction lists replayed in ``jax.numpy``, without CasADi.

:mod:`softpinn.bridge.exact.serialize` writes any SX Function of a symbolic model (the forward
dynamics of eq. 4, M, G, A, ...) as data of format ``softpinn-program/1``: operation names,
operand and result indices, constants, and each output's sparsity. This module replays such
data with the semantics of CasADi's generated C (comparisons give 1.0 or 0.0,
``if_else_zero``, ``fmod``, ``remainder``; :func:`replay` is also what
:mod:`softpinn.bridge.exact.translate` runs), so that the exact model runs where CasADi is not
installed: a run's known input matrix (:mod:`learn._known_input`), or a GPU machine
(``benchmarks/bench_gpu.py``). Under ``jax.vmap`` each scalar instruction becomes one vector
operation over the batch; ``jit``, ``grad`` and float32 work as for any JAX function.

    f = ProgramFunction(json.load(open("qdd.json")))
    qdd = jax.jit(jax.vmap(f))(q, qd, u)[0]     # (N, n): the first output, dense
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import jax.numpy as jnp
from jax import lax

from softpinn.errors import UserError

__all__ = ["KNOWN_OPS", "PROGRAM_FORMAT", "ProgramFunction", "check_program", "replay",
           "run_program"]

PROGRAM_FORMAT = "softpinn-program/1"

UNARY: dict[str, Callable] = {
    "ASSIGN": lambda x: x, "NEG": lambda x: -x, "EXP": jnp.exp, "LOG": jnp.log,
    "SQRT": jnp.sqrt, "SQ": lambda x: x * x, "TWICE": lambda x: x + x, "SIN": jnp.sin,
    "COS": jnp.cos, "TAN": jnp.tan, "ASIN": jnp.arcsin, "ACOS": jnp.arccos, "ATAN": jnp.arctan,
    "FLOOR": jnp.floor, "CEIL": jnp.ceil, "FABS": jnp.abs, "SIGN": jnp.sign, "ERF": lax.erf,
    "INV": lambda x: 1.0 / x, "SINH": jnp.sinh, "COSH": jnp.cosh, "TANH": jnp.tanh,
    "ASINH": jnp.arcsinh, "ACOSH": jnp.arccosh, "ATANH": jnp.arctanh, "LOG1P": jnp.log1p,
    "EXPM1": jnp.expm1, "ERFINV": lax.erf_inv,
}
BINARY: dict[str, Callable] = {
    "ADD": lambda x, y: x + y, "SUB": lambda x, y: x - y, "MUL": lambda x, y: x * y,
    "DIV": lambda x, y: x / y, "POW": jnp.power, "CONSTPOW": jnp.power, "ATAN2": jnp.arctan2,
    "FMIN": jnp.minimum, "FMAX": jnp.maximum, "FMOD": jnp.fmod,
    "REMAINDER": lambda x, y: x - y * jnp.round(x / y), "COPYSIGN": jnp.copysign,
    "HYPOT": jnp.hypot,
}
COMPARE: dict[str, Callable] = {
    "LT": lambda x, y: x < y, "LE": lambda x, y: x <= y, "EQ": lambda x, y: x == y,
    "NE": lambda x, y: x != y, "AND": lambda x, y: (x != 0) & (y != 0),
    "OR": lambda x, y: (x != 0) | (y != 0),
}
_OTHER = {"CONST", "INPUT", "OUTPUT", "NOT", "IF_ELSE_ZERO"}
KNOWN_OPS = set(UNARY) | set(BINARY) | set(COMPARE) | _OTHER


def _const(c, what: str) -> float:
    if isinstance(c, str) and c in ("inf", "-inf", "nan"):
        return float(c)
    if isinstance(c, bool) or not isinstance(c, int | float):
        raise UserError(f"{what}: a CONST must be a number, got {c!r}")
    return float(c)


def _int_list(x, what: str) -> tuple[int, ...]:
    if not isinstance(x, list | tuple) or not all(
            isinstance(k, int) and not isinstance(k, bool) and k >= 0 for k in x):
        raise UserError(f"{what} must be a list of indices >= 0, got {x!r}")
    return tuple(x)


def check_program(data: Any, what: str = "program") -> tuple:
    """The program data checked and frozen into nested tuples (hashable, fit for a static
    field): ``(code, inputs, outputs)`` with ``inputs`` the nonzero count of each input and
    ``outputs`` ``(rows, cols, row, col)`` of each output. Mistakes raise a :class:`UserError`
    whose message starts with ``what``."""
    if not isinstance(data, dict) or data.get("format") != PROGRAM_FORMAT:
        raise UserError(f"{what}: expected program data of format {PROGRAM_FORMAT!r} "
                        "(bridge.exact.serialize)")
    ins, outs, code = data.get("inputs"), data.get("outputs"), data.get("code")
    if not (isinstance(ins, list) and all(isinstance(d, dict) for d in ins)):
        raise UserError(f"{what}: 'inputs' must be a list of {{'name', 'nnz'}}")
    nnz_in = tuple(_int_list([d.get("nnz")], f"{what}: an input's nnz")[0] for d in ins)
    if not (isinstance(outs, list) and all(isinstance(d, dict) for d in outs)):
        raise UserError(f"{what}: 'outputs' must be a list of {{'rows', 'cols', 'row', 'col'}}")
    shapes = []
    for o in outs:
        rows, cols = _int_list([o.get("rows"), o.get("cols")], f"{what}: an output's size")
        row = _int_list(o.get("row"), f"{what}: output rows")
        col = _int_list(o.get("col"), f"{what}: output cols")
        if len(row) != len(col) or any(r >= rows for r in row) or any(c >= cols for c in col):
            raise UserError(f"{what}: output sparsity out of range")
        shapes.append((rows, cols, row, col))
    if not isinstance(code, list):
        raise UserError(f"{what}: 'code' must be a list of instructions")
    frozen = []
    defined: set[int] = set()
    for k, ins_ in enumerate(code):
        if not (isinstance(ins_, list | tuple) and len(ins_) == 4):
            raise UserError(f"{what}: instruction {k} must be [op, in, out, const]")
        op, i, out, c = ins_
        if op not in KNOWN_OPS:
            raise UserError(f"{what}: instruction {k}: unknown operation {op!r}")
        i = _int_list(i, f"{what}: instruction {k} operands")
        out = _int_list(out, f"{what}: instruction {k} results")
        if op == "INPUT":
            bad = len(i) != 2 or i[0] >= len(nnz_in) or i[1] >= nnz_in[i[0]] or not out
        elif op == "OUTPUT":
            bad = (len(out) != 2 or out[0] >= len(shapes) or out[1] >= len(shapes[out[0]][2])
                   or not i or i[0] not in defined)
        else:
            arity = 0 if op == "CONST" else (1 if op in UNARY or op == "NOT" else 2)
            bad = len(i) < arity or any(s not in defined for s in i[:arity]) or not out
        if bad:
            raise UserError(f"{what}: instruction {k} ({op}) has bad indices")
        if op != "OUTPUT":
            defined.add(out[0])
        frozen.append((op, i, out, _const(c, what) if op == "CONST" else None))
    return tuple(frozen), nnz_in, tuple(shapes)


def replay(code: Sequence[tuple], inputs: Sequence[Any], nnz_out: Sequence[int],
           dtype) -> list[list]:
    """Replay instructions ``(op name, operands, results, constant)`` on ``inputs`` (per
    input, its nonzeros: an array or a list of scalars) in ``dtype``; returns each output's
    nonzeros as a list of scalars. The one replay of CasADi's semantics in JAX: this module's
    programs and :mod:`softpinn.bridge.exact.translate` call it."""
    one, zero = jnp.asarray(1.0, dtype), jnp.asarray(0.0, dtype)
    values: list[list] = [[zero] * k for k in nnz_out]
    w: dict[int, Any] = {}
    for op, i, o, c in code:
        if op in BINARY:
            w[o[0]] = BINARY[op](w[i[0]], w[i[1]])
        elif op in UNARY:
            w[o[0]] = UNARY[op](w[i[0]])
        elif op == "CONST":
            w[o[0]] = c
        elif op == "INPUT":
            w[o[0]] = inputs[i[0]][i[1]]
        elif op == "OUTPUT":
            values[o[0]][o[1]] = w[i[0]]
        elif op in COMPARE:
            w[o[0]] = jnp.where(COMPARE[op](w[i[0]], w[i[1]]), one, zero)
        elif op == "NOT":
            w[o[0]] = jnp.where(w[i[0]] == 0, one, zero)
        else:  # IF_ELSE_ZERO
            w[o[0]] = jnp.where(w[i[0]] != 0, w[i[1]], zero)
    return values


def run_program(program: tuple, inputs: Sequence[Any], dtype) -> list:
    """Replay a :func:`check_program` result on ``inputs`` (one flat array of nonzeros per
    program input) in ``dtype``; returns each output as a dense (rows, cols) array."""
    code, _, shapes = program
    values = replay(code, inputs, [len(s[2]) for s in shapes], dtype)
    outs = []
    for (rows, cols, row, col), vals in zip(shapes, values, strict=True):
        out = jnp.zeros((rows, cols), dtype)
        if row:
            stacked = jnp.stack([jnp.asarray(v, dtype) for v in vals])
            out = out.at[jnp.asarray(row), jnp.asarray(col)].set(stacked)
        outs.append(out)
    return outs


class ProgramFunction:
    """A whole program as a JAX function: ``f(*inputs)`` takes one array per input (any shape
    with that input's nonzero count, a float dtype: float32 computes in float32) and returns
    the outputs as a tuple of dense (rows, cols) arrays."""

    def __init__(self, data: dict[str, Any]):
        self.program = check_program(data, f"program {data.get('name', '?')!r}"
                                     if isinstance(data, dict) else "program")
        self.name = str(data.get("name", "program"))
        self.name_in = tuple(str(d.get("name", f"i{k}")) for k, d in enumerate(data["inputs"]))
        self.name_out = tuple(str(d.get("name", f"o{k}"))
                              for k, d in enumerate(data["outputs"]))

    def __call__(self, *inputs):
        nnz = self.program[1]
        if len(inputs) != len(nnz):
            raise UserError(f"{self.name}: takes {len(nnz)} inputs {list(self.name_in)}, got "
                            f"{len(inputs)}")
        flat = [jnp.reshape(jnp.asarray(x), (-1,)) for x in inputs]
        for name, x, k in zip(self.name_in, flat, nnz, strict=True):
            if x.shape[0] != k:
                raise UserError(f"{self.name}: input {name} has {k} values, got {x.shape[0]}")
        dtype = next((x.dtype for x in flat if jnp.issubdtype(x.dtype, jnp.floating)),
                     jnp.result_type(float))
        return tuple(run_program(self.program, [x.astype(dtype) for x in flat], dtype))
