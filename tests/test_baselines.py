"""Linear baselines (learn/_baselines.py) and their rollout errors (learn/_baseline_errors.py):
exact recovery of known linear systems, predict's metric reproduced (against learn's own
evaluate and by hand), JSON round trips, the out-of-range flag, and one-line user errors."""

from __future__ import annotations

import json

import jax.numpy as jnp
import numpy as np
import pytest
from datagen import make_dataset, msd_matrices

from softpinn.errors import UserError
from softpinn.learn._baseline_errors import rollout_errors
from softpinn.learn._baseline_kinds import baseline_from_dict, fit_baseline
from softpinn.learn._baselines import (
    ARX,
    LinearSecondOrder,
    NoMotion,
    fit_arx,
    fit_linear_second_order,
)
from softpinn.learn._data import load_dataset, trajectories
from softpinn.learn._models import DynamicsModel, ModelConfig
from softpinn.learn._predict import evaluate

DT = 0.05


def _discrete(A, B, c, *, trajs=4, steps=80, seed=0):
    """Trajectories of q_{k+1} = Σ_i A[i] q_{k-i} + B u_k + c from random starts and inputs."""
    rng = np.random.default_rng(seed)
    p, n, _ = A.shape
    out = []
    for j in range(trajs):
        q = [rng.normal(size=n) for _ in range(p)]
        u = rng.normal(size=(steps + p, B.shape[1]))
        for k in range(p - 1, steps + p - 1):
            q.append(sum(A[i] @ q[k - i] for i in range(p)) + B @ u[k] + c)
        q = np.array(q)
        t = DT * np.arange(q.shape[0])
        out.append({"id": j, "t": t, "q": q, "u": u[: q.shape[0]], "qd": np.zeros_like(q)})
    return out


def _stable(rng, n, radius):
    A = rng.normal(size=(n, n))
    return radius * A / np.max(np.abs(np.linalg.eigvals(A)))


def test_arx_recovers_a_known_discrete_system():
    rng = np.random.default_rng(1)
    A, B, c = _stable(rng, 3, 0.9)[None], rng.normal(size=(3, 2)), rng.normal(size=3)
    data = _discrete(A, B, c)
    exact = fit_arx(data, ridge=0.0)
    np.testing.assert_allclose(exact.A, A, atol=1e-10)
    np.testing.assert_allclose(exact.B, B, atol=1e-10)
    np.testing.assert_allclose(exact.c, c, atol=1e-10)
    assert exact.dt == pytest.approx(DT) and exact.info["rank"] == exact.info["unknowns"] == 6
    ridged = fit_arx(data)  # the default ridge only conditions the solve
    np.testing.assert_allclose(ridged.A, A, atol=1e-6)
    np.testing.assert_allclose(ridged.c, c, atol=1e-6)
    # its rollout from a trajectory's start under its inputs is the trajectory
    tr = data[2]
    q = exact.rollout(tr["q"][0], None, tr["u"], DT)
    np.testing.assert_allclose(q, tr["q"], atol=1e-9)


def test_arx_of_order_two_and_its_history():
    rng = np.random.default_rng(2)
    A = np.stack([_stable(rng, 2, 0.6), _stable(rng, 2, 0.3)])
    B, c = rng.normal(size=(2, 1)), np.array([0.1, -0.2])
    data = _discrete(A, B, c)
    model = fit_arx(data, order=2, ridge=0.0)
    assert model.order == 2
    np.testing.assert_allclose(model.A, A, atol=1e-10)
    np.testing.assert_allclose(model.B, B, atol=1e-10)
    tr = data[0]
    q = model.rollout(tr["q"][:2], None, tr["u"][1:], DT)  # history: q_{-1}, q_0
    np.testing.assert_allclose(q, tr["q"][1:], atol=1e-9)
    # from q0 alone, the sample before is extrapolated back along q̇0
    q0, qd0 = tr["q"][1], (tr["q"][1] - tr["q"][0]) / DT
    np.testing.assert_allclose(model.rollout(q0, qd0, tr["u"][1:], DT), q, atol=1e-9)


def test_arx_keeps_a_constant_coordinate_constant():
    # an unobserved coordinate held at zero (a tip IMU's dL) is predicted as zero, not moved
    rng = np.random.default_rng(3)
    A = np.zeros((1, 2, 2))
    A[0, 0, 0] = 0.8
    data = _discrete(A, np.array([[1.0], [0.0]]), np.zeros(2), seed=4)
    for tr in data:
        tr["q"][:, 1] = 0.0
    model = fit_arx(data)
    q = model.rollout(np.array([0.3, 0.0]), None, rng.normal(size=(50, 1)), DT)
    assert np.all(q[:, 1] == 0.0)


@pytest.fixture(scope="module")
def msd(tmp_path_factory):
    """The forced two-mass spring-damper of eq. 25 (linear), simulated finely (datagen)."""
    path = make_dataset(tmp_path_factory.mktemp("bl") / "msd.npz", trajectories=4,
                        duration=4.0)
    return load_dataset(path)


def test_linear_second_order_recovers_a_damped_oscillator(msd):
    M, K, D, A = msd_matrices()
    model = fit_linear_second_order(msd, [0, 1, 2])
    Minv = np.linalg.inv(M)
    mats = model.matrices()
    np.testing.assert_allclose(mats["K"], Minv @ K, atol=1e-8)
    np.testing.assert_allclose(mats["D"], Minv @ D, atol=1e-8)
    np.testing.assert_allclose(mats["B"], Minv @ A, atol=1e-8)
    np.testing.assert_allclose(mats["c"], 0.0, atol=1e-8)
    np.testing.assert_array_equal(mats["M"], np.eye(2))
    assert model.info["max_real_eigenvalue"] < 0
    # exact (expm) rollouts under a first-order hold of the sinusoidal inputs are close to the
    # truth; RK4 at the data's step is close to expm
    exact = rollout_errors(model, msd, 3.0, traj_ids=[3], input_hold="linear")
    assert exact.rollout_error_mean < 1e-6 and exact.diverged == 0 and not exact.out_of_range
    rk4 = LinearSecondOrder.from_dict({**model.to_dict(), "integrator": "rk4"})
    close = rollout_errors(rk4, msd, 3.0, traj_ids=[3], input_hold="linear")
    assert close.rollout_error_mean < 1e-5


class LinearField(DynamicsModel):
    """ẋ = F x + G [u; 1] as a learn model, for predict's own rollouts."""

    F: jnp.ndarray = None
    G: jnp.ndarray = None

    @property
    def state_kind(self):
        return "velocity"

    def vector_field(self, x, u):
        return self.F @ x + self.G @ jnp.concatenate([u, jnp.ones(1)])


@pytest.mark.parametrize("hold", ["constant", "linear"])
def test_metric_is_predicts(msd, hold):
    # a slightly wrong linear model, stepped by RK4 at the data's step: learn's evaluate and
    # rollout_errors give the same error per trajectory, with and without resets
    model = fit_linear_second_order(msd, [0, 1, 2], integrator="rk4")
    wrong = LinearSecondOrder(1.2 * model.A_q, model.A_v, model.B_u, model.c, model.q_low,
                              model.q_high, "rk4")
    F, G = wrong._field()
    net = LinearField(ModelConfig(kind="blackbox", n=2, m=1, hidden=(4, 1)),
                      F=jnp.asarray(F), G=jnp.asarray(G))
    for reset in (None, 0.7):
        ref = evaluate(net, msd, [0, 3], horizon=3.0, reset_every=reset, input_hold=hold)
        ours = rollout_errors(wrong, msd, 3.0, traj_ids=[0, 3], reset_every=reset,
                              input_hold=hold)
        np.testing.assert_allclose(ours.rollout_errors, ref.rollout_errors, rtol=1e-9)
        assert ours.rollout_error_mean == pytest.approx(ref.rollout_error_mean, rel=1e-9)
        np.testing.assert_allclose(ours.rollouts[1]["resets"], ref.rollouts[1]["resets"])
        js = ours.to_json()
        assert js["rollout_errors"] == pytest.approx(ref.to_json()["rollout_errors"], rel=1e-9)
        assert js["model"] == "linear2" and js["rollout_diverged"] == 0


def test_no_motion_error_is_the_closed_form(msd):
    model = NoMotion.fit(msd, [0, 1])
    res = rollout_errors(model, trajectories(msd, [2, 3]), 2.0)
    for tid, err in zip([2, 3], res.rollout_errors, strict=True):
        rows = msd.indices(tid)
        q = msd.q[rows][msd.t[rows] - msd.t[rows][0] <= 2.0 + 1e-9]
        assert q.shape[0] == 41
        assert err == pytest.approx(np.mean(np.sum((q[1:] - q[0]) ** 2, axis=1)), rel=1e-14)


def test_metric_by_hand():
    # four samples 1 s apart, horizon 2 s: the samples at t = 1, 2 count
    tr = {"id": 7, "t": np.array([0.0, 1.0, 2.0, 3.0]), "q": np.array([[0.0], [1.0], [3.0],
                                                                      [9.0]]),
          "qd": np.zeros((4, 1)), "u": np.zeros((4, 0))}
    hold = NoMotion(1, 0, np.array([0.0]), np.array([3.0]))
    res = rollout_errors(hold, [tr], 2.0)
    assert res.rollout_errors == [pytest.approx((1.0 + 9.0) / 2)] and res.trajectories == [7]
    assert res.out_of_range == []
    # re-set to the truth every 1.5 s: at t = 2 the prediction is the truth, (1 + 0) / 2
    assert rollout_errors(hold, [tr], 2.0, reset_every=1.5).rollout_errors == [0.5]
    assert rollout_errors(hold, [tr], 3.0, reset_every=2.0).rollout_errors == [
        pytest.approx((1.0 + 0.0 + 36.0) / 3)]  # from t = 2 it holds q = 3: (9 - 3)² at t = 3
    with pytest.raises(UserError, match="horizon"):
        rollout_errors(hold, [tr], 10.0)


def test_out_of_range_and_diverged_rollouts_are_flagged():
    rng = np.random.default_rng(5)
    data = _discrete(_stable(rng, 2, 0.5)[None], np.zeros((2, 1)), np.zeros(2), steps=40)
    good = fit_arx(data)
    bad = ARX(1.5 * np.eye(2)[None], good.B, good.c, good.dt, good.q_low, good.q_high)
    res = rollout_errors(bad, data, 1.5)
    assert sorted(res.out_of_range) == [0, 1, 2, 3]
    assert res.to_json()["rollout_out_of_range"] == 4
    huge = ARX(1e300 * np.eye(2)[None], good.B, good.c, good.dt, good.q_low, good.q_high)
    res = rollout_errors(huge, data, 1.5)
    assert res.diverged == 4 and res.to_json()["rollout_error_mean"] is None
    assert rollout_errors(good, data, 1.5).out_of_range == []


def test_json_round_trip(msd):
    for kind, opts in (("arx", {"order": 2}), ("linear2", {}), ("no_motion", {})):
        model = fit_baseline(kind, msd, [0, 1], **opts)
        back = baseline_from_dict(json.loads(json.dumps(model.to_dict())))
        assert type(back) is type(model) and back.kind == kind
        a = rollout_errors(model, msd, 2.0, traj_ids=[2, 3]).rollout_errors
        b = rollout_errors(back, msd, 2.0, traj_ids=[2, 3]).rollout_errors
        np.testing.assert_allclose(b, a, rtol=1e-12)
    assert fit_baseline("arx", msd).info["trajectories"] == [0, 1, 2]  # the default split
    with pytest.raises(UserError, match="kind"):
        baseline_from_dict({"kind": "quadratic"})
    with pytest.raises(UserError, match="'A'"):
        baseline_from_dict({**model.to_dict(), "kind": "arx", "order": 1, "dt": 0.05,
                            "A": [[1.0]], "B": [[0.0]], "c": [0.0, 0.0]})


def _one_line(exc):
    assert "\n" not in str(exc.value)


def test_bad_input_is_a_one_line_user_error(msd):
    short = [{"t": np.arange(3) * DT, "q": np.zeros((3, 2)), "u": np.zeros((3, 1)),
              "qd": np.zeros((3, 2)), "qdd": np.zeros((3, 2))}]
    for fit in (fit_arx, fit_linear_second_order):
        with pytest.raises(UserError, match="coefficients") as e:
            fit(short)
        _one_line(e)
    with pytest.raises(UserError, match="like the first") as e:
        fit_arx([*short, {"t": np.arange(5.0), "q": np.zeros((5, 3)), "u": np.zeros((5, 1))}])
    _one_line(e)
    with pytest.raises(UserError, match="one sample step") as e:
        fit_arx([{"t": np.array([0.0, 0.1, 0.3, 0.4]), "q": np.zeros((4, 1)),
                  "u": np.zeros((4, 0))}])
    _one_line(e)
    model = fit_arx(msd, [0, 1, 2])
    for args, what in (((np.zeros(3), None, np.zeros((5, 1)), 0.05), "q0"),
                       ((np.zeros(2), None, np.zeros((5, 2)), 0.05), "u_seq"),
                       ((np.zeros(2), None, np.zeros((5, 1)), 0.01), "step")):
        with pytest.raises(UserError, match=what) as e:
            model.rollout(*args)
        _one_line(e)
    other = NoMotion(3, 1, np.zeros(3), np.ones(3))
    with pytest.raises(UserError, match="n=3") as e:
        rollout_errors(other, msd, 1.0)
    _one_line(e)
    with pytest.raises(UserError, match="order"):
        fit_arx(msd, order=3)
    with pytest.raises(UserError, match="ridge"):
        fit_arx(msd, ridge=-1.0)
