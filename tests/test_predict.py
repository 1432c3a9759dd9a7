"""Prediction (learn/_predict.py) against an exact analytic model of eq. 25: the rollout error is
only RK4's discretisation error, falls like dt^4 with a finer step, and a perturbed model's
error shrinks when the state is re-set to the truth."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest
from datagen import blackbox_train_config, make_dataset, msd_matrices, simulate, write

from softpinn.errors import UserError
from softpinn.learn._data import load_dataset, trajectories
from softpinn.learn._models import DynamicsModel, ModelConfig
from softpinn.learn._predict import _reset_mask, evaluate, predict, rollouts
from softpinn.learn._train import train


class ExactMSD(DynamicsModel):
    """The true vector field of eq. 25 (forced on mass 2), stiffness scaled by ``k_scale``."""

    k_scale: float = 1.0

    @property
    def state_kind(self):
        return "velocity"

    def vector_field(self, x, u):
        M, K, B, A = (jnp.asarray(a) for a in msd_matrices(forced=self.config.m == 1))
        q, qd = x[:2], x[2:]
        qdd = jnp.linalg.solve(M, A @ u - self.k_scale * (K @ q) - B @ qd)
        return jnp.concatenate([qd, qdd])


CFG = ModelConfig(kind="blackbox", n=2, m=0, hidden=(4, 1))  # unforced (eq. 25 as printed)
CFG_FORCED = ModelConfig(kind="blackbox", n=2, m=1, hidden=(4, 1))


@pytest.fixture(scope="module")
def msd(tmp_path_factory):
    path = make_dataset(tmp_path_factory.mktemp("p") / "msd.npz", trajectories=5, duration=4.0)
    return load_dataset(path)


@pytest.fixture(scope="module")
def free(tmp_path_factory):
    path = make_dataset(
        tmp_path_factory.mktemp("p") / "free.npz", trajectories=3, duration=4.0, forced=False
    )
    return load_dataset(path)


def test_exact_model_rollout_is_rk4_accurate(free):
    msd = free
    exact = ExactMSD(CFG)
    res = evaluate(exact, msd, [0, 1, 2], horizon=3.0)
    assert res.trajectories == [0, 1, 2] and len(res.rollout_errors) == 3
    assert res.rollout_error_mean < 1e-10
    assert res.one_step_error["mean"] < 1e-13 and res.one_step_error["pairs"] == 3 * 80
    assert res.rollout_error_std == pytest.approx(np.std(res.rollout_errors))
    # halving the step divides the (global, squared) RK4 error by about (2^4)^2
    fine = evaluate(exact, msd, [0, 1, 2], horizon=3.0, dt=0.025)
    coarse = evaluate(exact, msd, [0, 1, 2], horizon=3.0, dt=0.1)
    assert fine.rollout_error_mean < res.rollout_error_mean / 50
    assert coarse.rollout_error_mean > res.rollout_error_mean * 50
    ro = res.rollouts[0]
    assert ro["t"][0] == 0.0 and ro["t"][-1] == pytest.approx(3.0) and ro["t"].size == 61


def test_input_hold_of_forced_data(msd):
    # the data's input is a continuous sinusoid: holding it linearly between samples is more
    # accurate than holding it constant
    exact = ExactMSD(CFG_FORCED)
    const = evaluate(exact, msd, [0, 1], horizon=3.0)
    lin = evaluate(exact, msd, [0, 1], horizon=3.0, input_hold="linear")
    assert lin.rollout_error_mean < const.rollout_error_mean / 100
    assert lin.one_step_error["mean"] < const.one_step_error["mean"] / 100


def test_step_that_does_not_divide_the_data_step(free):
    exact = ExactMSD(CFG)
    res = evaluate(exact, free, [0], horizon=2.0, dt=0.03)
    # compared at the data times by interpolating the prediction: accurate, not exact
    assert 1e-12 < res.rollout_error_mean < 1e-4
    assert res.rollouts[0]["t"].size == 41


def test_reset_reduces_the_error_of_a_wrong_model(free):
    msd = free
    wrong = ExactMSD(CFG, k_scale=1.2)
    long = evaluate(wrong, msd, [0, 1], horizon=4.0)
    short = evaluate(wrong, msd, [0, 1], horizon=1.0)
    reset = evaluate(wrong, msd, [0, 1], horizon=4.0, reset_every=1.0)
    assert long.rollout_error_mean > 5 * short.rollout_error_mean
    assert reset.rollout_error_mean < long.rollout_error_mean / 5
    np.testing.assert_allclose(reset.rollouts[0]["resets"], [1.0, 2.0, 3.0, 4.0])
    # before the first reset the re-set rollout is the plain rollout; at t = 1 s it is the truth
    ro = reset.rollouts[0]
    np.testing.assert_allclose(ro["q_pred"][:20], short.rollouts[0]["q_pred"][:20], rtol=1e-12)
    np.testing.assert_array_equal(ro["q_pred"][20], ro["q_true"][20])
    assert np.abs(ro["q_pred"][19] - ro["q_true"][19]).max() > 1e-3


def test_chunked_rollouts_and_errors_equal_one_call(free, monkeypatch):
    # rollouts longer than a chunk continue from the chunk before (resets across a chunk's edge
    # included) and pairs are evaluated a chunk at a time: the same numbers as in one call
    import sys

    predict_mod = sys.modules[evaluate.__module__]  # learn._predict (the name is a function)
    wrong = ExactMSD(CFG, k_scale=1.2)
    one = evaluate(wrong, free, [0, 1, 2], horizon=4.0, reset_every=0.7)
    other = rollouts(wrong, trajectories(free, [0, 1]), horizon=3.0, dt=0.03)
    monkeypatch.setattr(predict_mod, "ROLLOUT_CHUNK", 7)
    monkeypatch.setattr(predict_mod, "PAIR_CHUNK", 32)
    calls = []
    real = predict_mod._batched_rollout
    monkeypatch.setattr(predict_mod, "_batched_rollout",
                        lambda *a, **k: calls.append(a[2].shape) or real(*a, **k))
    chunked = evaluate(wrong, free, [0, 1, 2], horizon=4.0, reset_every=0.7)
    assert calls and {c[1] for c in calls} == {8}  # 7 steps and the start, every call
    assert len(calls) == -(-(chunked.rollouts[0]["t"].size - 1) // 7)
    for a, b in zip(one.rollouts, chunked.rollouts, strict=True):
        np.testing.assert_array_equal(a["q_pred"], b["q_pred"])
        np.testing.assert_array_equal(a["resets"], b["resets"])
    assert chunked.one_step_error == one.one_step_error and one.one_step_error["pairs"] > 32
    again = rollouts(wrong, trajectories(free, [0, 1]), horizon=3.0, dt=0.03)
    for a, b in zip(other, again, strict=True):
        np.testing.assert_array_equal(a["q_pred"], b["q_pred"])


def test_reset_mask():
    t = np.arange(0.0, 1.01, 0.1)
    np.testing.assert_array_equal(np.flatnonzero(_reset_mask(t, 0.0, 0.25)), [3, 5, 8, 10])
    assert not _reset_mask(t, 0.0, None).any()


def test_variable_step_data_and_padding(tmp_path):
    arrays = simulate("msd", trajectories=2, duration=2.0, rate=20.0, forced=False)
    keep = np.ones(arrays["t"].size, bool)
    keep[5:9] = False  # drop samples of trajectory 0: uneven steps and unequal lengths
    ds = load_dataset(write(tmp_path / "v.npz", {k: v[keep] for k, v in arrays.items()}))
    res = evaluate(ExactMSD(CFG), ds, [0, 1], horizon=2.0)
    assert res.rollout_error_mean < 1e-7  # one RK4 step spans the 0.25 s gap
    assert [r["t"].size for r in res.rollouts] == [37, 41]
    with pytest.raises(UserError, match="horizon: 0.01 s is shorter than the first step"):
        rollouts(ExactMSD(CFG), trajectories(ds, [0]), horizon=0.01)


def test_predict_on_run_dir_and_plot(msd, tmp_path):
    train(msd, blackbox_train_config(), tmp_path / "run")
    res = predict(tmp_path / "run", msd.path, horizon=2.0, plot=tmp_path / "roll.png")
    assert res.trajectories == [4] and res.extra["split"] == "test"
    assert (tmp_path / "roll.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    out = res.to_json()
    for key in ("one_step_error", "rollout_error_mean", "rollout_error_std", "horizon"):
        assert key in out
    # the one-step error equals the training loss of the saved (best) model
    from softpinn.learn._train import load_run

    run = load_run(tmp_path / "run")
    assert out["one_step_error"]["mean"] == pytest.approx(
        min(
            r["test_loss"]
            for r in __import__("softpinn.learn._checkpoint", fromlist=["x"]).read_history(
                tmp_path / "run" / "history.csv"
            )
        ),
        rel=1e-9,
    )
    assert run.seed == 0
    res_all = predict(tmp_path / "run", msd.path, horizon=1.0, trajectories="all")
    assert res_all.trajectories == [0, 1, 2, 3, 4]
    other = make_dataset(tmp_path / "other.npz", trajectories=2, duration=2.0, seed=7)
    assert predict(tmp_path / "run", other, horizon=1.0).trajectories == [0, 1]
    with pytest.raises(UserError, match="no test split"):
        predict(tmp_path / "run", other, horizon=1.0, trajectories="test")
    pend = make_dataset(tmp_path / "pend.npz", "pendulum", trajectories=2, duration=1.0)
    with pytest.raises(UserError, match="model has n=2 coordinates, the file has n=1"):
        predict(tmp_path / "run", pend, horizon=1.0)
    with pytest.raises(UserError, match="horizon: expected a positive number of seconds"):
        predict(tmp_path / "run", msd.path, horizon=0.0)
