"""Batched C kernels (softpinn.symbolic.codegen._kernel): equal to CasADi to 1e-12 for every
instruction they write (CasADi's C semantics: sign(0), if_else_zero with a NaN in the unused branch,
comparisons as 1/0, non-finite constants), batches that are no multiple of the vector width, sparse
and matrix outputs, the fallbacks (plain flags when the fast ones fail, None without a compiler) and
the RK4 driver against CasADi's rk4."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from softpinn.symbolic import load_spec
from softpinn.symbolic.codegen import _kernel as kernel
from softpinn.symbolic.model._functions import functions
from softpinn.symbolic.simulation._datasets import data_config, draw_trajectories
from softpinn.symbolic.simulation._sim_config import SimulationConfig
from softpinn.symbolic.simulation._simulate import simulate


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("SOFTPINN_CACHE", str(tmp_path / "cache"))


def _ops_function() -> ca.Function:
    x = ca.SX.sym("x", 3)
    a, b, c = x[0], x[1], x[2]
    exprs = [
        ca.sin(a) * ca.cos(a), ca.cos(b), ca.exp(a) + ca.log(1 + b * b), ca.sqrt(1 + c * c),
        a**2, 2 * b, 1 / (2 + c), ca.tan(0.3 * a), ca.asin(0.5 * ca.tanh(b)),
        ca.acos(0.5 * ca.tanh(c)), ca.atan(a), ca.floor(3 * a), ca.ceil(3 * b), ca.fabs(c),
        ca.sign(a), ca.sign(a - a), ca.erf(b), ca.sinh(a), ca.cosh(b), ca.tanh(c),
        ca.asinh(a), ca.acosh(2 + b * b), ca.atanh(0.5 * ca.tanh(a)), ca.log1p(b * b),
        ca.expm1(c), ca.power(1.5 + ca.sin(a), b), a**3, ca.atan2(a, b), ca.fmin(a, b),
        ca.fmax(b, c), ca.fmod(3 * a, 0.7), ca.remainder(3 * b, 0.7), ca.copysign(a, b),
        ca.hypot(a, c), a < b, a <= b, a == a, a != b, ca.logic_and(a < b, b < c),
        ca.logic_or(a < b, b < c), ca.logic_not(a < b),
        ca.if_else(a < 0.1, b, ca.sqrt(a - 0.1)),  # NaN in the branch not taken
        ca.inf * (a - a + 1), -ca.inf + 0 * b, ca.pi * c,
        a == ca.floor(3 * a), ca.constpow(1.5 + a, 3.0), -ca.sin(c),
    ]
    return ca.Function("ops", [x], [ca.vertcat(*exprs)])


def test_every_instruction_equals_casadi():
    f = _ops_function()
    k = kernel.kernels({"ops": f})["ops"]
    rng = np.random.default_rng(0)
    x = rng.uniform(-1, 1, (37, 3))  # no multiple of 4 or 8: the scalar tail too
    x[0, 0] = 0.0
    want = np.asarray(f.map(37)(x.T)).T
    got = k(x)[0]
    assert got.shape == want.shape == (37, f.nnz_out(0))
    same_nan = np.isnan(got) == np.isnan(want)
    assert same_nan.all()
    fin = np.isfinite(want)
    assert np.array_equal(got[~fin & ~np.isnan(want)], want[~fin & ~np.isnan(want)])
    err = np.abs(got[fin] - want[fin]) / np.maximum(1.0, np.abs(want[fin]))
    assert err.max() <= 1e-12
    assert not np.isnan(got[:, 41]).any()  # if_else_zero: the unused NaN branch stays out


def test_a_states_bits_do_not_depend_on_its_place_in_the_batch():
    """Batches are padded to whole vectors: no state runs a scalar remainder (glibc's scalar
    sin is not libmvec's to the bit), so farming out or chunking never changes a result."""
    x = ca.SX.sym("x", 2)
    f = ca.Function("trig", [x], [ca.vertcat(*[ca.sin(x[0] * i + x[1]) * ca.cos(x[1] * i - x[0])
                                               for i in range(1, 40)])])
    k = kernel.kernels({"trig": f})["trig"]
    x = np.random.default_rng(4).uniform(-3, 3, (37, 2))
    whole = k(x)[0]
    for part in (x[:1], x[5:12], x[::-1][:30]):
        got = k(part)[0]
        idx = [int(np.flatnonzero((x == row).all(axis=1))[0]) for row in part]
        np.testing.assert_array_equal(got, whole[idx])


def test_matrix_sparse_and_broadcast_inputs():
    x = ca.SX.sym("x", 2)
    y = ca.SX.sym("y")
    mat = ca.SX(3, 2)
    mat[0, 0], mat[2, 1], mat[1, 0] = x[0] * y, ca.sin(x[1]), x[0] + x[1]
    f = ca.Function("m", [x, y], [mat, ca.sumsqr(x)])
    k = kernel.kernels({"m": f})["m"]
    rng = np.random.default_rng(1)
    xs = rng.normal(size=(5, 2))
    nz = k(xs, np.array([2.0]))  # y broadcast
    dense = k.dense(0, nz[0])
    for i in range(5):
        np.testing.assert_allclose(dense[i], np.asarray(f(xs[i], 2.0)[0]), rtol=1e-14)
        np.testing.assert_allclose(nz[1][i, 0], float(f(xs[i], 2.0)[1]), rtol=1e-14)
    assert k(np.zeros((0, 2)), np.zeros((0, 1)))[0].shape == (0, 3)


def test_erfinv_has_no_kernel_and_no_compiler_gives_none(monkeypatch):
    x = ca.SX.sym("x")
    with pytest.raises(kernel.KernelError, match="OP_ERFINV"):
        kernel.kernel_source(ca.Function("e", [x], [ca.erfinv(x)]), "e")
    monkeypatch.setattr(kernel, "find_compiler", lambda compiler=None: None)
    assert kernel.kernels({"ops": _ops_function()}) is None


def test_failing_fast_flags_fall_back_to_plain(monkeypatch):
    monkeypatch.setattr(kernel, "_settings", lambda: [(("-fno-such-flag-softpinn",), ()),
                                                      (kernel.PLAIN_FLAGS, ())])
    monkeypatch.setattr(kernel, "_failed", set())
    f = _ops_function()
    k = kernel.kernels({"ops": f})["ops"]
    assert k.library.flags == kernel.PLAIN_FLAGS
    x = np.random.default_rng(2).uniform(-1, 1, (9, 3))
    want = np.asarray(f.map(9)(x.T)).T
    fin = np.isfinite(want)
    np.testing.assert_allclose(k(x)[0][fin], want[fin], rtol=1e-12, atol=1e-12)


def test_rk4_equals_casadis_rk4_on_two_threads():
    spec = load_spec("task1")
    fns = functions(spec)
    x0, sigs = draw_trajectories(data_config(spec), spec.n, spec.m, list(range(5)),
                                 duration=0.5)
    cfg = SimulationConfig(integrator="rk4", duration=0.5, rate=50.0, dt=0.005)
    rk = kernel.RK4(fns["ode"], sigs[0].function(), extra={"M": fns["M"]})
    p = np.stack([s.params() for s in sigs])
    got = rk(x0, p, cfg.samples, cfg.substeps, cfg.step, cfg.rate, threads=2)
    ref = simulate(fns, x0, sigs, cfg)
    assert got.shape == ref.x.shape
    assert np.max(np.abs(got - ref.x)) <= 1e-12 * max(1.0, np.max(np.abs(ref.x)))
    mass = rk.kernels["M"].dense(0, rk.kernels["M"](got[0, :, :2])[0])
    np.testing.assert_allclose(mass[3], np.asarray(fns["M"](got[0, 3, :2])), rtol=1e-13)


@pytest.mark.parametrize("integrator", ["rk4", "cvodes"])
def test_simulate_with_compiled_functions_uses_kernels(tmp_path, integrator):
    """symbolic.simulation._simulate: with compiled functions the RK4 steps and q̈, p, M run in
    kernels (the same numbers as CasADi's path on the uncompiled functions, to rounding)."""
    from softpinn.symbolic.codegen import _codegen as codegen

    spec = load_spec("task1")
    raw = functions(spec)
    fns = codegen.compiled(raw, directory=tmp_path / "cache")
    x0, sigs = draw_trajectories(data_config(spec), spec.n, spec.m, list(range(3)),
                                 duration=0.5)
    cfg = SimulationConfig(integrator=integrator, duration=0.5, rate=50.0, dt=0.005)
    got, ref = simulate(fns, x0, sigs, cfg), simulate(raw, x0, sigs, cfg)
    assert got.info["kernels"] and not ref.info["kernels"]
    for key in ("x", "qdd", "p"):
        a, b = getattr(got, key), getattr(ref, key)
        assert np.max(np.abs(a - b)) <= 1e-10 * max(1.0, np.max(np.abs(b))), key
    assert got.info["max_mass_condition"] == pytest.approx(ref.info["max_mass_condition"])
