"""sinc and cosc of s = x^2: exact values, finite exact derivatives at 0, no jump at the switch."""

from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest

from softpinn.symbolic.derivation._smooth import SWITCH, cosc, sinc

s = ca.SX.sym("s")
F = ca.Function("f", [s], [ca.vertcat(sinc(s), cosc(s))])
J = ca.Function("j", [s], [ca.jacobian(ca.vertcat(sinc(s), cosc(s)), s)])
H = ca.Function("h", [s], [ca.jacobian(ca.jacobian(ca.vertcat(sinc(s), cosc(s)), s), s)])


def reference(x):
    """sin(x)/x and (1 - cos x)/x^2 in high precision (mpmath-free: 2 sin^2(x/2) form)."""
    return np.sin(x) / x, 2 * np.sin(x / 2) ** 2 / x**2


@pytest.mark.parametrize("x", [1e-6, 1e-3, 0.05, 0.0999, 0.1001, 0.5, 1.0, 3.0, 2 * np.pi, 10.0])
def test_values(x):
    got = np.array(F(x * x)).ravel()
    np.testing.assert_allclose(got, reference(x), rtol=2e-15, atol=1e-16)


def test_exact_at_zero_with_derivatives():
    np.testing.assert_array_equal(np.array(F(0.0)).ravel(), [1.0, 0.5])
    # d/ds sinc = -1/6, d/ds cosc = -1/24; second derivatives 2/120 and 2/720
    np.testing.assert_allclose(np.array(J(0.0)).ravel(), [-1 / 6, -1 / 24], rtol=1e-15)
    np.testing.assert_allclose(np.array(H(0.0)).ravel(), [2 / 120, 2 / 720], rtol=1e-15)
    for fn in (F, J, H):
        for x in (0.0, 1e-18, 1e-300):
            assert np.all(np.isfinite(np.array(fn(x))))


def test_no_jump_across_the_switch():
    below, above = np.nextafter(SWITCH, 0.0), SWITCH  # series below, direct formula at SWITCH
    for fn, tol in ((F, 1e-15), (J, 1e-12), (H, 1e-10)):
        a, b = np.array(fn(below)).ravel(), np.array(fn(above)).ravel()
        np.testing.assert_allclose(a, b, rtol=tol, atol=tol)


def test_derivative_matches_closed_form_away_from_zero():
    x = 1.3
    sx = x * x
    # d/ds [sin(sqrt s)/sqrt s] = (cos x - sinc) / (2 s)
    dsinc = (math.cos(x) - math.sin(x) / x) / (2 * sx)
    dcosc = (math.sin(x) / x - 2 * (1 - math.cos(x)) / sx) / (2 * sx)
    np.testing.assert_allclose(np.array(J(sx)).ravel(), [dsinc, dcosc], rtol=1e-13)


def test_numeric_arguments():
    assert float(sinc(0.0)) == 1.0 and float(cosc(4.0)) == pytest.approx((1 - math.cos(2)) / 4)


def test_jet_values_and_derivatives_match_high_precision():
    """The jet's closed forms and series (cosc, sinc and two s-derivatives) against mpmath."""
    import mpmath

    from softpinn.symbolic.derivation._smooth import JET_SWITCH, Jet

    jet = Jet()
    s = ca.SX.sym("s")
    f = ca.Function("jet", [s], [jet.values(s)])

    def exact(sv):
        with mpmath.workdps(40):
            sv = mpmath.mpf(sv)
            c1 = lambda t: (1 - mpmath.cos(mpmath.sqrt(t))) / t if t else mpmath.mpf(1) / 2
            c2 = lambda t: mpmath.sin(mpmath.sqrt(t)) / mpmath.sqrt(t) if t else mpmath.mpf(1)
            out = []
            for fn in (c1, c2):
                out += [fn(sv), mpmath.diff(fn, sv, 1) if sv else None,
                        mpmath.diff(fn, sv, 2) if sv else None]
            return out

    for sv in (1e-6, 0.05, np.nextafter(JET_SWITCH, 0), JET_SWITCH, 0.5, 4.0, 39.0):
        got = np.array(f(sv)).ravel()
        want = np.array([float(x) for x in exact(sv)])
        got = got[[0, 1, 2, 3, 4, 5]]
        np.testing.assert_allclose(got, want, rtol=1e-11, atol=1e-15, err_msg=str(sv))
    at0 = np.array(f(0.0)).ravel()
    np.testing.assert_allclose(at0, [1 / 2, -1 / 24, 2 / 720, 1, -1 / 6, 2 / 120], rtol=1e-15)
