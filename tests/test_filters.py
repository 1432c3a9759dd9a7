"""The smoothers of softpinn import (symbolic/recorded/_filters.py) against closed forms: MATLAB's
movmean, Savitzky-Golay and piecewise polyfit reproduce the polynomials they fit, with exact
derivatives; central differences are exact for quadratics; the Hermite resampling is exact for
cubics."""

from __future__ import annotations

import numpy as np
import pytest

from softpinn.symbolic.recorded import _filters as F


def cubic(t):
    return 0.5 * t**3 - 2.0 * t**2 + t - 3.0, 1.5 * t**2 - 4.0 * t + 1.0, 3.0 * t - 4.0


def nonuniform_times(count=80, seed=0):
    rng = np.random.default_rng(seed)
    return np.cumsum(rng.uniform(0.005, 0.02, count))


def test_movmean_matches_matlab():
    # MATLAB's documentation: movmean([4 8 6 -1 -2 -3 -1 3 4 5], 3)
    a = np.array([4, 8, 6, -1, -2, -3, -1, 3, 4, 5], dtype=float)
    np.testing.assert_allclose(F.movmean(a, 3),
                               [6, 6, 13 / 3, 1, -2, -2, -1 / 3, 2, 4, 4.5], atol=1e-14)
    # even window: W/2 before and W/2 - 1 after, shrunk at the ends (brute force)
    for w in (1, 2, 4, 5, 20):
        want = [a[max(0, k - w // 2): k + (w - 1 - w // 2) + 1].mean() for k in range(len(a))]
        np.testing.assert_allclose(F.movmean(a, w), want, atol=1e-14)


def test_movmean_of_a_line_is_the_line_inside():
    t = np.linspace(0.0, 1.0, 50)
    y = np.stack([3 * t - 1, -t], 1)
    s, sd, sdd = F.smooth(t, y, "movmean:7")
    np.testing.assert_allclose(s[3:-3], y[3:-3], atol=1e-13)
    np.testing.assert_allclose(sd[4:-4], [[3.0, -1.0]] * 42, atol=1e-10)
    np.testing.assert_allclose(sdd[6:-6], 0.0, atol=1e-7)


@pytest.mark.parametrize("uniform", [True, False])
def test_savgol_reproduces_polynomials_and_their_derivatives(uniform):
    t = np.linspace(0.0, 1.2, 81) if uniform else nonuniform_times()
    y, yd, ydd = cubic(t)
    s, sd, sdd = F.smooth(t, y, "savgol:11:3")
    np.testing.assert_allclose(s, y, atol=1e-11)
    np.testing.assert_allclose(sd, yd, atol=1e-9)
    np.testing.assert_allclose(sdd, ydd, atol=1e-7)


def test_savgol_in_time_is_scipys_savgol_on_uniform_times():
    from scipy.signal import savgol_filter

    t = np.linspace(0.0, 2.0, 60)
    y = np.sin(3 * t)[:, None] + 0.01 * np.random.default_rng(1).normal(size=(60, 1))
    mine = F.local_fits(t, y, 9, 2)
    for k in range(3):
        want = savgol_filter(y, 9, 2, deriv=k, delta=t[1] - t[0], axis=0, mode="interp")
        np.testing.assert_allclose(mine[k], want, atol=1e-9)


def test_an_even_savgol_degree_differentiates_like_the_odd_degree_below():
    """What docs/import.md warns of: at the window's centre the slope of a quadratic fit is the
    straight line's, so savgol:5:2 keeps 71 % of a 0.6 Hz sine's velocity at 5 Hz (cubics 99 %)."""
    t = np.arange(200) * 0.2
    w = 2 * np.pi * 0.6
    y = np.sin(w * t)[:, None]
    inner = slice(2, -2)
    np.testing.assert_allclose(F.smooth(t, y, "savgol:5:2")[1][inner],
                               F.smooth(t, y, "savgol:5:1")[1][inner], atol=1e-12)
    true = w * np.cos(w * t)[inner]
    for text, gain in (("savgol:5:2", 0.711), ("savgol:5:3", 0.990)):
        fit = np.polyfit(true, F.smooth(t, y, text)[1][inner, 0], 1)[0]
        assert fit == pytest.approx(gain, abs=1e-3), text


@pytest.mark.parametrize("uniform", [True, False])
def test_polyfit_pieces_reproduce_a_polynomial(uniform):
    t = np.linspace(0.0, 1.0, 53) if uniform else nonuniform_times(53)
    y, yd, ydd = cubic(t)
    s, sd, sdd = F.smooth(t, np.stack([y, 2 * y], 1), "polyfit:3:10")
    np.testing.assert_allclose(s[:, 0], y, atol=1e-11)
    np.testing.assert_allclose(sd[:, 1], 2 * yd, atol=1e-8)
    np.testing.assert_allclose(sdd[:, 0], ydd, atol=1e-6)


def test_polyfit_pieces_fit_each_run_on_its_own():
    # a kink between the runs [0, 10) and [10, 20): each straight piece is fitted exactly
    t = np.arange(20.0)
    y = np.where(t < 10, t, 20 - t)
    s, sd, _ = F.smooth(t, y, "polyfit:1:10")
    np.testing.assert_allclose(s, y, atol=1e-12)
    np.testing.assert_allclose(sd, np.where(t < 10, 1.0, -1.0), atol=1e-12)
    # a short remainder (3 samples < half a window) joins the last run
    s, _, _ = F.smooth(np.arange(23.0), np.arange(23.0) ** 2, "polyfit:2:10")
    np.testing.assert_allclose(s, np.arange(23.0) ** 2, atol=1e-9)


@pytest.mark.parametrize("uniform", [True, False])
def test_central_differences_are_exact_for_quadratics(uniform):
    t = np.linspace(0.0, 1.0, 30) if uniform else nonuniform_times(30)
    y = 2 * t**2 - t
    s, sd, sdd = F.smooth(t, y, "none")
    np.testing.assert_array_equal(s, y)
    np.testing.assert_allclose(sd, 4 * t - 1, atol=1e-10)
    np.testing.assert_allclose(sdd[2:-2], 4.0, atol=1e-6)


@pytest.mark.parametrize("uniform", [True, False])
def test_fourth_order_differences_are_exact_for_quartics(uniform):
    # inside, the quartic through the 5 samples around each sample: exact for quartics, the
    # samples themselves kept; the two samples at each end take second order's (one-sided
    # quartics would amplify noise up to 8 times there)
    t = np.linspace(0.0, 1.0, 30) if uniform else nonuniform_times(30)
    y = np.stack([t**4 - 2 * t**3 + t, 3 * t**2], 1)
    s, sd, sdd = F.smooth(t, y, F.parse_smoother("none", 4))
    np.testing.assert_array_equal(s, y)
    inside = slice(2, -2)
    np.testing.assert_allclose(sd[inside, 0], (4 * t**3 - 6 * t**2 + 1)[inside], atol=1e-9)
    np.testing.assert_allclose(sdd[inside, 0], (12 * t**2 - 12 * t)[inside], atol=1e-6)
    np.testing.assert_allclose(sd[:, 1], 6 * t, atol=1e-9)  # a quadratic: the ends too
    _, sd2, sdd2 = F.smooth(t, y, "none")
    for end in (slice(0, 2), slice(-2, None)):
        np.testing.assert_array_equal(sd[end], sd2[end])
        np.testing.assert_array_equal(sdd[end], sdd2[end])
    # second order is not exact for a quartic's slope
    assert np.abs(sd2[inside, 0] - (4 * t**3 - 6 * t**2 + 1)[inside]).max() > 1e-4


def test_fourth_order_differences_are_the_classic_stencils():
    rng = np.random.default_rng(3)
    h, y = 0.2, rng.normal(size=(40, 1))
    t = h * np.arange(40)
    _, sd, sdd = F.smooth(t, y, F.parse_smoother("movmean:1", 4))  # movmean:1 keeps y
    v = y[:, 0]
    np.testing.assert_allclose(sd[2:-2, 0], (v[:-4] - 8 * v[1:-3] + 8 * v[3:-1] - v[4:]) / (12 * h),
                               atol=1e-12)
    np.testing.assert_allclose(
        sdd[2:-2, 0], (-v[:-4] + 16 * v[1:-3] - 30 * v[2:-2] + 16 * v[3:-1] - v[4:]) / (12 * h * h),
        atol=1e-10)


def test_the_orders_velocity_gains_on_a_sinusoid():
    # the documented gains: sin(x)/x and (8 sin x - sin 2x)/(6x) at x = ωh (0.6 Hz at 5 Hz)
    f, h = 0.6, 0.2
    t = h * np.arange(200)
    y = np.sin(2 * np.pi * f * t)[:, None]
    x = 2 * np.pi * f * h
    amp = 2 * np.pi * f
    for order, gain in ((2, np.sin(x) / x), (4, (8 * np.sin(x) - np.sin(2 * x)) / (6 * x))):
        _, sd, _ = F.smooth(t, y, F.parse_smoother("none", order))
        got = sd[10:-10, 0] / (amp * np.cos(2 * np.pi * f * t[10:-10]))
        keep = np.abs(np.cos(2 * np.pi * f * t[10:-10])) > 0.5
        np.testing.assert_allclose(got[keep], gain, rtol=1e-9)
    assert round(np.sin(x) / x, 3) == 0.908
    assert round((8 * np.sin(x) - np.sin(2 * x)) / (6 * x), 3) == 0.99


def test_hermite_resampling_is_exact_for_cubics():
    t = nonuniform_times(40)
    y, yd, ydd = cubic(t)
    tn, yn, ydn, yddn = F.resample_uniform(t, y[:, None], yd[:, None], ydd[:, None], 50.0)
    np.testing.assert_allclose(np.diff(tn), 0.02, atol=1e-12)
    assert tn[0] == t[0] and tn[-1] <= t[-1]
    want = cubic(tn)
    np.testing.assert_allclose(yn[:, 0], want[0], atol=1e-12)
    np.testing.assert_allclose(ydn[:, 0], want[1], atol=1e-3)  # yd is quadratic: Hermite
    np.testing.assert_allclose(yddn[:, 0], want[2], atol=1e-12)  # ydd linear: exact


@pytest.mark.parametrize(
    "text,match",
    [
        ("median:5", r"smooth: expected none \| movmean:W \| savgol:W:P \| polyfit:DEG:W"),
        ("movmean", r"smooth: expected none"),
        ("movmean:x", r"window and degree must be integers"),
        ("movmean:0", r"at least 1 sample"),
        ("savgol:10:3", r"odd number >= 3"),
        ("savgol:5:5", r"degree must be in 0 .. window - 1"),
        ("polyfit:3:3", r"a window of 3 samples cannot fit degree 3"),
    ],
)
def test_bad_settings(text, match):
    with pytest.raises(F.FilterError, match=match):
        F.parse_smoother(text)


@pytest.mark.parametrize("order", [3, 0, True, "4"])
def test_bad_difference_orders(order):
    with pytest.raises(F.FilterError, match=r"differences: expected one of 2, 4"):
        F.parse_smoother("none", order)


def test_a_moving_mean_longer_than_the_trajectory_is_refused():
    """movmean:W over fewer than W samples flattens the trajectory (every sample the mean of
    nearly all): refused, as savgol is, instead of giving a constant q."""
    t = np.arange(40.0)
    with pytest.raises(F.FilterError, match="movmean:100 needs at least 100 samples per "
                       "trajectory, got 40"):
        F.smooth(t, np.sin(t), F.parse_smoother("movmean:100"))
    F.smooth(t, np.sin(t), F.parse_smoother("movmean:40"))


def test_fourth_order_differences_need_five_samples():
    with pytest.raises(F.FilterError, match=r"none, differences 4 needs at least 5 samples"):
        F.smooth(np.arange(4.0), np.arange(4.0), F.parse_smoother("none", 4))
    # a smoother with a derivative of its own ignores the order (and says nothing of it)
    sm = F.parse_smoother("savgol:5:3", 4)
    assert sm.label == "savgol:5:3" and "differences" not in sm.describe()
    assert F.parse_smoother("none", 4).describe()["differences"] == 4


def test_round_trip_of_the_setting_text():
    for text in ("none", "movmean:20", "savgol:11:3", "polyfit:5:40"):
        assert str(F.parse_smoother(text)) == text


def test_too_short_for_the_window():
    with pytest.raises(F.FilterError, match="savgol:11:3 needs at least 11 samples"):
        F.smooth(np.arange(5.0), np.arange(5.0), "savgol:11:3")
