"""TrueModel: batched evaluation equals single evaluation, shapes, and user errors."""

from __future__ import annotations

import numpy as np
import pytest

from softpinn.symbolic import TrueModel, UserError


@pytest.fixture(scope="module")
def tm():
    return TrueModel("task5")


def test_shapes_and_batch(tm):
    rng = np.random.default_rng(0)
    Q, QD, U = rng.uniform(-0.4, 0.4, (5, 6)), rng.normal(size=(5, 6)), rng.normal(size=(5, 6))
    assert (tm.n, tm.m) == (6, 6) and tm.spec.name == "task5" and "forward" in tm.functions
    assert tm.M(Q[0]).shape == (6, 6) and tm.G(Q[0]).shape == (6,)
    assert isinstance(tm.energy(Q[0], QD[0]), float)
    batched = {"M": tm.M(Q), "M_inv": tm.M_inv(Q), "A": tm.A(Q), "qdd": tm.qdd(Q, QD, U),
               "E": tm.energy(Q, QD), "C": tm.C(Q, QD)}
    assert batched["M"].shape == (5, 6, 6) and batched["qdd"].shape == (5, 6)
    assert batched["E"].shape == (5,) and batched["A"].shape == (5, 6, 6)
    for k in range(5):
        np.testing.assert_array_equal(batched["M"][k], tm.M(Q[k]))
        np.testing.assert_array_equal(batched["M_inv"][k], tm.M_inv(Q[k]))
        np.testing.assert_array_equal(batched["A"][k], tm.A(Q[k]))
        np.testing.assert_array_equal(batched["C"][k], tm.C(Q[k], QD[k]))
        np.testing.assert_array_equal(batched["qdd"][k], tm.qdd(Q[k], QD[k], U[k]))
        assert batched["E"][k] == tm.energy(Q[k], QD[k])
    # one state broadcast against a batch of inputs
    np.testing.assert_array_equal(tm.qdd(Q[0], QD[0], U)[3], tm.qdd(Q[0], QD[0], U[3]))
    qdot, pdot = tm.hamiltonian(Q, tm.momentum(Q, QD), U)
    np.testing.assert_allclose(qdot, QD, atol=1e-9)
    assert pdot.shape == (5, 6)


def test_unforced_undamped_energy_is_conserved():
    """RK4 on the ODE with D = 0: the energy drift falls with the step like h^4."""
    from softpinn.symbolic.spec._spec import load_spec, preset_path, spec_from_toml

    text = preset_path("task4").read_text().replace("damping = [0.1, 0.1, 0.1]",
                                                    "damping = [0.0, 0.0, 0.0]")
    tm = TrueModel(spec_from_toml(text, source="undamped"))
    assert load_spec("task4").segments[0].damping == (0.1, 0.1, 0.1)
    x0 = np.array([0.4, -0.2, 0.05, 0.0, 0.3, 0.0])

    def drift(h, steps):
        x = x0.copy()
        for _ in range(steps):
            k1 = tm.ode(x)
            k2 = tm.ode(x + h / 2 * k1)
            k3 = tm.ode(x + h / 2 * k2)
            k4 = tm.ode(x + h * k3)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        return abs(tm.energy(x[:3], x[3:]) - tm.energy(x0[:3], x0[3:]))

    coarse, fine = drift(2e-3, 50), drift(1e-3, 100)
    assert fine < 1e-6 and coarse / fine > 8  # fourth order: ratio ~ 16


def test_user_errors(tm):
    with pytest.raises(UserError, match="q: expected length 6 for model 'task5', got 3"):
        tm.M(np.zeros(3))
    with pytest.raises(UserError, match=r"q: expected shape \(6,\) or \(N, 6\), got \(\)"):
        tm.G(0.0)
    with pytest.raises(UserError, match="u: expected length 6"):
        tm.qdd(np.zeros(6), np.zeros(6), np.zeros(2))
    with pytest.raises(UserError, match="batch size 4 differs from 3"):
        tm.qdd(np.zeros((3, 6)), np.zeros((4, 6)), np.zeros(6))
    with pytest.raises(UserError, match="unknown model"):
        TrueModel("task42")
