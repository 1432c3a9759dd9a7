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

import casadi as ca
import jax.numpy as jnp

from softpinn.bridge.exact.errors import TranslationError
from softpinn.learn import KNOWN_OPS, replay

#: CasADi's operation codes by name ("ADD", ...: ``OP_*`` without the prefix); the code keeps
#: the names, which :func:`softpinn.learn._sx_replay.replay` evaluates
_OP_NAMES = {getattr(ca, a): a[3:] for a in dir(ca) if a.startswith("OP_")}


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
        code = []
        for k in range(f.n_instructions()):
            op = _OP_NAMES.get(f.instruction_id(k), f.instruction_id(k))
            if op not in KNOWN_OPS:
                raise TranslationError(f"{self.name}: instruction {k} is CasADi's "
                                       f"OP_{op}, which has no JAX translation")
            const = f.instruction_constant(k) if op == "CONST" else None
            code.append((op, tuple(f.instruction_input(k)), tuple(f.instruction_output(k)),
                         const))
        self.code = code  # (op name, operands, results, constant) per instruction

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
        outs = replay(self.code, scalars, [sp.nnz() for sp in self.sparsity_out], dtype)
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
