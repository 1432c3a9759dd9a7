"""Meaningless prediction requests refused with one line before any work (issue 15): a horizon
longer than the data, a step longer than the horizon, a step so small that the arrays would not
fit, a member a one-seed run does not have."""

from __future__ import annotations

import importlib

import numpy as np
import pytest
from datagen import blackbox_train_config, make_dataset

from softpinn.bridge.cli import main
from softpinn.errors import UserError
from softpinn.learn._predict import predict
from softpinn.learn._train import train


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    base = tmp_path_factory.mktemp("lim")
    data = make_dataset(base / "msd.npz", trajectories=5, duration=3.0)
    train(data, blackbox_train_config(), base / "run")
    return base / "run", data


@pytest.mark.parametrize(
    "flags, message",
    [
        (["--horizon", "1e6"], "--horizon: 1e+06 s is longer than the trajectories (3 s at most"),
        (["--horizon", "1", "--dt", "10"], "--dt: 10 s is longer than the horizon (1 s)"),
        (["--horizon", "1", "--dt", "1e-9"], "--dt: 1e-09 s makes 1e+09 steps per trajectory"),
        (["--horizon", "1", "--member", "3"], "--member: run "),
        (["--horizon", "nan"], "--horizon: expected a positive number of seconds, got nan"),
        (["--horizon", "1", "--dt", "inf"], "--dt: expected a positive number of seconds"),
    ],
)
def test_one_line_errors(run, flags, message, capsys):
    out, data = run
    assert main(["predict", str(out), str(data), *flags]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("softpinn: error: " + message), err


def test_tiny_dt_is_refused_before_allocating(run, monkeypatch):
    out, data = run
    pr = importlib.import_module("softpinn.learn._predict")
    monkeypatch.setattr(pr, "_interp_rows", lambda *a: pytest.fail("allocated the grid"))
    with pytest.raises(UserError, match=r"about .* GiB, the limit is 2 GiB"):
        predict(out, data, horizon=1.0, dt=1e-9)


def test_horizon_of_the_data_length_is_accepted(run):
    out, data = run
    t = np.load(data)["t"]
    step = float(t[1] - t[0])
    res = predict(out, data, horizon=3.0 + step)  # samples end at 3 s: one step more is fine
    assert res.rollouts[0]["t"][-1] == pytest.approx(3.0)
    with pytest.raises(UserError, match="longer than the trajectories"):
        predict(out, data, horizon=3.0 + 2 * step)
    assert predict(out, data, horizon=1.0, member=0).extra["seed"] == 0
