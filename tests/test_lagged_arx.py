"""ARX with lags of q and u (learn/_lagged_arx.py): a system with input memory and a third-order
recurrence is recovered exactly and its order found on the held-out trajectory, where ARX of
order 2 cannot follow it; rollouts from a measured past equal the recurrence by hand; unstable
fits are refused; JSON round trip; one-line user errors."""

from __future__ import annotations

import numpy as np
import pytest

from softpinn.errors import UserError
from softpinn.learn._baseline_errors import rollout_errors
from softpinn.learn._baseline_kinds import baseline_from_dict, fit_baseline
from softpinn.learn._baselines import fit_arx
from softpinn.learn._lagged_arx import LaggedARX, fit_lagged_arx, window_score

DT = 0.05


def _system(seed=0):
    """q_{k+1} = Σ_{i<3} A_i q_{k-i} + Σ_{j<3} B_j u_{k-j} + c, stable (n = 2, m = 1): a
    delayed input (B_0 = 0) and a resonance that two lags of q do not hold."""
    rng = np.random.default_rng(seed)
    n, m, p = 2, 1, 3
    comp = np.zeros((p * n, p * n))
    comp[n:, :-n] = np.eye((p - 1) * n)
    comp[:n] = rng.normal(size=(n, p * n))
    while np.max(np.abs(np.linalg.eigvals(comp))) > 0.97:
        comp[:n] *= 0.95
    A = np.stack([comp[:n, i * n:(i + 1) * n] for i in range(p)])
    B = rng.normal(size=(p, n, m))
    B[0] = 0.0
    return LaggedARX(A, B, rng.normal(size=n) * 0.1, DT, -np.ones(n), np.ones(n))


def _trajectories(model, trajs=5, steps=300, seed=1):
    rng = np.random.default_rng(seed)
    out = []
    for j in range(trajs):
        u = np.cumsum(rng.normal(size=(steps, model.m)), axis=0) * 0.2  # slowly varying
        u -= u.mean(axis=0)
        q = model.rollout(np.zeros(model.n), None, u, DT)  # from rest: zero past, u held
        qd = np.gradient(q, DT, axis=0)
        qd[0] = 0.0
        out.append({"id": j, "t": DT * np.arange(steps), "q": q, "u": u, "qd": qd})
    return out


def test_recovers_a_system_with_memory_and_its_order():
    true = _system()
    data = _trajectories(true)
    fit = fit_lagged_arx(data, ridge=0.0)
    assert fit.order == 3, fit.info["orders_tried"]
    np.testing.assert_allclose(fit.A, true.A, atol=1e-8)
    np.testing.assert_allclose(fit.B, true.B, atol=1e-8)
    assert fit.info["order_chosen_on"] == "held-out training trajectory 4"
    tried = fit.info["orders_tried"]
    assert tried["3"]["least squares"] < 1e-15 < tried["2"]["least squares"]
    assert fit.info["fit"] == "least squares" and fit.info["horizon"] == 5.0
    # the plain ARX of order 2 cannot follow it: predict's metric on new trajectories
    test = _trajectories(true, trajs=2, seed=9)
    lag = rollout_errors(fit, test, 5.0).rollout_error_mean
    two = rollout_errors(fit_arx(data, order=2), test, 5.0).rollout_error_mean
    assert lag < 1e-12 and two > 1e-4, (lag, two)


def test_rollout_from_a_measured_past_is_the_recurrence():
    model = _system(seed=3)
    rng = np.random.default_rng(4)
    u = rng.normal(size=(6, 1))
    hist = rng.normal(size=(3, 2))  # oldest first
    got = model.rollout(hist, np.zeros(2), u, DT)
    q = [hist[0], hist[1], hist[2]]
    us = [u[0], u[0], u[0]]  # earlier inputs held at u0
    for k in range(5):
        us.append(u[k])
        q.append(sum(model.A[i] @ q[-1 - i] for i in range(3))
                 + sum(model.B[j] @ us[-1 - j] for j in range(3)) + model.c)
    np.testing.assert_allclose(got, np.array(q[2:]), rtol=1e-12, atol=1e-14)
    # from q0 and q̇0 alone: earlier samples extrapolated back along q̇0
    qd = np.array([0.3, -0.1])
    one = model.rollout(hist[-1], qd, u, DT)
    back = np.array([hist[-1] - 2 * DT * qd, hist[-1] - DT * qd, hist[-1]])
    np.testing.assert_allclose(one, model.rollout(back, None, u, DT), rtol=1e-12)


def test_unstable_orders_are_refused():
    """A random walk (unit root) with noise: the higher orders that fit the noise unstably are
    scored inf, never chosen."""
    rng = np.random.default_rng(5)
    data = []
    for j in range(3):
        q = np.cumsum(rng.normal(size=(200, 1)) * 0.01, axis=0)
        data.append({"id": j, "t": DT * np.arange(200), "q": q,
                     "u": rng.normal(size=(200, 1)), "qd": np.gradient(q, DT, axis=0)})
    fit = fit_lagged_arx(data)
    assert fit.info["spectral_radius"] <= 1.0 + 1e-9 or all(
        v is None for tried in fit.info["orders_tried"].values() for v in tried.values())
    assert np.isfinite(window_score(fit, data))


def test_json_round_trip_and_registry():
    data = _trajectories(_system(), trajs=3)
    fit = fit_baseline("arx_lags", data)
    back = baseline_from_dict(fit.to_dict())
    assert isinstance(back, LaggedARX) and back.order == fit.order
    u = np.ones((20, 1))
    np.testing.assert_allclose(back.rollout(np.zeros(2), None, u, DT),
                               fit.rollout(np.zeros(2), None, u, DT), rtol=1e-13, atol=1e-15)


def test_bad_input_is_a_one_line_user_error():
    data = _trajectories(_system(), trajs=2, steps=60)
    fit = fit_lagged_arx(data)
    d = fit.to_dict()
    for bad, what in (({**d, "order": 0}, "'order'"), ({**d, "dt": -1}, "'dt'"),
                      ({**d, "B": [[0.0]]}, "'B'")):
        with pytest.raises(UserError, match=what) as err:
            baseline_from_dict(bad)
        assert "\n" not in str(err.value)
    with pytest.raises(UserError, match="fitted at step"):
        fit.rollout(np.zeros(2), None, np.ones((5, 1)), 2 * DT)
    with pytest.raises(UserError, match="too few sample pairs"):
        fit_lagged_arx([{**data[0], "t": data[0]["t"][:3], "q": data[0]["q"][:3],
                         "u": data[0]["u"][:3], "qd": data[0]["qd"][:3]}])
    uneven = dict(data[0], t=np.cumsum(np.r_[0.0, np.full(59, DT)] * np.linspace(1, 2, 60)))
    with pytest.raises(UserError, match="one sample step"):
        fit_lagged_arx([uneven])


def test_rollout_jacobian_is_exact():
    """The sensitivities' recursion equals central differences of the residuals."""
    from softpinn.learn import _lagged_rollout as lr

    rng = np.random.default_rng(0)
    n, m, p = 2, 3, 3
    segs = [{"q": rng.normal(size=(60, n)) * 0.1, "u": rng.normal(size=(60, m))}
            for _ in range(2)]
    problem = lr._Problem(segs, p, 20, 2)
    theta = rng.normal(size=lr.parameters(n, m, p)) * 0.2
    h = 1e-6
    central = np.stack([(problem.residuals(theta + h * e) - problem.residuals(theta - h * e))
                        / (2 * h) for e in np.eye(theta.size)], axis=1)
    got = problem.jacobian(theta)
    assert got.shape == central.shape == (problem.windows * 20 * n, theta.size)
    assert np.max(np.abs(got - central)) <= 1e-8 * np.max(np.abs(central))


def test_noisy_angles_are_fitted_by_their_rollouts():
    """Sensor noise on q biases least squares on one-step pairs (errors in variables); the
    rollout fit is chosen and rolls out closer to the noise-free motion."""
    true = _system(seed=2)
    clean = _trajectories(true, trajs=5, steps=300, seed=3)
    rng = np.random.default_rng(4)
    scale = np.std(np.concatenate([s["q"] for s in clean]))
    noisy = [dict(s, q=s["q"] + 0.3 * scale * rng.normal(size=s["q"].shape)) for s in clean]
    fit = fit_lagged_arx(noisy)
    ls = fit_lagged_arx(noisy, rollout=False)
    assert fit.info["fit"] == "rollout" and ls.info["fit"] == "least squares"
    test = _trajectories(true, trajs=2, seed=9)
    err = {k: rollout_errors(f, test, 5.0).rollout_error_mean for k, f in
           (("rollout", fit), ("least squares", ls))}
    assert err["rollout"] < 0.8 * err["least squares"], err  # 0.028 against 0.044


def test_resets_pass_the_inputs_past():
    """predict's resets give the lagged ARX the measured past of q and of u: from there its
    rollout is the recurrence on the measured samples (exact on data it generated)."""
    true = _system(seed=6)
    data = _trajectories(true, trajs=1, steps=120, seed=7)
    err = rollout_errors(true, data, 5.0, reset_every=1.0)
    assert err.rollout_error_mean < 1e-24  # every reset from the exact past
    s = data[0]
    a = 40  # a reset sample: its past of q and of u reproduces the sample after it
    got = true.rollout(s["q"][a - 2:a + 1], s["qd"][a], s["u"][a:a + 10], DT,
                       u_past=s["u"][a - 2:a])
    np.testing.assert_allclose(got, s["q"][a:a + 10], rtol=1e-12, atol=1e-14)
    held = true.rollout(s["q"][a - 2:a + 1], s["qd"][a], s["u"][a:a + 10], DT)
    assert np.max(np.abs(held - s["q"][a:a + 10])) > 1e-6  # without it, the inputs are held
    with pytest.raises(UserError, match="u_past must have shape"):
        true.rollout(s["q"][a], None, s["u"][a:a + 3], DT, u_past=np.zeros((2, 5)))


def test_reports_and_predict_say_what_the_fit_chose():
    """The comparison carries the lagged ARX's order and fit (stored as JSON, older JSON without
    it still loads); the table's row and predict's line show it, the name stays."""
    import json

    from softpinn.bridge.analysis.baselines import BaselineComparison, compare_baselines
    from softpinn.bridge.report.baselines import baseline_rows

    data = [dict(s, qdd=np.gradient(s["qd"], DT, axis=0))
            for s in _trajectories(_system(), trajs=4, steps=200)]
    c = compare_baselines(data, [0, 1, 2], [3], [2.0])
    lag = next(s for s in c.scores if s.kind == "arx_lags")
    # an exact fit: least squares keeps its ridge (1e-9), the rollout fit polishes it away
    assert lag.name == "lagged ARX" and lag.detail == "order 3, rollout fit"
    assert lag.label == "lagged ARX (order 3, rollout fit)"
    stored = json.loads(json.dumps(c.to_json()))
    assert BaselineComparison.from_json(stored) == c
    for s in stored["scores"]:
        s.pop("detail", None)
    assert BaselineComparison.from_json(stored).scores[0].detail == ""
    labels = [row[0] for row in baseline_rows({}, c)]
    assert "lagged ARX (order 3, rollout fit)" in labels and "ARX (order 2)" in labels
