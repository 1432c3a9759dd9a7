"""``TrueModel``: the numeric face of :func:`symbolic.model._functions.functions`.

Every method takes numpy arrays: one state (``q`` of shape (n,)) or a batch (shape (N, n)),
evaluated with ``Function.map(N)`` in one call (no Python loop), and returns numpy arrays:
(n, n) / (n,) / float for one state, (N, n, n) / (N, n) / (N,) for a batch.

Batches of :data:`COMPILE_FROM` states or more run a batched C kernel of the function
(:mod:`symbolic.codegen._kernel`: the SX instructions inside one loop over the states, vectorised by
the compiler; compiled once per machine into the code cache of :mod:`symbolic.codegen._codegen`):
task5's forward dynamics costs about 0.4 µs per state there, against 4.8 µs in CasADi's own C
(``map``, the path for a function that has no kernel) and 56 µs in CasADi's interpreter, which stays
the path for single states and small batches (where a first compile would cost more than it saves)
and the fallback when no C compiler is found (with one warning).
"""

from __future__ import annotations

import warnings
from pathlib import Path

import casadi as ca
import numpy as np

from softpinn.errors import UserError
from softpinn.symbolic.codegen import _codegen as codegen
from softpinn.symbolic.codegen import _kernel as kernel
from softpinn.symbolic.codegen._compiler import CompilerError
from softpinn.symbolic.model._functions import functions
from softpinn.symbolic.spec._model_spec import ModelSpec
from softpinn.symbolic.spec._spec import load_spec

#: batches of at least this many states run compiled C (``compiled=None``, the default)
COMPILE_FROM = 100

#: outputs returned as matrices even when a dimension is 1 (A with one input)
_MATRICES = frozenset({"M", "M_inv", "D", "A", "C"})
#: The scalar outputs (energies): a number, or (N,) in a batch. Every other output is a vector
#: of n (or 2n) entries even where n = 1: (1,), or (N, 1) in a batch.
_SCALARS = frozenset({"E", "T", "V"})


class TrueModel:
    """Numeric M, M^-1, G, D, A, C, C qd, forward and inverse dynamics, energies and the
    Hamiltonian form (eqs. 4, 7) of a model spec, a preset name or a spec path."""

    def __init__(self, model: str | Path | ModelSpec, order: int | None = None, *,
                 compiled: bool | None = None):
        """``compiled``: None runs batches of :data:`COMPILE_FROM` states or more as compiled
        C and everything else in CasADi's interpreter; True compiles every batched call; False
        never compiles."""
        if compiled not in (None, True, False):
            raise UserError(f"compiled: expected None, True or False, got {compiled!r}")
        self.spec: ModelSpec = load_spec(model)
        self.n: int = self.spec.n
        self.m: int = self.spec.m
        self.functions: dict[str, ca.Function] = functions(self.spec, order)
        self.compiled = compiled
        self._mapped: dict[tuple[str, int], ca.Function] = {}
        self._compiled: dict[str, ca.Function] = {}
        self._kernels: dict[str, kernel.Kernel | None] = {}

    def _kernel(self, key: str, batch: int) -> kernel.Kernel | None:
        """The batched C kernel of Function ``key`` where the setting and batch size ask for
        compiled code and one can be built (else None: CasADi's C or interpreter)."""
        if self.compiled is False or (self.compiled is None and batch < COMPILE_FROM):
            return None
        if key not in self._kernels:
            try:
                built = kernel.kernels({key: self.functions[key]})
            except (kernel.KernelError, CompilerError):
                built = None  # CasADi's C (or its interpreter, with codegen's warning)
            self._kernels[key] = None if built is None else built[key]
        return self._kernels[key]

    def _batch_function(self, key: str, batch: int) -> ca.Function:
        """Function ``key`` for a batch: compiled C where the setting and batch size ask for
        it and a compiler exists, else the interpreted one."""
        f = self.functions[key]
        if self.compiled is False or (self.compiled is None and batch < COMPILE_FROM):
            return f
        if key not in self._compiled:
            self._compiled[key] = codegen.compiled({key: f})[key]
        return self._compiled[key]

    # ------------------------------------------------------------------ evaluation core

    def _arg(self, name: str, value, size: int) -> tuple[np.ndarray, bool]:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("error", np.exceptions.ComplexWarning)
                a = np.asarray(value, dtype=float)
        except (TypeError, ValueError, np.exceptions.ComplexWarning):
            raise UserError(f"{name}: expected real numbers, got {_short(value)}") from None
        if a.ndim == 0 or a.ndim > 2:
            raise UserError(f"{name}: expected shape ({size},) or (N, {size}), got {a.shape}")
        if a.shape[-1] != size:
            raise UserError(f"{name}: expected length {size} for model "
                            f"'{self.spec.name}', got {a.shape[-1]}")
        if not np.all(np.isfinite(a)):
            where = np.argwhere(~np.isfinite(a))[0]
            raise UserError(f"{name}: values must be finite, got {a[tuple(where)]} at index "
                            f"{tuple(int(i) for i in where) if a.ndim == 2 else int(where[0])}")
        return a, a.ndim == 2

    def call(self, key: str, **inputs) -> list[np.ndarray]:
        """Evaluate Function ``key`` at named numpy inputs; returns its outputs as arrays."""
        if key not in self.functions:
            raise UserError(f"{key}: not a function of the model (one of "
                            f"{', '.join(sorted(self.functions))})")
        f = self.functions[key]
        sizes = {f.name_in(i): f.size1_in(i) for i in range(f.n_in())}
        if set(inputs) != set(sizes):
            raise UserError(f"{key}: expected inputs {sorted(sizes)}, got {sorted(inputs)}")
        arrays, batch = {}, None
        for name, size in sizes.items():
            a, is_batch = self._arg(name, inputs[name], size)
            arrays[name] = a
            if is_batch:
                if batch is not None and batch != a.shape[0]:
                    raise UserError(f"{name}: batch size {a.shape[0]} differs from {batch}")
                batch = a.shape[0]
        if batch is None:
            res = f.call({k: ca.DM(v) for k, v in arrays.items()})
            return [self._single(f, j, res[f.name_out(j)]) for j in range(f.n_out())]
        if batch == 0:
            return [self._batched(f, j, np.zeros((f.size1_out(j), 0)), 0)
                    for j in range(f.n_out())]
        kern = self._kernel(key, batch)
        if kern is not None:
            nz = kern(*[arrays[f.name_in(i)] for i in range(f.n_in())])
            return [self._batched(f, j, kern.dense(j, nz[j]), batch, stacked=True)
                    for j in range(f.n_out())]
        args = {}
        for name, a in arrays.items():
            if a.ndim == 1:
                a = np.broadcast_to(a, (batch, a.size))
            args[name] = ca.DM(np.ascontiguousarray(a.T))
        fm = self._mapped.get((key, batch))
        if fm is None:
            fm = self._mapped[(key, batch)] = self._batch_function(key, batch).map(batch)
        res = fm.call(args)
        return [self._batched(f, j, res[f.name_out(j)], batch) for j in range(f.n_out())]

    @staticmethod
    def _single(f: ca.Function, j: int, value: ca.DM):
        a = np.array(value, dtype=float).reshape(f.size1_out(j), f.size2_out(j), order="F")
        if f.name_out(j) in _MATRICES:
            return a
        if f.name_out(j) in _SCALARS:
            return float(a[0, 0])
        return a[:, 0]

    @staticmethod
    def _batched(f: ca.Function, j: int, value, batch: int, stacked: bool = False):
        r, c = f.size1_out(j), f.size2_out(j)
        if stacked:  # (batch, r, c) from a kernel
            a = np.asarray(value, dtype=float)
        else:
            a = np.array(value, dtype=float)  # r x (c * batch)
            a = a.reshape(r, batch, c).transpose(1, 0, 2)
        if f.name_out(j) in _MATRICES:
            return a
        if f.name_out(j) in _SCALARS:
            return a[:, 0, 0]
        return a[:, :, 0]

    # ------------------------------------------------------------------ the public face

    def M(self, q):
        """Mass matrix M(q) (eqs. 18-20)."""
        return self.call("M", q=q)[0]

    def M_inv(self, q):
        """M(q)^-1 by a Cholesky solve."""
        return self.call("M_inv", q=q)[0]

    def G(self, q):
        """Generalized potential force dV/dq (eqs. 21-24)."""
        return self.call("G", q=q)[0]

    def D(self, q):
        """Damping matrix."""
        return self.call("D", q=q)[0]

    def A(self, q):
        """Input matrix A(q) (n x m)."""
        return self.call("A", q=q)[0]

    def C(self, q, qd):
        """Coriolis matrix from the Christoffel symbols of M."""
        return self.call("C", q=q, qd=qd)[0]

    def Cqd(self, q, qd):
        """C(q, qd) qd = Mdot qd - 1/2 d(qd^T M qd)/dq."""
        return self.call("Cqd", q=q, qd=qd)[0]

    def qdd(self, q, qd, u=None):
        """Forward dynamics: qdd solving M qdd + C qd + G + D qd = A u (eq. 4)."""
        return self.call("forward", q=q, qd=qd, u=self._u(u, q))[0]

    def tau(self, q, qd, qdd):
        """Inverse dynamics: M qdd + C qd + G + D qd (equals A u)."""
        return self.call("inverse", q=q, qd=qd, qdd=qdd)[0]

    def energy(self, q, qd):
        """Total energy: kinetic + gravitational + elastic."""
        return self.call("energy", q=q, qd=qd)[0]

    def kinetic(self, q, qd):
        return self.call("kinetic", q=q, qd=qd)[0]

    def potential(self, q):
        return self.call("potential", q=q)[0]

    def momentum(self, q, qd):
        """p = M(q) qd."""
        return self.call("momentum", q=q, qd=qd)[0]

    def hamiltonian(self, q, p, u=None):
        """(qdot, pdot) of the Hamiltonian form (eq. 7) with damping and input."""
        return tuple(self.call("hamiltonian", q=q, p=p, u=self._u(u, q)))

    def ode(self, x, u=None):
        """xdot = [qd; qdd] for x = [q; qd]."""
        return self.call("ode", x=x, u=self._u(u))[0]

    def _u(self, u, q=None):
        if u is None:
            return np.zeros(self.m)
        return u

    def __repr__(self) -> str:
        return f"TrueModel({self.spec.name!r}, n={self.n}, m={self.m})"


def _short(value) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."
