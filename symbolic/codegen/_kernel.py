"""Batched C kernels generated from CasADi's SX instruction list: one state's straight-line code
inside a loop over a batch of states that the C compiler vectorises.

CasADi's own C (:mod:`.codegen`) evaluates one state per call through a work vector in memory;
``Function.map`` loops over those calls. Here the SX algorithm (``Function.expand`` for MX) is
written out once as C statements on local variables inside

    for (i = 0; i < n; ++i)   /* #pragma omp simd: lanes i, i+1, ... of one vector */

with the batch as struct of arrays (input k, nonzero j of state i at ``arg[k][j*ld + i]``), so
each instruction becomes one vector instruction over 4 (AVX2) or 8 (AVX-512) states. ``sin`` and
``cos`` inside the vectorised loop come from glibc's vector math library (libmvec, at most 4 ulp:
the results equal CasADi's to ~1e-15 relative); where that library or the flags are missing the
same source compiles to scalar code (slower, same results). Libraries are compiled through
:mod:`.compiler` (supervised, with a timeout) into the code cache of :mod:`.codegen` (keyed by
the functions' ``serialize()``, the source generator's version, compiler and flags) and loaded
with ``ctypes`` (which releases the GIL during a call, so Python threads run kernels in parallel).

:func:`kernels` returns ``None`` when no compiler is found (callers fall back to CasADi);
:func:`rk4_source` adds a fixed-step RK4 integrator over many trajectories in the same C.

task5's forward dynamics (10,013 SX instructions) runs at 0.32-0.35 µs per state on one core
of a shared 2-core AVX-512 machine (best and median of 41 alternated rounds, load 1.6; the
source of before 28 Nov in the same rounds: 0.37-0.40 µs; CasADi's C with ``map``: ~5 µs) and
compiles in ~3 s.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import hashlib
import json
import os
import platform
import shutil
import sys
import tempfile
import threading
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import casadi as ca
import numpy as np

from softpinn.symbolic import _outputs as outputs
from softpinn.symbolic.codegen._codegen import open_cache, remove_stale_builds
from softpinn.symbolic.codegen._compiler import (
    DEFAULT_TIMEOUT,
    CompilerError,
    CompilerTimeout,
    compile_c,
    find_compiler,
)
from softpinn.symbolic.codegen._kernel_source import (
    HEADER,
    WIDTH,
    KernelError,
    dense,
    expand,
    kernel_source,
    rk4_source,
)

#: bump when the generated source (:mod:`.kernel_source`) changes (part of the cache key)
VERSION = 4

#: vectorising flags (gcc): -O1 plus the vectoriser. On the kernels of :mod:`.kernel_source`
#: -O2 compiles task5 in ~5 s against ~3.5 s and is no faster, nor are -fschedule-insns2,
#: -fschedule-insns -fsched-pressure (10 s), -fira-region=one/all, -fira-algorithm=priority or
#: -fno-trapping-math (alternated rounds, 28 Nov); 256-bit vectors are ~1.5x slower than 512.
#: No scalar epilogue re-vectorised (only kernels above _kernel_source.LARGE instructions
#: keep one). -fexpensive-optimizations lets -O1 fuse a product and a sum into one FMA where the
#: host has it (gcc does so from -O2 on): task5 0.42 -> 0.37 µs per state, same compile time,
#: and still equal to CasADi's evaluation to ~4e-14 relative per state
#: (tests/test_batched_kernels.py)
FAST_FLAGS: tuple[str, ...] = (
    "-O1", "-ftree-vectorize", "-fexpensive-optimizations", "--param=vect-epilogues-nomask=0",
    "-march=native", "-fno-math-errno", "-fopenmp-simd", "-fPIC", "-shared",
)
#: any C99 compiler: scalar code
PLAIN_FLAGS: tuple[str, ...] = ("-O1", "-fPIC", "-shared")

# ---------------------------------------------------------------------------- build and load

def _mvec_available() -> bool:
    """glibc's libmvec on x86_64 Linux (its vector sin/cos)."""
    if not (sys.platform.startswith("linux") and platform.machine() in ("x86_64", "AMD64")):
        return False
    return ctypes.util.find_library("mvec") is not None


def _settings() -> list[tuple[tuple[str, ...], tuple[str, ...]]]:
    """(flags, libraries) to try, fastest first."""
    out = []
    if _mvec_available():
        out.append(((*FAST_FLAGS, "-DSOFTPINN_MVEC"), ("-lmvec",)))
    out.append((FAST_FLAGS, ()))
    out.append((PLAIN_FLAGS, ()))
    return out


_failed: set[tuple] = set()  # settings whose compile failed in this process (not retried)
_lock = threading.Lock()


@dataclass
class Library:
    """A compiled kernel library: the ctypes handle and how it was made."""

    cdll: ctypes.CDLL
    path: Path
    flags: tuple[str, ...]
    from_cache: bool
    compile_seconds: float = 0.0
    info: dict = field(default_factory=dict)


def build(source: str, tag: str, *, directory=None, compiler=None,
          timeout: float = DEFAULT_TIMEOUT) -> Library | None:
    """Compile ``source`` (cached by its content, the compiler and the flags) and load it;
    None when no compiler is found. The fastest setting that compiles wins (vectorised with
    libmvec, vectorised, plain)."""
    cc = find_compiler(compiler)
    if cc is None:
        return None
    last_error: CompilerError | None = None
    for flags, libs in _settings():
        if (cc, flags) in _failed:
            continue
        h = hashlib.sha256(f"kernel {VERSION}\0{cc}\0{' '.join(flags + libs)}\0{ca.__version__}"
                           f"\0".encode() + source.encode()).hexdigest()[:24]
        cache = open_cache(directory)
        root = cache / f"kernel_{h}"
        library = root / f"{tag}_{h}.so"
        from_cache = library.is_file()
        seconds = 0.0
        if not from_cache:
            remove_stale_builds(cache)
            try:
                root.mkdir(parents=True, exist_ok=True)
                work = Path(tempfile.mkdtemp(prefix=f".build-{outputs.owner_tag()}-", dir=root))
            except OSError as exc:
                raise CompilerError(f"the compiled-code cache {cache} cannot be written "
                                    f"({exc.strerror or type(exc).__name__}; set "
                                    "SOFTPINN_CACHE to a writable folder)") from None
            try:
                src = work / f"{tag}_{h}.c"
                src.write_text(source)
                try:
                    seconds = compile_c(src, work / library.name, compiler=cc, flags=flags,
                                        timeout=timeout, libraries=libs)
                except CompilerTimeout:
                    raise
                except CompilerError as exc:
                    _failed.add((cc, flags))
                    last_error = exc
                    continue
                (work / "kernel.json").write_text(json.dumps(
                    {"compiler": cc, "flags": list(flags), "libraries": list(libs),
                     "version": VERSION, "casadi": ca.__version__}, indent=1))
                os.replace(work / "kernel.json", root / "kernel.json")
                os.replace(src, root / src.name)
                os.replace(work / library.name, library)
            finally:
                shutil.rmtree(work, ignore_errors=True)
        cdll = ctypes.CDLL(str(library))
        return Library(cdll=cdll, path=library, flags=flags + libs, from_cache=from_cache,
                       compile_seconds=seconds)
    raise last_error or CompilerError("no compiler setting worked")


_PTRS = ctypes.c_void_p


def _aligned(shape: tuple[int, int]) -> np.ndarray:
    """An uninitialised C-contiguous float64 array whose data start 64-byte aligned."""
    size = shape[0] * shape[1]
    raw = np.empty(size + 8)
    off = (-raw.ctypes.data % 64) // 8
    return raw[off : off + size].reshape(shape)


class Kernel:
    """One batched Function: ``kernel(*inputs)`` with input k an array (N, nnz_in[k]) (or
    (nnz_in[k],), broadcast) returns the outputs' nonzeros, one (N, nnz_out[k]) array each;
    :meth:`dense` gives them shaped (N, rows, cols)."""

    def __init__(self, f: ca.Function, library: Library, symbol: str):
        self.name = f.name()
        self.n_in, self.n_out = f.n_in(), f.n_out()
        self.nnz_in = [f.nnz_in(k) for k in range(self.n_in)]
        self.sparsity_out = [f.sparsity_out(k) for k in range(self.n_out)]
        self.library = library
        self._fn = getattr(library.cdll, symbol)
        self._fn.restype = None
        self._fn.argtypes = [ctypes.c_long, ctypes.c_long, _PTRS, _PTRS]

    def nonzeros_soa(self, args: Sequence[np.ndarray], n: int) -> list[np.ndarray]:
        """Inputs as (nnz_in[k], n) arrays; outputs (nnz_out[k], n). The batch is padded to a
        multiple of :data:`WIDTH` in 64-byte aligned buffers, so that every state runs the
        vector code: a state's result is the same bits wherever it sits in any batch."""
        ins = [np.asarray(a, dtype=np.float64) for a in args]
        for a, nnz in zip(ins, self.nnz_in, strict=True):
            if a.shape != (nnz, n):
                raise KernelError(f"{self.name}: expected an input of shape {(nnz, n)}, "
                                  f"got {a.shape}")
        if n == 0:
            return [np.empty((sp.nnz(), 0)) for sp in self.sparsity_out]
        ld = -(-n // WIDTH) * WIDTH
        bufs = []
        for a in ins:
            b = _aligned((a.shape[0], ld))
            b[:, :n] = a
            b[:, n:] = 0.0
            bufs.append(b)
        outs = [_aligned((sp.nnz(), ld)) for sp in self.sparsity_out]
        a_ptr = (_PTRS * max(self.n_in, 1))(*[a.ctypes.data for a in bufs])
        r_ptr = (_PTRS * max(self.n_out, 1))(*[o.ctypes.data for o in outs])
        self._fn(ld, ld, a_ptr, r_ptr)
        return [o[:, :n] for o in outs]

    def __call__(self, *args) -> list[np.ndarray]:
        if len(args) != self.n_in:
            raise KernelError(f"{self.name}: expected {self.n_in} inputs, got {len(args)}")
        arrays = [np.asarray(a, dtype=np.float64) for a in args]
        n = max((a.shape[0] for a in arrays if a.ndim == 2), default=1)
        soa = []
        for a, nnz in zip(arrays, self.nnz_in, strict=True):
            if a.ndim != 2:
                a = np.broadcast_to(a.reshape(1, nnz), (n, nnz))
            soa.append(a.T)
        return [o.T for o in self.nonzeros_soa(soa, n)]

    def dense(self, k: int, nonzeros: np.ndarray) -> np.ndarray:
        """Output ``k``'s nonzeros (N, nnz) as dense (N, rows, cols)."""
        sp = self.sparsity_out[k]
        rows, cols = sp.size1(), sp.size2()
        n = nonzeros.shape[0]
        if sp.is_dense():
            return nonzeros.reshape(n, cols, rows).transpose(0, 2, 1)
        out = np.zeros((n, rows, cols))
        r, c = sp.get_triplet()
        out[:, r, c] = nonzeros
        return out


def kernels(fns: Mapping[str, ca.Function], *, directory=None, compiler=None,
            timeout: float = DEFAULT_TIMEOUT) -> dict[str, Kernel] | None:
    """Batched kernels of every Function of ``fns`` in one library (compiled once per machine,
    then loaded from the cache); None without a C compiler."""
    parts, symbols = [HEADER], {}
    for i, key in enumerate(sorted(fns)):
        symbols[key] = f"softpinn_k{i}"
        parts.append(kernel_source(fns[key], symbols[key]))
    with _lock:
        lib = build("".join(parts), "kernels", directory=directory, compiler=compiler,
                    timeout=timeout)
    if lib is None:
        return None
    return {key: Kernel(expand(fns[key]), lib, symbols[key]) for key in fns}


class RK4:
    """Fixed-step RK4 of many trajectories in C: ``rk4(x0 (K, nx), p (K, np), samples, sub, dt,
    rate, threads)`` -> x (K, samples, nx); trajectories split over ``threads`` Python threads
    (ctypes releases the GIL)."""

    def __init__(self, ode: ca.Function, signal: ca.Function, *, extra: Mapping[str,
                 ca.Function] | None = None, directory=None, compiler=None,
                 timeout: float = DEFAULT_TIMEOUT):
        """``extra``: more Functions compiled into the same library, as :class:`Kernel`
        objects in ``self.kernels`` (with ``"ode"`` and ``"signal"``)."""
        extra = dict(extra or {})
        parts, symbols = [HEADER, rk4_source(ode, signal)], {}
        for i, key in enumerate(sorted(extra)):
            symbols[key] = f"softpinn_x{i}"
            parts.append(kernel_source(extra[key], symbols[key]))
        with _lock:
            lib = build("".join(parts), "rk4", directory=directory, compiler=compiler,
                        timeout=timeout)
        if lib is None:
            raise CompilerError("no C compiler found")
        self.library = lib
        self.kernels = {"ode": Kernel(dense(expand(ode)), lib, "softpinn_ode"),
                        "signal": Kernel(dense(expand(signal)), lib, "softpinn_signal")}
        self.kernels.update({k: Kernel(expand(f), lib, symbols[k]) for k, f in extra.items()})
        self.nx = ode.nnz_in(0)
        self.np = signal.nnz_in(1) if signal.n_in() > 1 else 0
        self._fn = lib.cdll.softpinn_rk4
        self._fn.restype = None
        L, D = ctypes.c_long, ctypes.c_double
        self._fn.argtypes = [L, L, L, L, _PTRS, _PTRS, L, L, D, D, _PTRS]
        self._nu = ode.nnz_in(1)

    def __call__(self, x0: np.ndarray, p: np.ndarray, samples: int, sub: int, dt: float,
                 rate: float, threads: int = 1) -> np.ndarray:
        x0 = np.ascontiguousarray(np.asarray(x0, dtype=np.float64).reshape(-1, self.nx))
        K = x0.shape[0]
        p = np.asarray(p, dtype=np.float64).reshape(K, self.np)
        out = np.empty((K, samples, self.nx))
        parts = [ix for ix in np.array_split(np.arange(K), max(1, min(threads, K))) if len(ix)]

        def run(ix):
            xa = np.ascontiguousarray(x0[ix].T)
            pa = np.ascontiguousarray(p[ix].T) if self.np else np.zeros((1, len(ix)))
            o = np.empty((samples, self.nx, len(ix)))
            self._fn(len(ix), self.nx, self._nu, self.np, xa.ctypes.data, pa.ctypes.data,
                     samples, sub, dt, rate, o.ctypes.data)
            out[ix] = o.transpose(2, 0, 1)

        if len(parts) <= 1:
            for ix in parts:
                run(ix)
        else:
            with ThreadPoolExecutor(len(parts)) as pool:
                list(pool.map(run, parts))
        return out


def available(compiler=None) -> bool:
    """Whether a C compiler is found (kernels can be built)."""
    return find_compiler(compiler) is not None


__all__ = ["FAST_FLAGS", "PLAIN_FLAGS", "RK4", "Kernel", "KernelError", "Library", "available",
           "build", "expand", "kernel_source", "kernels", "rk4_source"]
