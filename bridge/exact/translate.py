"""CasADi Function -> pure ``jax.numpy`` function, traced from CasADi's instruction list.

An MX Function (the project's Functions call mapped plate densities and a Cholesky solve) is
first expanded to SX (``Function.expand``: milliseconds, every call and serial ``map``
inlined); the SX algorithm is then replayed instruction by instruction on JAX values. The result
works on ONE evaluation point (inputs as 1-D arrays of the inputs' nonzeros, outputs dense, shaped
like CasADi's outputs); batches come from ``jax.vmap``, under which each scalar instruction becomes
one elementwise vector operation that XLA fuses and vectorises.

Semantics follow CasADi's C code generator (``casadi_*`` in ``casadi/core/calculus.hpp``):
comparisons and logic give 1.0 / 0.0, ``if_else_zero(c, x)`` is ``c ? x : 0`` (no NaN from the
unused branch), ``sign(0) = 0``, ``fmod`` is C's, constants are Python floats so that a float32
input stays float32.
"""

from __future__ import annotations

from collections.abc import Callable

import casadi as ca
import jax.numpy as jnp
from jax import lax

from .errors import TranslationError


def _unary() -> dict[int, Callable]:
    return {
        ca.OP_ASSIGN: lambda x: x,
        ca.OP_NEG: lambda x: -x,
        ca.OP_EXP: jnp.exp,
        ca.OP_LOG: jnp.log,
        ca.OP_SQRT: jnp.sqrt,
        ca.OP_SQ: lambda x: x * x,
        ca.OP_TWICE: lambda x: x + x,
        ca.OP_SIN: jnp.sin,
        ca.OP_COS: jnp.cos,
        ca.OP_TAN: jnp.tan,
        ca.OP_ASIN: jnp.arcsin,
        ca.OP_ACOS: jnp.arccos,
        ca.OP_ATAN: jnp.arctan,
        ca.OP_FLOOR: jnp.floor,
        ca.OP_CEIL: jnp.ceil,
        ca.OP_FABS: jnp.abs,
        ca.OP_SIGN: jnp.sign,
        ca.OP_ERF: lax.erf,
        ca.OP_INV: lambda x: 1.0 / x,
        ca.OP_SINH: jnp.sinh,
        ca.OP_COSH: jnp.cosh,
        ca.OP_TANH: jnp.tanh,
        ca.OP_ASINH: jnp.arcsinh,
        ca.OP_ACOSH: jnp.arccosh,
        ca.OP_ATANH: jnp.arctanh,
        ca.OP_LOG1P: jnp.log1p,
        ca.OP_EXPM1: jnp.expm1,
        ca.OP_ERFINV: lax.erf_inv,
    }


def _binary() -> dict[int, Callable]:
    return {
        ca.OP_ADD: lambda x, y: x + y,
        ca.OP_SUB: lambda x, y: x - y,
        ca.OP_MUL: lambda x, y: x * y,
        ca.OP_DIV: lambda x, y: x / y,
        ca.OP_POW: jnp.power,
        ca.OP_CONSTPOW: jnp.power,
        ca.OP_ATAN2: jnp.arctan2,
        ca.OP_FMIN: jnp.minimum,
        ca.OP_FMAX: jnp.maximum,
        ca.OP_FMOD: jnp.fmod,
        ca.OP_REMAINDER: lambda x, y: x - y * jnp.round(x / y),  # IEEE remainder, as C
        ca.OP_COPYSIGN: jnp.copysign,
        ca.OP_HYPOT: jnp.hypot,
    }


_COMPARE = {
    ca.OP_LT: lambda x, y: x < y,
    ca.OP_LE: lambda x, y: x <= y,
    ca.OP_EQ: lambda x, y: x == y,
    ca.OP_NE: lambda x, y: x != y,
    ca.OP_AND: lambda x, y: (x != 0) & (y != 0),
    ca.OP_OR: lambda x, y: (x != 0) | (y != 0),
}

_OP_NAMES = {getattr(ca, a): a for a in dir(ca) if a.startswith("OP_")}
_UNARY = _unary()
_BINARY = _binary()


class Program:
    """The SX algorithm of a CasADi Function as a flat instruction table (plain Python
    tuples), ready to be replayed on JAX values by :meth:`__call__`."""

    def __init__(self, f: ca.Function):
        if f.is_a("MXFunction"):
            try:
                f = f.expand()
            except RuntimeError as err:  # e.g. a call to a non-expandable Function
                raise TranslationError(f"{f.name()}: cannot expand to SX ({err})") from err
        if not f.is_a("SXFunction"):
            raise TranslationError(f"{f.name()}: expected an SX or MX Function, got "
                                   f"{f.class_name()}")
        self.name = f.name()
        self.n_in, self.n_out = f.n_in(), f.n_out()
        self.name_in = [f.name_in(i) for i in range(self.n_in)]
        self.name_out = [f.name_out(i) for i in range(self.n_out)]
        self.nnz_in = [f.nnz_in(i) for i in range(self.n_in)]
        self.sparsity_out = [f.sparsity_out(i) for i in range(self.n_out)]
        self.n_instructions = f.n_instructions()
        known = set(_UNARY) | set(_BINARY) | set(_COMPARE) | {
            ca.OP_CONST, ca.OP_INPUT, ca.OP_OUTPUT, ca.OP_NOT, ca.OP_IF_ELSE_ZERO}
        code = []
        for k in range(f.n_instructions()):
            op = f.instruction_id(k)
            if op not in known:
                raise TranslationError(f"{self.name}: instruction {k} is CasADi's "
                                       f"{_OP_NAMES.get(op, op)}, which has no JAX translation")
            const = f.instruction_constant(k) if op == ca.OP_CONST else None
            code.append((op, tuple(f.instruction_input(k)), tuple(f.instruction_output(k)),
                         const))
        self.code = code

    def __call__(self, *args):
        """Evaluate at one point: ``args[i]`` holds input i's nonzeros (1-D, length
        ``nnz_in[i]``, column-major as CasADi); returns the dense outputs (one array each,
        shaped (rows,) for a column, (rows, cols) otherwise)."""
        outs, dtype = self.nonzeros(*args)
        return tuple(self._dense(j, vals, dtype) for j, vals in enumerate(outs))

    def nonzeros(self, *args) -> tuple[list[list], object]:
        """The outputs' nonzeros (a list of scalars per output) and the working dtype."""
        if len(args) != self.n_in:
            raise TranslationError(f"{self.name}: expected {self.n_in} inputs "
                                   f"{self.name_in}, got {len(args)}")
        ins = [jnp.asarray(a) for a in args]
        dtype = jnp.result_type(*ins) if ins else jnp.float64
        if not jnp.issubdtype(dtype, jnp.floating):
            dtype = jnp.float64
        ins = [jnp.reshape(a, (-1,)).astype(dtype) for a in ins]
        for i, (a, nnz) in enumerate(zip(ins, self.nnz_in, strict=True)):
            if a.shape[0] != nnz:
                raise TranslationError(f"{self.name}: input '{self.name_in[i]}' expected "
                                       f"{nnz} values, got {a.shape[0]}")
        scalars = [[a[j] for j in range(a.shape[0])] for a in ins]
        one, zero = jnp.asarray(1.0, dtype), jnp.asarray(0.0, dtype)

        def f(b):
            return jnp.where(b, one, zero)

        outs = [[zero] * sp.nnz() for sp in self.sparsity_out]
        w: dict[int, object] = {}
        unary, binary, compare = _UNARY, _BINARY, _COMPARE
        for op, i, o, const in self.code:
            if op in binary:
                w[o[0]] = binary[op](w[i[0]], w[i[1]])
            elif op in unary:
                w[o[0]] = unary[op](w[i[0]])
            elif op == ca.OP_CONST:
                w[o[0]] = const
            elif op == ca.OP_INPUT:
                w[o[0]] = scalars[i[0]][i[1]]
            elif op == ca.OP_OUTPUT:
                outs[o[0]][o[1]] = w[i[0]]
            elif op in compare:
                w[o[0]] = f(compare[op](w[i[0]], w[i[1]]))
            elif op == ca.OP_NOT:
                w[o[0]] = f(w[i[0]] == 0)
            else:  # OP_IF_ELSE_ZERO
                w[o[0]] = jnp.where(w[i[0]] != 0, w[i[1]], zero)
        return outs, dtype

    def _dense(self, j: int, vals: list, dtype):
        sp = self.sparsity_out[j]
        rows, cols = sp.size1(), sp.size2()
        vals = [jnp.asarray(v, dtype) for v in vals]
        if sp.is_dense():
            flat = jnp.stack(vals) if vals else jnp.zeros((0,), dtype)
            if cols == 1:
                return flat
            return flat.reshape(cols, rows).T
        out = jnp.zeros((rows, cols), dtype)
        if vals:
            r, c = sp.get_triplet()
            out = out.at[jnp.asarray(r), jnp.asarray(c)].set(jnp.stack(vals))
        return out[:, 0] if cols == 1 else out


def translate(f: ca.Function) -> Program:
    """A :class:`Program` (a callable on JAX values) equal to the CasADi Function ``f``."""
    return Program(f)


__all__ = ["Program", "translate"]
