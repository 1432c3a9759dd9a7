"""learn._integrate: RK4 order, input holds, sub-steps, rollouts with variable dt and re-sets."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from known_fields import Field, MassField

from softpinn.errors import UserError
from softpinn.learn._integrate import rk4_step, rollout, step
from softpinn.learn._models import LagrangianNet, ModelConfig


def analytic_lagrangian(n, m, M, K, D, A):
    """q̈ = M⁻¹ (A u - K q - D q̇) with constant matrices, as a LagrangianNet."""
    M, K, D, A = (jnp.asarray(a, jnp.float64) for a in (M, K, D, A))
    return LagrangianNet(
        config=ModelConfig(kind="lagrangian", n=n, m=m),
        mass=MassField(lambda q: M),
        potential=Field(lambda q: 0.5 * q @ K @ q),
        damping=Field(lambda q: D),
        input_map=Field(lambda q: A),
    )


def _slope(dts, errs):
    return np.polyfit(np.log(dts), np.log(errs), 1)[0]


def test_rk4_step_has_order_four():
    """y' = -2 t y, y(0) = 1, y(1) = e^-1 (time-dependent f: stage times are exercised)."""
    f = lambda t, y, args: -2.0 * t * y

    @jax.jit
    def solve(dt):
        def body(i, y):
            return rk4_step(f, i * dt, y, None, dt)

        return jax.lax.fori_loop(0, jnp.round(1.0 / dt).astype(int), body, jnp.ones(()))

    dts = np.array([0.1, 0.05, 0.025, 0.0125])
    errs = np.array([abs(float(solve(dt)) - np.exp(-1.0)) for dt in dts])
    assert 3.8 < _slope(dts, errs) < 4.3


def test_rollout_of_a_mass_spring_damper_converges_with_order_four():
    model = analytic_lagrangian(1, 1, [[1.0]], [[2.1]], [[0.3]], [[1.0]])
    Asys = np.array([[0.0, 1.0], [-2.1, -0.3]])
    w, V = np.linalg.eig(Asys)
    x0 = np.array([1.0, -0.5])
    exact = np.real(V @ np.diag(np.exp(w * 2.0)) @ np.linalg.solve(V, x0))
    run = jax.jit(lambda x0, u, t: rollout(model, x0, u, t))
    dts = np.array([0.2, 0.1, 0.05])
    errs = []
    for dt in dts:
        t = np.linspace(0.0, 2.0, int(round(2.0 / dt)) + 1)
        errs.append(np.linalg.norm(np.asarray(run(x0, np.zeros((len(t), 1)), t))[-1] - exact))
    assert 3.7 < _slope(dts, np.array(errs)) < 4.4


def test_input_holds_are_exact_for_a_double_integrator():
    """q̈ = u: RK4 is exact for the constant hold and for the linear interpolation."""
    model = analytic_lagrangian(2, 2, np.eye(2), np.zeros((2, 2)), np.zeros((2, 2)), np.eye(2))
    x0, u0, u1, dt = (
        jnp.array([0.1, -0.2, 0.3, 0.4]),
        jnp.array([1.0, -2.0]),
        jnp.array([3.0, 0.5]),
        0.3,
    )
    q0, v0 = x0[:2], x0[2:]
    const = step(model, x0, u0, u1, dt)
    np.testing.assert_allclose(const[:2], q0 + v0 * dt + 0.5 * u0 * dt**2, atol=1e-14)
    np.testing.assert_allclose(const[2:], v0 + u0 * dt, atol=1e-14)
    lin = step(model, x0, u0, u1, dt, input_hold="linear")
    np.testing.assert_allclose(lin[:2], q0 + v0 * dt + dt**2 * (2 * u0 + u1) / 6, atol=1e-14)
    np.testing.assert_allclose(lin[2:], v0 + dt * (u0 + u1) / 2, atol=1e-14)
    # with sub-steps the linear hold stays exact (stage times run across the sub-steps)
    lin3 = step(model, x0, u0, u1, dt, input_hold="linear", substeps=3)
    np.testing.assert_allclose(lin3, lin, atol=1e-14)


def test_substeps_equal_repeated_steps_and_rollout_handles_variable_dt():
    model = analytic_lagrangian(
        2, 1, [[2.0, 0.3], [0.3, 1.0]], [[4.0, 1.0], [1.0, 3.0]], 0.2 * np.eye(2), [[1.0], [0.5]]
    )
    x0, u = jnp.array([0.3, -0.1, 0.0, 0.2]), jnp.array([0.7])
    two = step(model, x0, u, u, 0.2, substeps=2)
    ref = step(model, step(model, x0, u, u, 0.1), u, u, 0.1)
    np.testing.assert_allclose(two, ref, atol=1e-14)

    t = jnp.array([0.0, 0.05, 0.15, 0.2, 0.4])
    us = jnp.array([[0.0], [1.0], [0.5], [-1.0], [0.2]])
    xs = rollout(model, x0, us, t, input_hold="linear")
    assert xs.shape == (5, 4)
    np.testing.assert_array_equal(xs[0], x0)
    x = x0
    for k in range(4):
        x = step(model, x, us[k], us[k + 1], t[k + 1] - t[k], input_hold="linear")
        np.testing.assert_allclose(xs[k + 1], x, atol=1e-13)

    truth = jnp.arange(20.0).reshape(5, 4)
    mask = jnp.array([False, False, True, False, False])
    xr = rollout(model, x0, us, t, reset=(truth, mask))
    np.testing.assert_allclose(xr[:2], rollout(model, x0, us, t)[:2], atol=1e-14)
    np.testing.assert_array_equal(xr[2], truth[2])
    np.testing.assert_allclose(xr[3], step(model, truth[2], us[2], us[3], 0.05), atol=1e-13)


def test_bad_options_are_user_errors():
    model = analytic_lagrangian(1, 1, [[1.0]], [[1.0]], [[0.0]], [[1.0]])
    x0, u = jnp.zeros(2), jnp.zeros(1)
    with pytest.raises(UserError, match="substeps must be an integer >= 1, got 0"):
        step(model, x0, u, u, 0.1, substeps=0)
    with pytest.raises(UserError, match="input_hold must be one of"):
        step(model, x0, u, u, 0.1, input_hold="cubic")
    with pytest.raises(UserError, match="rollout needs u"):
        rollout(model, x0, jnp.zeros((3, 1)), jnp.zeros(4))
    with pytest.raises(UserError, match="x0 of shape"):
        rollout(model, jnp.zeros(3), jnp.zeros((3, 1)), jnp.arange(3.0))
    with pytest.raises(UserError, match="reset needs"):
        rollout(
            model, x0, jnp.zeros((3, 1)), jnp.arange(3.0), reset=(jnp.zeros((3, 2)), jnp.ones(2))
        )
