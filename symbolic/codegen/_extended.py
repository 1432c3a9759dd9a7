"""A Function evaluated in extended precision: the reference that double-precision results are
measured against (issue 45's "no accuracy lost").

CasADi's interpreter and the batched kernels (:mod:`.kernel`) both round in double precision,
each in its own order of operations (the kernels fuse products and sums where the host has FMA
and divide once per shared divisor). Where the result is ill-conditioned (a 4-segment arm's
mass matrix at some states), the two differ by far more than a few ulp, and neither is the
exact value: comparing them says nothing about which one lost accuracy. This module writes the
Function with CasADi's own C code generator in ``long double`` (80-bit x87 on x86_64: a 64-bit
significand, 2,048 times finer than double; quadruple precision on aarch64), with
``<tgmath.h>`` so that every math call takes the long double variant, and evaluates a batch
through ``map``. The constants are the same doubles, so the reference is the exact value of the
same double-precision function to about 1e-19 relative times the condition number.
"""

from __future__ import annotations

import ctypes
import tempfile
from pathlib import Path

import casadi as ca
import numpy as np

from softpinn.symbolic.codegen._compiler import compile_c, find_compiler

__all__ = ["available", "extended"]

#: finer than this unit roundoff or no extended type: :func:`available` is False (MSVC's long
#: double is a double)
_EPS = 1e-18


def available(compiler=None) -> bool:
    """Whether a C compiler exists and the platform's long double is finer than double."""
    return float(np.finfo(np.longdouble).eps) < _EPS and find_compiler(compiler) is not None


def extended(f: ca.Function, *args: np.ndarray, compiler=None) -> list[np.ndarray]:
    """``f`` at the columns of ``args`` (input k an (nnz_in[k], N) array) in long double: its
    outputs' nonzeros as (nnz_out[k], N) ``np.longdouble`` arrays. MX Functions are expanded to
    SX first (the instruction list both double-precision paths evaluate)."""
    cc = find_compiler(compiler)
    if cc is None or float(np.finfo(np.longdouble).eps) >= _EPS:
        raise RuntimeError("extended precision needs a C compiler and a long double finer than "
                           "double")
    if f.is_a("MXFunction"):
        f = f.expand()
    if len(args) != f.n_in():
        raise ValueError(f"{f.name()}: expected {f.n_in()} inputs, got {len(args)}")
    n = max(int(np.shape(a)[1]) for a in args) if args else 1
    batch = f.map(n, "serial")
    with tempfile.TemporaryDirectory(prefix="softpinn-extended-") as tmp:
        gen = ca.CodeGenerator("extended.c", {"casadi_real": "long double",
                                              "with_header": False})
        gen.add(batch)
        gen.generate(tmp + "/")
        source = Path(tmp) / "extended.c"
        text = source.read_text()
        source.write_text("#include <tgmath.h>\n" + text)
        library = Path(tmp) / "extended.so"
        compile_c(source, library, compiler=cc)
        lib = ctypes.CDLL(str(library))
        fn = getattr(lib, batch.name())
        ins = []
        for k, a in enumerate(args):
            a = np.asarray(a, dtype=np.float64)
            if a.shape != (f.nnz_in(k), n):
                raise ValueError(f"{f.name()}: input {k}: expected shape {(f.nnz_in(k), n)}, "
                                 f"got {a.shape}")
            # column-major (nnz, N): each state's nonzeros are contiguous
            ins.append(np.ascontiguousarray(a.T, dtype=np.longdouble))
        outs = [np.empty((n, f.nnz_out(k)), dtype=np.longdouble) for k in range(f.n_out())]
        sz_arg, sz_res, sz_iw, sz_w = batch.sz_arg(), batch.sz_res(), batch.sz_iw(), batch.sz_w()
        arg = (ctypes.c_void_p * max(sz_arg, 1))(*[a.ctypes.data for a in ins])
        res = (ctypes.c_void_p * max(sz_res, 1))(*[o.ctypes.data for o in outs])
        iw = (ctypes.c_longlong * max(sz_iw, 1))()
        w = np.zeros(max(sz_w, 1), dtype=np.longdouble)
        fn.restype = ctypes.c_int
        fn.argtypes = [ctypes.c_void_p] * 4 + [ctypes.c_int]
        if fn(arg, res, iw, w.ctypes.data, 0) != 0:
            raise RuntimeError(f"{f.name()}: the extended-precision evaluation failed")
        del lib
    return [o.T for o in outs]
