"""The CasADi -> JAX translation of the exact model (softpinn.bridge.exact): equal to CasADi to
1e-12 at random states (theta = 0 of the delta parameterization included), and jit, vmap, grad
and float32 work."""

from __future__ import annotations

import casadi as ca
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from softpinn.bridge.exact import ExactModel, TranslationError, dynamics, jax_model, translate
from softpinn.symbolic import SIGNATURES, TrueModel

jax.config.update("jax_enable_x64", True)


def _close(got, ref, tol=1e-12):
    got, ref = np.asarray(got, dtype=float), np.asarray(ref, dtype=float)
    assert got.shape == ref.shape, (got.shape, ref.shape)
    scale = max(1.0, float(np.max(np.abs(ref), initial=0.0)))
    err = float(np.max(np.abs(got - ref), initial=0.0))
    assert err <= tol * scale, f"error {err:.3g} at scale {scale:.3g}"


def _states(name, n, m, count=4, seed=0):
    rng = np.random.default_rng(seed)
    q = rng.uniform(-0.4, 0.4, (count, n))
    q[0] = 0.0  # straight: theta = 0 of the delta parameterization
    return q, rng.uniform(-0.5, 0.5, (count, n)), rng.uniform(-1, 1, (count, m))


_ARGS = {"q": 0, "qd": 1, "u": 2, "p": 1, "qdd": 1}


@pytest.mark.parametrize("name", ["task1", "task3", "task4"])
def test_every_function_equals_casadi(name):
    em, tm = jax_model(name), TrueModel(name)
    n, m = em.n, em.m
    q, qd, u = _states(name, n, m)
    for key, (ins, _) in SIGNATURES.items():
        f = tm.functions[key]
        prog = em.program(key)
        for i in range(len(q)):
            if key == "ode":
                args = [np.r_[q[i], qd[i]], u[i]]
            else:
                args = [(q, qd, u)[_ARGS[a]][i] if a != "qdd" else qd[i] * 3
                        for a in ins]
            ref = f(*args)
            ref = ref if isinstance(ref, tuple) else (ref,)
            got = prog(*args)
            for j, r in enumerate(ref):
                r = np.asarray(r)  # (rows, cols) as CasADi
                _close(np.asarray(got[j]).reshape(r.shape), r)


def test_methods_shapes_and_named_faces_task4():
    em, tm = jax_model("task4"), TrueModel("task4")
    q, qd, u = _states("task4", 3, 3, count=1, seed=3)
    q, qd, u = q[0] + 0.1, qd[0], u[0]
    _close(em.M(q), tm.M(q))
    _close(em.M_inv(q), tm.M_inv(q))
    _close(em.A(q), tm.A(q))
    _close(em.C(q, qd), tm.C(q, qd))
    _close(em.qdd(q, qd, u), tm.qdd(q, qd, u))
    _close(em.tau(q, qd, em.qdd(q, qd, u)), tm.A(q) @ u)
    assert em.energy(q, qd).shape == ()
    _close(em.energy(q, qd), tm.energy(q, qd))
    qdot, pdot = em.hamiltonian(q, tm.momentum(q, qd), u)
    _close(qdot, qd)
    assert em.A(q).shape == (3, 3) and jax_model("task1").A(np.zeros(2)).shape == (2, 0)
    assert jax_model("task4") is em and repr(em) == "ExactModel('task4', n=3, m=3)"


def test_jit_vmap_grad_and_float32():
    em = jax_model("task4")
    q, qd, u = _states("task4", 3, 3, count=6, seed=1)
    ref = TrueModel("task4").qdd(q, qd, u)
    _close(jax.jit(jax.vmap(em.qdd))(q, qd, u), ref)
    # grad of the potential is G (eqs. 21-24), of the kinetic energy in qd the momentum M qd
    for i in (0, 3):
        _close(jax.grad(em.potential)(q[i]), em.G(q[i]), 1e-10)
        _close(jax.grad(em.kinetic, argnums=1)(q[i], qd[i]), em.momentum(q[i], qd[i]), 1e-10)
    # forward-mode and reverse-mode derivatives of the dynamics agree
    jf = jax.jacfwd(em.qdd)(q[2], qd[2], u[2])
    jr = jax.jacrev(em.qdd)(q[2], qd[2], u[2])
    _close(jf, jr, 1e-9)
    assert np.all(np.isfinite(jax.jacrev(em.qdd)(jnp.zeros(3), qd[0], u[0])))
    got32 = jax.vmap(em.qdd)(*(jnp.asarray(a, jnp.float32) for a in (q, qd, u)))
    assert got32.dtype == jnp.float32
    np.testing.assert_allclose(np.asarray(got32), ref, rtol=2e-3, atol=2e-3 * np.abs(ref).max())


def test_dynamics_callable_and_task5_forward_at_straight_state():
    qdd = dynamics("task5")
    tm = TrueModel("task5")
    rng = np.random.default_rng(5)
    for q in (np.zeros(6), rng.uniform(-0.3, 0.3, 6)):
        qd, u = rng.uniform(-0.2, 0.2, 6), rng.uniform(-1, 1, 6)
        _close(qdd(q, qd, u), tm.qdd(q, qd, u))
    _close(dynamics("task1")(np.ones(2), np.zeros(2)), TrueModel("task1").qdd(np.ones(2),
                                                                               np.zeros(2)))


def test_elementary_operations_follow_casadi():
    x = ca.SX.sym("x", 3)
    y = ca.SX.sym("y")
    exprs = [ca.atan2(x[0], y), ca.fmod(x[1] * 7, y), ca.if_else(x[0] < y, ca.exp(x[1]),
             ca.log(y)), ca.sign(x[2] - x[2]), ca.fabs(x[1]), ca.fmin(x[0], y),
             ca.fmax(x[0], y), ca.logic_and(x[0] > 0, y > 0), ca.logic_or(x[0] > 0, y > 0),
             ca.logic_not(x[0] <= 0), x[0] == y, x[0] != y, ca.tanh(x[1]) + ca.sinh(x[2]),
             ca.cosh(x[0]) * ca.asinh(y) + ca.arctan(x[1]) - ca.arcsin(x[0]) / ca.arccos(x[2]),
             x[1] ** 3 + ca.fabs(x[0]) ** y + ca.sqrt(y) + 1 / x[2] + ca.tan(x[0]) + ca.erf(x[1]),
             ca.floor(x[1] * 5) + ca.ceil(x[1] * 5) + ca.atanh(x[0] / 2) + ca.acosh(1 + y),
             ca.log1p(y) + ca.expm1(x[0]) + ca.hypot(x[0], y) + ca.copysign(y, x[1]),
             ca.remainder(x[1] * 9, y)]
    f = ca.Function("ops", [x, y], [ca.vertcat(*exprs), ca.DM([[1.0, 0.0], [0.0, 2.0]])])
    prog = translate(f)
    for xv, yv in (([0.3, -0.7, 0.4], 1.3), ([-0.2, 0.6, -0.5], 0.7)):
        ref = f(xv, yv)
        got = prog(jnp.asarray(xv), jnp.asarray([yv]))
        _close(got[0], np.asarray(ref[0]).ravel(), 1e-14)
        _close(got[1], np.asarray(ref[1]))


def test_bad_inputs_name_what_is_wrong():
    em = ExactModel("task1")
    with pytest.raises(TranslationError, match="expected 3 inputs"):
        em.program("forward")(np.zeros(2))
    with pytest.raises(TranslationError, match="input 'q' expected 2 values, got 3"):
        em.M(np.zeros(3))
    with pytest.raises(TranslationError, match="key: expected one of"):
        em.program("nope")
    lut = ca.interpolant("lut", "bspline", [[0.0, 1.0, 2.0, 3.0]], [0.0, 1.0, 4.0, 9.0])
    x = ca.MX.sym("x")
    with pytest.raises(TranslationError, match="h: instruction 1 is CasADi's OP_CALL"):
        translate(ca.Function("h", [x], [lut(x)]))
