"""What a simulation computes at every output sample besides the state: q̈ (eq. 4), p = M q̇
and M, from the batched C kernels of :mod:`symbolic.codegen._kernel` where the model's functions
are compiled, else from one mapped CasADi call; and the C kernels' RK4 for
:mod:`symbolic.simulation._simulate`.
"""

from __future__ import annotations

from collections.abc import Mapping
from concurrent.futures import ThreadPoolExecutor

import casadi as ca
import numpy as np

from softpinn.symbolic.codegen import _codegen as codegen
from softpinn.symbolic.codegen import _kernel as kernel
from softpinn.symbolic.codegen._compiler import CompilerError
from softpinn.symbolic.simulation._signals import Signal

__all__ = ["batched", "condition_numbers", "post_function", "postprocess", "kernel_rk4",
           "kernel_post", "kernel_postprocess", "in_threads"]


def post_function(fns: Mapping[str, ca.Function], n: int, m: int) -> ca.Function | None:
    """SX ``post(x, u) -> [qdd; p; vec(M)]`` from the sources of compiled ``forward``,
    ``momentum`` and ``M`` (None for uncompiled functions, or where there is no source)."""
    srcs = {}
    for key in ("forward", "momentum", "M"):
        if key not in fns:
            return None
        srcs[key] = codegen.source_of(fns[key])
        if srcs[key] is fns[key] or not srcs[key].is_a("SXFunction") and \
                not srcs[key].is_a("MXFunction"):
            return None  # not compiled (the caller asked for CasADi) or unknown
    try:
        fwd, mom, mass = (kernel.expand(srcs[k]) for k in ("forward", "momentum", "M"))
    except kernel.KernelError:
        return None
    x, u = ca.SX.sym("x", 2 * n), ca.SX.sym("u", m)
    q, qd = x[:n], x[n:]
    out = ca.vertcat(fwd(q, qd, u), mom(q, qd), ca.reshape(mass(q), n * n, 1))
    return ca.Function("post", [x, u], [ca.densify(out)], ["x", "u"], ["post"])


def kernel_rk4(ode, signal: Signal, post_fn) -> kernel.RK4 | None:
    """The C kernels' RK4 for compiled functions (None: CasADi's)."""
    src = codegen.source_of(ode)
    if post_fn is None or src is ode:
        return None
    try:
        return kernel.RK4(src, signal.function(), extra={"post": post_fn})
    except (kernel.KernelError, CompilerError):
        return None


def kernel_post(post_fn) -> kernel.Kernel | None:
    try:
        built = kernel.kernels({"post": post_fn})
    except (kernel.KernelError, CompilerError):
        return None
    return None if built is None else built["post"]


def in_threads(part, N: int, threads: int) -> None:
    """Call ``part(ix)`` on up to ``threads`` contiguous index blocks of range(N) at once (the
    C kernels release the GIL, so the blocks run on as many cores)."""
    parts = [ix for ix in np.array_split(np.arange(N), max(1, min(threads, N))) if len(ix)]
    if len(parts) > 1:
        with ThreadPoolExecutor(len(parts)) as pool:
            list(pool.map(part, parts))
    else:
        for ix in parts:
            part(ix)


def kernel_postprocess(post: kernel.Kernel, x, u, n, threads):
    """(qdd, p, M) at N samples from the post kernel, N split over ``threads`` threads."""
    N = len(x)
    res = np.empty((N, 2 * n + n * n))

    def part(ix):
        res[ix] = post(x[ix], u[ix])[0]

    in_threads(part, N, threads)
    mass = res[:, 2 * n :].reshape(-1, n, n).transpose(0, 2, 1)
    return res[:, :n], res[:, n : 2 * n], mass


def postprocess(fns, x, u, n, threads):
    """qdd = forward(q, qd, u), p = M(q) qd (and M where the model's functions include
    ``"outputs"(q, qd, u) -> (qdd, p, M)``, which shares the work) at every sample: one mapped
    call. Returns (qdd, p, M or None)."""
    xs = ca.MX.sym("x", 2 * n)
    us = ca.MX.sym("u", u.shape[1])
    q, qd = xs[:n], xs[n:]
    if "outputs" in fns:
        qdd, p, mass = fns["outputs"](q, qd, us)
        outs = [qdd, p, ca.reshape(mass, n * n, 1)]
    else:
        outs = [fns["forward"](q, qd, us), fns["momentum"](q, qd)]
    post = ca.Function("post", [xs, us], [ca.vertcat(*outs)])
    res = batched(post, x, u, threads=threads)
    mass = res[:, 2 * n :].reshape(-1, n, n).transpose(0, 2, 1) if "outputs" in fns else None
    return res[:, :n], res[:, n : 2 * n], mass


def batched(fn: ca.Function, *args: np.ndarray, threads: int = 1) -> np.ndarray:
    """Evaluate ``fn`` (first output) on N rows at once with ``Function.map``; returns (N, ...).

    Each argument is (N, size) (a row per sample). A matrix-valued output comes back as
    (N, rows, cols).
    """
    nrows = args[0].shape[0]
    if nrows == 0:
        return np.zeros((0,) + fn.size_out(0))
    fm = fn.map(nrows, "thread", threads) if threads > 1 else fn.map(nrows)
    ins = [np.asarray(a, dtype=float).reshape(nrows, -1).T for a in args]
    out = np.asarray(fm(*ins) if fn.n_out() == 1 else fm(*ins)[0])
    r, c = fn.size_out(0)
    if c == 1:
        return out.reshape(r, nrows).T
    return out.reshape(r, nrows, c).transpose(1, 0, 2)


def condition_numbers(mats: np.ndarray) -> np.ndarray:
    """cond_2 of symmetric matrices (..., n, n) from their eigenvalues; inf if singular."""
    if mats.size == 0:
        return np.zeros(mats.shape[:-2])
    mats = np.nan_to_num(mats, nan=np.inf)
    if not np.all(np.isfinite(mats)):
        return np.where(np.all(np.isfinite(mats), axis=(-1, -2)), 0.0, np.inf)
    ev = np.abs(np.linalg.eigvalsh(mats))
    with np.errstate(divide="ignore"):
        return np.where(ev.min(-1) > 0, ev.max(-1) / np.maximum(ev.min(-1), 1e-300), np.inf)
