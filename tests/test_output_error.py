"""The linear second-order model fitted by its rollout error (learn/_output_error.py, issue
43): it recovers a known linear system where the q̈ labels mislead least squares, is never worse
than least squares on its own objective, round-trips as a baseline, and refuses bad input in
one line."""

from __future__ import annotations

import json

import numpy as np
import pytest
from datagen import make_dataset, msd_matrices

from softpinn.errors import UserError
from softpinn.learn._baseline_errors import rollout_errors
from softpinn.learn._baseline_kinds import baseline_from_dict, fit_baseline
from softpinn.learn._baselines import fit_linear_second_order
from softpinn.learn._data import load_dataset
from softpinn.learn._output_error import LinearRolloutFit, fit_linear_rollout, window_error
from softpinn.learn._trajectories import trajectory_arrays


@pytest.fixture(scope="module")
def msd(tmp_path_factory):
    """The forced two-mass spring-damper of eq. 25 (linear), simulated finely (datagen)."""
    path = make_dataset(tmp_path_factory.mktemp("oe") / "msd.npz", trajectories=4,
                        duration=4.0)
    return load_dataset(path)


def _misled(msd, ids):
    """The trajectories with q̈ labels 30 % too small (as a heavy smoother leaves them)."""
    segs = trajectory_arrays(msd, ids, need=("t", "q", "qd", "qdd", "u"))
    return [{**s, "qdd": 0.7 * s["qdd"]} for s in segs]


def test_the_rollout_fit_recovers_the_system_least_squares_misses(msd):
    M, K, D, A = msd_matrices()
    Minv = np.linalg.inv(M)
    segs = _misled(msd, [0, 1, 2])
    ls = fit_linear_second_order(segs)
    oe = fit_linear_rollout(segs, horizon=2.0, input_hold="linear")
    assert np.abs(ls.matrices()["K"] - Minv @ K).max() > 0.1 * np.abs(Minv @ K).max()
    for key, true in (("K", Minv @ K), ("D", Minv @ D), ("B", Minv @ A)):
        np.testing.assert_allclose(oe.matrices()[key], true, atol=5e-3 * np.abs(true).max())
    info = oe.info
    assert info["fit"] == "rollout" and info["horizon"] == pytest.approx(2.0)
    assert info["rollout_error"] < 1e-6 * info["least_squares_rollout_error"]
    assert [s["steps"] for s in info["stages"]] == sorted(s["steps"] for s in info["stages"])
    # its objective is window_error on the training trajectories; held out, it is as good
    assert window_error(oe, segs, horizon=2.0, input_hold="linear") == pytest.approx(
        info["rollout_error"], rel=1e-12)
    held = [rollout_errors(f, msd, 3.0, traj_ids=[3], input_hold="linear").rollout_error_mean
            for f in (ls, oe)]
    assert held[1] < 1e-3 * held[0]


def test_never_worse_than_least_squares_on_its_objective(msd):
    exact = fit_linear_second_order(msd, [0, 1])  # the true labels: least squares is right
    oe = fit_linear_rollout(msd, [0, 1], horizon=1.0)
    assert oe.info["rollout_error"] <= oe.info["least_squares_rollout_error"]
    assert window_error(oe, msd, [0, 1], horizon=1.0) <= window_error(exact, msd, [0, 1],
                                                                       horizon=1.0)


def test_round_trip_as_a_baseline(msd):
    model = fit_baseline("linear2_rollout", msd, [0, 1], horizon=1.0)
    assert isinstance(model, LinearRolloutFit) and model.to_dict()["kind"] == "linear2_rollout"
    back = baseline_from_dict(json.loads(json.dumps(model.to_dict())))
    assert type(back) is LinearRolloutFit and back.info["fit"] == "rollout"
    a = rollout_errors(model, msd, 2.0, traj_ids=[2, 3]).rollout_errors
    np.testing.assert_allclose(rollout_errors(back, msd, 2.0, traj_ids=[2, 3]).rollout_errors,
                               a, rtol=1e-12)
    with pytest.raises(UserError, match="baseline linear2_rollout: 'A_q'"):
        baseline_from_dict({**model.to_dict(), "A_q": [[1.0]]})


def test_bad_input_is_one_line(msd):
    segs = trajectory_arrays(msd, [0, 1], need=("t", "q", "qd", "qdd", "u"))
    for bad in (0.0, -1.0, float("nan"), "5"):
        with pytest.raises(UserError, match="horizon: expected a positive number") as e:
            fit_linear_rollout(segs, horizon=bad)
        assert "\n" not in str(e.value)
    with pytest.raises(UserError, match="input_hold"):
        fit_linear_rollout(segs, input_hold="cubic")
    uneven = [{**s, "t": s["t"] * (1 + 0.01 * np.arange(s["t"].size) / s["t"].size)}
              for s in segs]
    with pytest.raises(UserError, match="needs one sample step") as e:
        fit_linear_rollout(uneven)
    assert "\n" not in str(e.value)
