"""bridge.floors: the true model's one-step loss under the networks' RK4 step, checked on
systems with closed-form solutions."""

from __future__ import annotations

import numpy as np
import pytest

from softpinn.bridge.analysis.floors import drift_baseline, integration_floor, true_vector_field
from softpinn.learn._data import PairData


class Oscillator:
    """q̈ = -q + u with M = 1, so p = q̇: the TrueModel interface the floor uses."""

    n, m = 1, 1

    def qdd(self, q, qd, u):
        return -q + (0.0 if u is None else u)

    def hamiltonian(self, q, p, u):
        return p, -q + (0.0 if u is None else u)


def _pairs(x0, x1, dt, u0=None, u1=None):
    b = len(x0)
    u0 = np.zeros((b, 1)) if u0 is None else u0
    u1 = u0 if u1 is None else u1
    return PairData(x0, u0, u1, np.full(b, dt), x1, None)


def _free_oscillation(dt, b=16, seed=0):
    """Exact pairs of the unforced oscillator: x1 is x0 rotated by dt."""
    x0 = np.random.default_rng(seed).uniform(-1, 1, (b, 2))
    c, s = np.cos(dt), np.sin(dt)
    x1 = np.stack([c * x0[:, 0] + s * x0[:, 1], -s * x0[:, 0] + c * x0[:, 1]], axis=1)
    return _pairs(x0, x1, dt)


def test_floor_falls_at_rk4s_order():
    """Local error O(dt⁵), so the squared error falls 2¹⁰ = 1024 times when dt halves."""
    coarse = integration_floor(Oscillator(), _free_oscillation(0.2), state="velocity").mean()
    fine = integration_floor(Oscillator(), _free_oscillation(0.1), state="velocity").mean()
    assert coarse > 1e-14
    assert 700 < coarse / fine < 1400


def test_substeps_lower_the_floor_like_a_smaller_step():
    """Two half steps: twice a local error 32 times smaller, so a squared error ~256 smaller."""
    pairs = _free_oscillation(0.2)
    one = integration_floor(Oscillator(), pairs, state="velocity").mean()
    two = integration_floor(Oscillator(), pairs, state="velocity", substeps=2).mean()
    assert 180 < one / two < 330


def test_momentum_form_equals_velocity_form_when_m_is_identity():
    pairs = _free_oscillation(0.3)
    v = integration_floor(Oscillator(), pairs, state="velocity", substeps=3)
    p = integration_floor(Oscillator(), pairs, state="momentum", substeps=3)
    np.testing.assert_allclose(p, v, rtol=1e-12)


def test_linear_hold_is_exact_for_a_ramp_input_and_constant_hold_is_not():
    """q̈ = u(t) = a + b t (no spring): q and q̇ are polynomials that RK4 integrates exactly
    with the input interpolated; holding u0 misses b dt²/2 in q̇ and b dt³/6 in q."""

    class Ramp(Oscillator):
        def qdd(self, q, qd, u):
            return u

    a, b, dt = 0.3, 2.0, 0.1
    x0 = np.array([[0.2, -0.5]])
    q1 = x0[0, 0] + x0[0, 1] * dt + a * dt**2 / 2 + b * dt**3 / 6
    qd1 = x0[0, 1] + a * dt + b * dt**2 / 2
    pairs = _pairs(x0, np.array([[q1, qd1]]), dt, np.array([[a]]), np.array([[a + b * dt]]))
    linear = integration_floor(Ramp(), pairs, state="velocity", input_hold="linear")
    constant = integration_floor(Ramp(), pairs, state="velocity", input_hold="constant")
    assert linear[0] < 1e-28
    np.testing.assert_allclose(constant[0], (b * dt**3 / 6) ** 2 + (b * dt**2 / 2) ** 2,
                               rtol=1e-9)


def test_unforced_true_model_gets_no_input():
    """An m = 0 model is called with u None, whatever the pairs' empty input arrays hold."""

    class Free(Oscillator):
        m = 0

        def qdd(self, q, qd, u):
            assert u is None
            return -q

    pairs = _free_oscillation(0.1)._replace(u0=np.zeros((16, 0)), u1=np.zeros((16, 0)))
    assert integration_floor(Free(), pairs, state="velocity").max() < 1e-12


def test_a_blow_up_is_inf_not_nan():
    class Stiff(Oscillator):
        def qdd(self, q, qd, u):
            return -1e200 * q

    err = integration_floor(Stiff(), _free_oscillation(0.5), state="velocity")
    assert np.all(err == np.inf)


@pytest.mark.parametrize(
    "kw, message",
    [
        ({"substeps": 0}, "substeps must be an integer >= 1"),
        ({"input_hold": "cubic"}, "input_hold must be 'constant' or 'linear'"),
        ({"state": "position"}, "state must be 'velocity' or 'momentum'"),
    ],
)
def test_bad_options_name_the_option(kw, message):
    with pytest.raises(ValueError, match=message):
        integration_floor(Oscillator(), _free_oscillation(0.1), **({"state": "velocity"} | kw))


def test_vector_field_rejects_unknown_state():
    with pytest.raises(ValueError, match="momentum"):
        true_vector_field(Oscillator(), "acceleration")


def test_no_forces_baseline_is_rk4_with_zero_acceleration():
    class Free(Oscillator):
        def qdd(self, q, qd, u):
            return 0.0 * q

    pairs = _free_oscillation(0.2)
    drift = drift_baseline(pairs, pairs.x0[:, 1:], state="velocity")
    np.testing.assert_allclose(drift, integration_floor(Free(), pairs, state="velocity"),
                               rtol=1e-12)
    # the oscillator's true model is far below it
    assert integration_floor(Oscillator(), pairs, state="velocity").mean() < 1e-6 * drift.mean()


def test_no_forces_baseline_in_momentum_form_keeps_p():
    """q + dt q̇₀ against q₁, p₀ against p₁ (here M = 2, so p = 2 q̇)."""
    x0 = np.array([[0.1, 2.0]])
    x1 = np.array([[0.25, 1.5]])
    pairs = _pairs(x0, x1, 0.1)
    got = drift_baseline(pairs, np.array([[1.0]]), state="momentum", weight=2.0)
    np.testing.assert_allclose(got, [(0.25 - 0.2) ** 2 + 2.0 * 0.5**2], rtol=1e-12)


def test_no_forces_baseline_rejects_bad_input():
    pairs = _free_oscillation(0.1)
    with pytest.raises(ValueError, match=r"qd0 must have shape \(16, 1\)"):
        drift_baseline(pairs, np.zeros((3, 1)), state="velocity")
    with pytest.raises(ValueError, match="state must be"):
        drift_baseline(pairs, pairs.x0[:, 1:], state="force")
