"""Batched forward dynamics (TrueModel.qdd on a batch: the C kernels of
softpinn.symbolic.codegen._kernel) equal CasADi's own evaluation of the same Function to 1e-13
relative per state, on the models of benchmarks/bench_peers.py (planar PCC of 1 and 2 segments,
task5) including straight and nearly straight arms (the Taylor branches); the kernels'
shared reciprocals (one division per divisor that divides several times) keep CasADi's results
for zero, signed-zero, infinite and NaN divisors, their branchless if_else for NaN, signed-zero
and infinite conditions and branches."""

from __future__ import annotations

import re

import casadi as ca
import numpy as np
import pytest

from softpinn.symbolic import TrueModel, load_spec
from softpinn.symbolic.codegen import _extended
from softpinn.symbolic.codegen import _kernel as kernel
from softpinn.symbolic.codegen._kernel_source import shared_denominators
from softpinn.symbolic.spec._spec import spec_from_dict

pytestmark = pytest.mark.usefixtures("session_cache")

#: per state: max |kernel - CasADi| / max |CasADi| over the state's q̈
TOLERANCE = 1e-13


def _planar(segments: int):
    seg = {"length": 0.5, "mass": 0.5, "stiffness": [10.0, 10.0], "damping": [0.4, 0.4]}
    return spec_from_dict({"name": f"planar{segments}", "kind": "planar-pcc",
                           "gravity": [0.0, 9.81], "actuation": "none",
                           "segment": [seg] * segments}, source="test")


def _states(n: int, m: int, batch: int, seed: int):
    rng = np.random.default_rng(seed)
    q = rng.uniform(-0.3, 0.3, (batch, n))
    q[:8] = 0.0  # straight
    q[8:16] *= 1e-9  # nearly straight: the series branches
    q[16:24] *= 1e-3
    return q, rng.uniform(-0.2, 0.2, (batch, n)), rng.uniform(-0.3, 0.3, (batch, m))


@pytest.mark.parametrize("model", ["planar1", "planar2", "task5"])
def test_batched_forward_dynamics_equal_casadi_per_state(model):
    spec = load_spec("task5") if model == "task5" else _planar(int(model[-1]))
    tm = TrueModel(spec)
    batch = 203  # above TrueModel.COMPILE_FROM, no multiple of the vector width
    q, qd, u = _states(spec.n, spec.m, batch, seed=len(model))
    got = tm.qdd(q, qd, u)
    assert tm._kernels.get("forward") is not None  # the batch ran in the C kernel
    fwd = tm.functions["forward"]
    want = np.asarray(fwd.map(batch)(q.T, qd.T, u.T)).T  # CasADi's interpreter
    assert got.shape == want.shape == (batch, spec.n)
    per_state = np.max(np.abs(got - want), axis=1) / np.max(np.abs(want), axis=1)
    assert per_state.max() <= TOLERANCE, (model, per_state.max())
    # one state alone (CasADi's interpreter path of TrueModel) agrees with its batch row
    np.testing.assert_allclose(tm.qdd(q[3], qd[3], u[3]), got[3], rtol=0, atol=TOLERANCE
                               * np.max(np.abs(want[3])))


def test_planar_kernel_divides_once_per_divisor():
    """One segment: 205 divisions by 32 distinct values per state in CasADi's instruction list;
    the kernel's source inverts each of those values once."""
    spec = _planar(1)
    f = kernel.expand(TrueModel(spec).functions["forward"])
    divisions = sum(f.instruction_id(k) == ca.OP_DIV for k in range(f.n_instructions()))
    shared = shared_denominators(f)
    src = kernel.kernel_source(f, "k")
    body = src.split("#pragma omp simd", 1)[1]
    reciprocals = len(re.findall(r"double d\d+ = 1\./t\d+;", body))
    assert reciprocals == len(shared) > 0
    assert body.count("/t") - reciprocals < divisions - len(shared)


def test_shared_reciprocals_keep_casadis_special_values():
    x = ca.SX.sym("x", 3)
    a, b, d = x[0], x[1], x[2]
    # d divides four times (shared), a once (plain division)
    f = ca.Function("div", [x], [ca.vertcat(a / d, b / d, (a + b) / d, 1 / d, b / a,
                                            ca.if_else(d > 0, a / d, 0.0))])
    assert len(shared_denominators(f)) == 1
    k = kernel.kernels({"div": f})["div"]
    rows = np.array([[1.0, 2.0, 0.0], [1.0, -2.0, -0.0], [0.0, 1.0, 0.0], [1.0, 2.0, np.inf],
                     [np.inf, 1.0, np.inf], [1.0, 2.0, np.nan], [3.0, -1.5, 0.25],
                     [-0.0, 2.0, -3.0], [1e-300, 1e300, 1e-8]])
    got = k(rows)[0]
    want = np.asarray(f.map(rows.shape[0])(rows.T)).T
    assert np.array_equal(np.isnan(got), np.isnan(want))
    fin = np.isfinite(want)
    assert np.array_equal(got[~fin & ~np.isnan(want)], want[~fin & ~np.isnan(want)])
    np.testing.assert_allclose(got[fin], want[fin], rtol=1e-15, atol=0)


def test_the_cuda_kernel_is_the_c_kernel_with_one_thread_per_state():
    """bench_gpu.py's CUDA kernel (NVRTC on a GPU machine; no CUDA compiler here): the same
    straight-line body as the C kernel, the state loop replaced by the thread's index."""
    import casadi as ca

    from softpinn.symbolic.codegen._kernel_source import cuda_source, kernel_source

    x = ca.SX.sym("x", 2)
    f = ca.Function("f", [x], [ca.vertcat(ca.sin(x[0]) / x[1], x[0] / x[1] + ca.cos(x[1]),
                                          ca.if_else(x[0] < 1, x[1], 2 * x[1]))])
    c, cu = kernel_source(f, "f"), cuda_source(f, "f")
    helper, kern = cu.split("#endif\n", 1)  # softpinn_if as a device function, then the kernel
    assert "__device__" in helper and "softpinn_if" in helper
    assert kern.startswith('extern "C" __global__ void f(long n, long ld, const double* const* '
                           "arg, double* const* res) {")
    assert "long i = (long)blockIdx.x * blockDim.x + threadIdx.x;\n  if (i < n) {" in cu
    assert "#pragma omp" not in cu and "restrict " not in cu and "SOFTPINN_ALIGNED" not in cu
    body = lambda s: s[s.index("    double t"):]  # noqa: E731
    assert body(cu) == body(c)
    assert "softpinn_if(" in c


def test_branchless_if_else_keeps_casadis_results():
    """CasADi's if_else (two OP_IF_ELSE_ZERO and a sum) through the kernels' branchless
    softpinn_if: a NaN condition counts as true, a signed zero as false, and the branch not
    taken may be infinite or NaN without reaching the result."""
    x = ca.SX.sym("x", 3)
    c, a, b = x[0], x[1], x[2]
    f = ca.Function("sel", [x], [ca.vertcat(ca.if_else(c, a, b), ca.if_else(c < 0.5, a / c, b),
                                            ca.if_else(ca.logic_not(c), ca.sin(a), b * b))])
    assert any(f.instruction_id(k) == ca.OP_IF_ELSE_ZERO for k in range(f.n_instructions()))
    k = kernel.kernels({"sel": f})["sel"]
    rows = np.array([[1.0, 2.0, 3.0], [0.0, 2.0, 3.0], [-0.0, np.inf, 3.0],
                     [np.nan, 2.0, np.inf], [0.25, np.nan, 1.0], [2.0, 1.0, np.nan],
                     [np.inf, -0.0, 1.0], [0.0, np.inf, -np.inf], [-1e-300, 1.0, 2.0]])
    got = k(rows)[0]
    want = np.asarray(f.map(rows.shape[0])(rows.T)).T
    assert np.array_equal(np.isnan(got), np.isnan(want))
    fin = np.isfinite(want)
    assert np.array_equal(got[~fin & ~np.isnan(want)], want[~fin & ~np.isnan(want)])
    np.testing.assert_allclose(got[fin], want[fin], rtol=1e-15, atol=0)  # sin: libmvec, 4 ulp


def test_large_kernels_keep_the_remainder_loop_and_equal_casadi(monkeypatch):
    """Above _kernel_source.LARGE instructions (here: the planar arm of one segment with the
    limit at 0) the kernel keeps C's ?: and the scalar remainder loop (gcc's fast register
    allocation), with the same results."""
    from softpinn.symbolic.codegen import _kernel_source

    monkeypatch.setattr(_kernel_source, "LARGE", 0)
    f = kernel.expand(TrueModel(_planar(1)).functions["forward"])
    body = kernel.kernel_source(f, "k").split("#pragma omp simd", 1)[1]
    assert "for (long i = 0; i < n; ++i)" in body and "?" in body
    assert "softpinn_if(" not in body
    k = kernel.kernels({"forward": f})["forward"]
    q, qd, u = _states(2, 0, 37, seed=5)
    got = k(q, qd, u)[0]
    want = np.asarray(f.map(37)(q.T, qd.T, u.T)).T
    per_state = np.max(np.abs(got - want), axis=1) / np.max(np.abs(want), axis=1)
    assert per_state.max() <= TOLERANCE, per_state.max()


@pytest.mark.skipif(not _extended.available(),
                    reason="needs a C compiler and a long double finer than double")
@pytest.mark.parametrize("model", ["planar2", "task5"])
def test_kernels_are_as_close_to_the_exact_value_as_casadi(model):
    """Against the forward dynamics in long double (the exact value of the same function to
    ~1e-19 times its condition): the kernel's per-state error stays within 1e-13 and within a
    few times CasADi's own, including the straight and nearly straight arms."""
    spec = load_spec("task5") if model == "task5" else _planar(int(model[-1]))
    tm = TrueModel(spec)
    q, qd, u = _states(spec.n, spec.m, 400, seed=7)
    fwd = tm.functions["forward"]
    got = kernel.kernels({"forward": fwd})["forward"].nonzeros_soa([q.T, qd.T, u.T], 400)[0]
    exact = _extended.extended(fwd, q.T, qd.T, u.T)[0]
    casadi = np.asarray(fwd.map(400)(q.T, qd.T, u.T))
    scale = np.max(np.abs(exact), axis=0)
    err = {k: (np.max(np.abs(x - exact), axis=0) / scale).astype(np.float64)
           for k, x in (("kernel", got), ("casadi", casadi))}
    assert 0 < err["casadi"].max() <= TOLERANCE  # the reference is finer than double
    assert err["kernel"].max() <= TOLERANCE, err["kernel"].max()
    assert err["kernel"].max() <= 8 * err["casadi"].max(), (err["kernel"].max(),
                                                            err["casadi"].max())


def test_extended_precision_evaluates_a_known_function():
    """1/(3 + x) + sin(x) in long double, to the long double's own rounding (a double
    evaluation is 2,000 times coarser)."""
    x = ca.SX.sym("x")
    f = ca.Function("f", [x], [1.0 / (3.0 + x) + ca.sin(x)])
    xs = np.array([[0.0, 0.5, 1e-3]])
    got = _extended.extended(f, xs)[0]
    assert got.dtype == np.longdouble and got.shape == (1, 3)
    xl = xs.astype(np.longdouble)
    want = np.longdouble(1) / (np.longdouble(3) + xl) + np.sin(xl)
    assert np.max(np.abs(got - want)) <= 4 * np.finfo(np.longdouble).eps
    double = np.asarray(f.map(3)(xs))
    assert np.max(np.abs(double - want)) > 16 * np.finfo(np.longdouble).eps
