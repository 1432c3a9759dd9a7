"""A translated CasADi Function (:class:`.translate.Program`) as pure data, and back to CasADi.

:func:`program_data` writes a Program's SX instruction list as a JSON-ready dict that names
every operation (``"ADD"``, ``"SIN"``, ... : CasADi's ``OP_*`` names without the prefix, not
its version-dependent integer codes), so that :mod:`softpinn.learn._known_input` can replay
it in JAX
without CasADi (a run's known input matrix A(q), eq. 6, stored in its ``config.json``)::

    {"format": "softpinn-program/1", "name": "A",
     "inputs": [{"name": "q", "nnz": 3}],
     "outputs": [{"name": "A", "rows": 3, "cols": 3, "row": [...], "col": [...]}],
     "code": [["INPUT", [0, 2], [5], null], ["CONST", [], [6], 0.5], ["MUL", [5, 6], [7], null],
              ["OUTPUT", [7], [0, 4], null], ...]}

``code`` holds one entry per instruction: the operation's name, its operand indices (work
slots; for ``INPUT``: input and nonzero; for ``OUTPUT``: the work slot), its result indices
(work slot; for ``OUTPUT``: output and nonzero) and the constant of a ``CONST`` (a float, or
"inf", "-inf", "nan" as text, so that the data stays strict JSON). Each output is given by its
sparsity pattern (the row and column of each nonzero, column-major as CasADi).

:func:`casadi_function` rebuilds the data as an SX Function (the exporter's known A, and the
check that the data say what the Function said).
"""

from __future__ import annotations

import math
from typing import Any

import casadi as ca

from softpinn.bridge.exact.errors import TranslationError
from softpinn.bridge.exact.translate import Program, translate
from softpinn.learn import PROGRAM_FORMAT, known_input_text
from softpinn.symbolic import functions, load_spec

__all__ = ["FORMAT", "program_data", "function_data", "casadi_function", "spec_known_input"]

FORMAT = PROGRAM_FORMAT


def _constant(c: float) -> float | str:
    c = float(c)
    if math.isfinite(c):
        return c
    return "nan" if math.isnan(c) else ("inf" if c > 0 else "-inf")


def program_data(program: Program) -> dict[str, Any]:
    """The JSON-ready data of a :class:`Program` (see the module's docstring)."""
    code = []
    for op, i, o, const in program.code:  # op: CasADi's name for it (translate.Program)
        code.append([op, [int(k) for k in i], [int(k) for k in o],
                     None if const is None else _constant(const)])
    outputs = []
    for name, sp in zip(program.name_out, program.sparsity_out, strict=True):
        r, c = sp.get_triplet()
        outputs.append({"name": name, "rows": int(sp.size1()), "cols": int(sp.size2()),
                        "row": [int(k) for k in r], "col": [int(k) for k in c]})
    return {
        "format": FORMAT,
        "name": program.name,
        "inputs": [{"name": nm, "nnz": int(k)}
                   for nm, k in zip(program.name_in, program.nnz_in, strict=True)],
        "outputs": outputs,
        "code": code,
    }


def function_data(f: ca.Function) -> dict[str, Any]:
    """The data of a CasADi Function (translated first; an MX Function is expanded to SX)."""
    return program_data(translate(f))


_UNARY = {
    "ASSIGN": lambda x: x, "NEG": lambda x: -x, "EXP": ca.exp, "LOG": ca.log, "SQRT": ca.sqrt,
    "SQ": lambda x: x * x, "TWICE": lambda x: x + x, "SIN": ca.sin, "COS": ca.cos, "TAN": ca.tan,
    "ASIN": ca.asin, "ACOS": ca.acos, "ATAN": ca.atan, "FLOOR": ca.floor, "CEIL": ca.ceil,
    "FABS": ca.fabs, "SIGN": ca.sign, "ERF": ca.erf, "INV": lambda x: 1.0 / x, "SINH": ca.sinh,
    "COSH": ca.cosh, "TANH": ca.tanh, "ASINH": ca.asinh, "ACOSH": ca.acosh, "ATANH": ca.atanh,
    "LOG1P": ca.log1p, "EXPM1": ca.expm1, "ERFINV": ca.erfinv, "NOT": ca.logic_not,
}
_BINARY = {
    "ADD": lambda x, y: x + y, "SUB": lambda x, y: x - y, "MUL": lambda x, y: x * y,
    "DIV": lambda x, y: x / y, "POW": lambda x, y: x ** y, "CONSTPOW": lambda x, y: x ** y,
    "ATAN2": ca.atan2, "FMIN": ca.fmin, "FMAX": ca.fmax, "FMOD": ca.fmod,
    "REMAINDER": ca.remainder, "COPYSIGN": ca.copysign, "HYPOT": ca.hypot,
    "LT": lambda x, y: x < y, "LE": lambda x, y: x <= y, "EQ": lambda x, y: x == y,
    "NE": lambda x, y: x != y, "AND": ca.logic_and, "OR": ca.logic_or,
    "IF_ELSE_ZERO": lambda c, x: ca.if_else(c, x, 0),
}


def casadi_function(data: dict[str, Any], name: str | None = None) -> ca.Function:
    """The SX Function that the data describe (inputs as dense columns of their nonzeros)."""
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise TranslationError(f"expected program data of format {FORMAT!r}")
    ins = [ca.SX.sym(d["name"], int(d["nnz"])) for d in data["inputs"]]
    outs = [[ca.SX(0)] * len(d["row"]) for d in data["outputs"]]
    w: dict[int, Any] = {}
    for op, i, o, const in data["code"]:
        if op == "CONST":
            w[o[0]] = ca.SX(float(const))
        elif op == "INPUT":
            w[o[0]] = ins[i[0]][i[1]]
        elif op == "OUTPUT":
            outs[o[0]][o[1]] = w[i[0]]
        elif op in _BINARY:
            w[o[0]] = _BINARY[op](w[i[0]], w[i[1]])
        elif op in _UNARY:
            w[o[0]] = _UNARY[op](w[i[0]])
        else:
            raise TranslationError(f"{data.get('name')}: unknown operation {op!r}")
    dense = []
    for d, vals in zip(data["outputs"], outs, strict=True):
        sp = ca.Sparsity.triplet(int(d["rows"]), int(d["cols"]), list(d["row"]), list(d["col"]))
        dense.append(ca.densify(ca.SX(sp, ca.vertcat(*vals) if vals else ca.SX(0, 1))))
    return ca.Function(name or str(data.get("name", "f")), ins, dense,
                       [d["name"] for d in data["inputs"]], [d["name"] for d in data["outputs"]])


def spec_known_input(model) -> tuple[str, int, int]:
    """``(known_input text, n, m)``: the exact A(q) of a spec (a preset name, a spec path or a
    ``ModelSpec``) as program data for :class:`softpinn.learn._models.ModelConfig`
    (``input_form="known"``)."""

    spec = load_spec(model)
    return known_input_text(function_data(functions(spec)["A"])), spec.n, spec.m
