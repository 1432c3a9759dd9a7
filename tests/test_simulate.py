"""Simulation: exact inputs, energy conservation, power balance, RK4 vs cvodes, singularities."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from softpinn.symbolic.codegen import _codegen as codegen
from softpinn.symbolic.model._functions import functions
from softpinn.symbolic.simulation._samples import batched
from softpinn.symbolic.simulation._signals import Sinusoid, Step, Zero
from softpinn.symbolic.simulation._sim_config import (
    SimulationConfig,
    SimulationError,
    SingularityError,
)
from softpinn.symbolic.simulation._simulate import simulate
from softpinn.symbolic.spec._spec import spec_from_dict


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("cache")


def driven_point_mass() -> dict[str, ca.Function]:
    """q'' = u: a unit point mass pushed by a known force (test model, not a paper model)."""
    q, qd, u, x = ca.SX.sym("q"), ca.SX.sym("qd"), ca.SX.sym("u"), ca.SX.sym("x", 2)
    return {
        "ode": ca.Function("pm_ode", [x, u], [ca.vertcat(x[1], u)], ["x", "u"], ["xdot"]),
        "forward": ca.Function("pm_fwd", [q, qd, u], [u], ["q", "qd", "u"], ["qdd"]),
        "momentum": ca.Function("pm_mom", [q, qd], [qd], ["q", "qd"], ["p"]),
        "M": ca.Function("pm_M", [q], [ca.SX.ones(1, 1)], ["q"], ["M"]),
    }


def pm_exact(t, x0, s: Sinusoid):
    """Closed form for q'' = c + a sin(w t + ph)."""
    a, f, ph, c = (np.asarray(v)[0] for v in (s.amplitude, s.frequency, s.phase, s.offset))
    w = 2 * np.pi * f
    q = (
        x0[0]
        + x0[1] * t
        + c * t**2 / 2
        + a / w**2 * (np.sin(ph) + w * t * np.cos(ph) - np.sin(w * t + ph))
    )
    qd = x0[1] + c * t + a / w * (np.cos(ph) - np.cos(w * t + ph))
    return q, qd


@pytest.mark.parametrize("integrator,dt", [("cvodes", None), ("rk4", 1e-3)])
def test_input_is_exact_inside_the_integrator(integrator, dt):
    fns = driven_point_mass()
    sigs = [Sinusoid([1.5], [0.7], [0.3], [0.2]), Sinusoid([0.5], [2.0], [-1.0], [-0.4])]
    x0 = np.array([[0.1, -0.2], [0.0, 0.5]])
    cfg = SimulationConfig(
        integrator=integrator, duration=3.0, rate=50.0, dt=dt, rtol=1e-12, atol=1e-12
    )
    res = simulate(fns, x0, sigs, cfg)
    assert res.x.shape == (2, 150, 2) and res.u.shape == (2, 150, 1)
    np.testing.assert_allclose(res.t, np.arange(150) / 50.0)
    for k, s in enumerate(sigs):
        q, qd = pm_exact(res.t, x0[k], s)
        tol = 1e-9 if integrator == "cvodes" else 1e-10  # RK4 is exact up to its O(dt^4) error
        np.testing.assert_allclose(res.q[k, :, 0], q, atol=max(tol, 1e-9))
        np.testing.assert_allclose(res.qd[k, :, 0], qd, atol=max(tol, 1e-9))
        np.testing.assert_allclose(res.u[k], s(res.t), rtol=0, atol=0)
        np.testing.assert_allclose(res.qdd[k, :, 0], s(res.t)[:, 0], atol=1e-14)


def test_step_input_is_exact():
    fns = driven_point_mass()
    res = simulate(
        fns,
        np.zeros((1, 2)),
        [Step(times=[0.505], levels=[[1.0], [-1.0]])],
        SimulationConfig(duration=1.0, rate=100.0, rtol=1e-12, atol=1e-12),
    )
    t = res.t
    exact = np.where(t < 0.505, t**2 / 2, 0.505**2 / 2 + 0.505 * (t - 0.505) - (t - 0.505) ** 2 / 2)
    np.testing.assert_allclose(res.q[0, :, 0], exact, atol=1e-9)


def test_double_pendulum_conserves_energy(cache):
    fns = codegen.compiled(functions("task2"), directory=cache)
    x0 = np.array([[1.2, -0.5, 0.3, 0.8]])
    cfg = SimulationConfig(duration=10.0, rate=100.0, rtol=1e-13, atol=1e-13)
    res = simulate(fns, x0, [Zero(0)], cfg)
    e = batched(fns["energy"], res.q[0], res.qd[0])[:, 0]
    drift = np.max(np.abs(e - e[0])) / np.abs(e[0])
    assert drift < 1e-8, drift
    assert np.ptp(res.q[0, :, 0]) > 1.0  # it did move


def _arm(
    damping,
    kind="spatial-pcc",
    actuation="tip-wrench",
    param="delta",
    stiffness=(1.0, 1.0, 1.0),
    segments=1,
):
    seg = {"length": 0.2, "mass": 0.3, "stiffness": list(stiffness), "damping": damping}
    return spec_from_dict(
        {
            "name": f"arm_{param}_{sum(damping):g}_{segments}_{actuation}",
            "kind": kind,
            "parameterization": param,
            "gravity": [0.0, 0.0, 9.81],
            "actuation": actuation,
            "segment": [seg] * segments,
        },
        source="test",
    )


def _planar(damping):
    seg = {"length": 1.0, "mass": 1.0, "stiffness": [10.0, 10.0], "damping": damping}
    return spec_from_dict(
        {"name": "planar_free", "kind": "planar-pcc", "actuation": "none", "segment": [seg, seg]},
        source="test",
    )


@pytest.mark.parametrize("which", ["spatial", "planar"])
def test_undamped_pcc_arm_conserves_energy(cache, which):
    """Two segments, no damping, no input: E = T + V is constant along 10 s (eq. 4 with D = 0)."""
    if which == "spatial":
        spec = _arm([0.0, 0.0, 0.0], segments=2, actuation="none")
        x0 = np.array([[0.4, -0.3, 0.05, -0.2, 0.3, 0.0, 0.2, 0.1, 0.0, 0.0, -0.1, 0.05]])
    else:
        spec = _planar([0.0, 0.0])
        x0 = np.array([[0.8, 0.1, -0.5, 0.0, 0.5, 0.0, 0.0, 0.2]])
    fns = codegen.compiled(functions(spec), directory=cache)
    cfg = SimulationConfig(duration=10.0, rate=100.0, rtol=1e-12, atol=1e-12)
    res = simulate(fns, x0, [Zero(0)], cfg)
    e = batched(fns["energy"], res.q[0], res.qd[0])[:, 0]
    kinetic = batched(fns["kinetic"], res.q[0], res.qd[0])[:, 0]
    scale = max(abs(e[0]), kinetic.max())  # the zero of V is arbitrary: also compare with T
    assert kinetic.max() > 1e-3 * abs(e[0])  # it moved
    assert np.max(np.abs(e - e[0])) / scale < 1e-8


def test_power_balance_with_damping_and_input(cache):
    """dE/dt = qd^T (A u - D qd) along a damped, driven trajectory of the task 4 arm."""
    fns = codegen.compiled(functions("task4"), directory=cache)
    x0 = np.array([[0.3, 0.2, 0.05, -0.2, 0.1, 0.0]])
    sig = Sinusoid([0.5, 0.3, 0.4], [0.6, 0.9, 0.4], [0.0, 1.0, 2.0], [0.1, -0.1, 0.5])
    cfg = SimulationConfig(duration=1.0, rate=2000.0, rtol=1e-12, atol=1e-12)
    res = simulate(fns, x0, [sig], cfg)
    q, qd, u = res.q[0], res.qd[0], res.u[0]
    e = batched(fns["energy"], q, qd)[:, 0]
    A = batched(fns["A"], q)
    D = batched(fns["D"], q)
    power = np.einsum(
        "ki,ki->k", qd, np.einsum("kij,kj->ki", A, u) - np.einsum("kij,kj->ki", D, qd)
    )
    h = 1 / cfg.rate  # dE/dt by the fourth-order central difference
    dedt = (-e[4:] + 8 * e[3:-1] - 8 * e[1:-3] + e[:-4]) / (12 * h)
    assert np.max(np.abs(power)) > 1e-1
    np.testing.assert_allclose(dedt, power[2:-2], atol=1e-5 * np.max(np.abs(power)))
    # and the momentum and accelerations stored agree with the model
    np.testing.assert_allclose(res.p[0], batched(fns["momentum"], q, qd), rtol=1e-12, atol=1e-14)


def test_rk4_agrees_with_cvodes(cache):
    fns = codegen.compiled(functions("task4"), directory=cache)
    x0 = np.array([[0.3, -0.2, 0.05, 0.1, 0.1, 0.0], [-0.4, 0.1, 0.0, 0.0, -0.2, 0.05]])
    sigs = [
        Sinusoid([0.3, 0.3, 0.2], [0.5, 0.5, 0.5], [0, 0, 0], [0, 0, 0.2]),
        Sinusoid([0.1, 0.4, 0.2], [0.2, 0.8, 0.3], [1, 2, 3], [0.1, 0, 0]),
    ]
    a = simulate(fns, x0, sigs, SimulationConfig(duration=2.0, rate=100.0, rtol=1e-12, atol=1e-12))
    b = simulate(
        fns, x0, sigs, SimulationConfig(integrator="rk4", duration=2.0, rate=100.0, dt=1e-4)
    )
    np.testing.assert_allclose(b.x, a.x, atol=1e-7)
    np.testing.assert_allclose(b.qdd, a.qdd, atol=1e-5)


def test_phi_theta_through_theta_zero_raises(cache):
    spec = _arm([0.0, 0.0, 0.0], param="phi-theta", actuation="none", stiffness=(0.0, 1.0, 1.0))
    fns = codegen.compiled(functions(spec), directory=cache)
    # theta = 0 at the start: M is singular there (its phi column vanishes)
    with pytest.raises(SingularityError, match=r"t = 0 s.*theta = 0.*delta"):
        simulate(
            fns,
            np.array([[0.3, 0.0, 0.0, 0.0, 0.0, 0.0]]),
            [Zero(0)],
            SimulationConfig(duration=1.0, rate=100.0),
        )
    # swinging through theta = 0 in the plane phi = 0.3: stops there, never a silent NaN
    with pytest.raises(SingularityError) as err:
        simulate(
            fns,
            np.array([[0.3, 0.5, 0.0, 0.0, -3.0, 0.0]]),
            [Zero(0)],
            SimulationConfig(duration=2.0, rate=100.0, rtol=1e-8, atol=1e-8),
        )
    msg = str(err.value)
    assert "\n" not in msg and "trajectory 0" in msg and "delta" in msg
    theta = float(msg.split("q = [")[1].split(",")[1])
    assert abs(theta) < 0.05  # the state named is next to theta = 0
    assert float(msg.split("t = ")[1].split(" s")[0]) > 0.1


@pytest.mark.parametrize(
    "kwargs,match",
    [
        ({"duration": -1.0}, "duration: must be positive"),
        ({"rate": 0.0}, "rate: must be a positive"),
        ({"integrator": "euler"}, "integrator: expected one of cvodes, rk4"),
        ({"integrator": "rk4", "rate": 100.0, "dt": 0.003}, "whole multiple of dt"),
        ({"rtol": 0.0}, "rtol: must be positive"),
        ({"duration": 0.01, "rate": 100.0}, "at least 2 samples"),
    ],
)
def test_bad_configuration(kwargs, match):
    with pytest.raises(SimulationError, match=match):
        SimulationConfig(**kwargs)


def test_bad_initial_state_and_signal():
    fns = driven_point_mass()
    cfg = SimulationConfig(duration=1.0, rate=10.0)
    with pytest.raises(SimulationError, match="expected 2 values"):
        simulate(fns, np.zeros((1, 3)), [Zero(1)], cfg)
    with pytest.raises(SimulationError, match="expected 1 inputs, got 2"):
        simulate(fns, np.zeros((1, 2)), [Zero(2)], cfg)
    with pytest.raises(SimulationError, match="one per trajectory"):
        simulate(fns, np.zeros((2, 2)), [Zero(1)], cfg)


def test_ill_conditioned_mass_matrix_raises():
    """cond(M) above max_condition stops the simulation (checked every condition_stride-th)."""
    x, u, q, qd = ca.SX.sym("x", 4), ca.SX.sym("u", 0), ca.SX.sym("q", 2), ca.SX.sym("qd", 2)
    fns = {
        "ode": ca.Function("c_ode", [x, u], [ca.vertcat(x[2:], 0, 0)], ["x", "u"], ["xdot"]),
        "forward": ca.Function("c_fwd", [q, qd, u], [ca.SX.zeros(2)], ["q", "qd", "u"], ["qdd"]),
        "momentum": ca.Function("c_mom", [q, qd], [qd], ["q", "qd"], ["p"]),
        "M": ca.Function("c_M", [q], [ca.diag(ca.vertcat(1, ca.exp(-100 * q[0])))], ["q"], ["M"]),
    }
    x0 = np.array([[0.0, 0.0, 1.0, 0.0]])  # q0 = t: cond(M) = exp(100 t) passes 1e12 at 0.276 s
    cfg = SimulationConfig(duration=1.0, rate=100.0, condition_stride=5)
    with pytest.raises(SingularityError, match=r"ill-conditioned \(cond = .* at t = 0.3 s"):
        simulate(fns, x0, [Zero(0)], cfg)
    res = simulate(
        fns, x0, [Zero(0)], SimulationConfig(duration=1.0, rate=100.0, max_condition=None)
    )
    assert res.info["max_mass_condition"] is None
    # a model with a combined "outputs"(q, qd, u) -> (qdd, p, M) function: M at every sample
    mass = fns["M"](q)
    fns["outputs"] = ca.Function(
        "c_out", [q, qd, u], [ca.SX.zeros(2), mass @ qd, mass], ["q", "qd", "u"], ["qdd", "p", "M"]
    )
    with pytest.raises(SingularityError, match=r"ill-conditioned \(cond = .* at t = 0.28 s"):
        simulate(fns, x0, [Zero(0)], cfg)
    res = simulate(fns, np.array([[0.0, 0.0, 0.2, 0.5]]), [Zero(0)], cfg)
    np.testing.assert_allclose(res.p[0, :, 1], 0.5 * np.exp(-100 * res.q[0, :, 0]), rtol=1e-12)
