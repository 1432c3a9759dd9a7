"""MPC behind an actuator (issue 43 item 2, bridge/control/actuation.py): the controller plans
the commands through the lag (its states tracked from the commands sent) and across the dead
time (the commands in transit rolled first), the plant applies the same actuator, and a run
trained with an actuator controls through it."""

from __future__ import annotations

import json

import numpy as np
import pytest
from datagen import make_dataset, tiny_model_config

from softpinn.actuator import Actuator
from softpinn.bridge.control import (
    MPC,
    ControlConfig,
    MPCConfig,
    closed_loop,
    compare,
    equilibrium,
    from_true,
    plant,
    tip_output,
)
from softpinn.bridge.control.models import actuate
from softpinn.errors import UserError
from softpinn.learn import TrainConfig, train
from softpinn.symbolic import TrueModel

#: compiled libraries go to a cache of this test session (conftest.py)
pytestmark = pytest.mark.usefixtures("session_cache")


def _loop(spec, act, steps=40, dt=0.05, **kw):
    tm = TrueModel(spec)
    out = tip_output(tm.spec)
    q_star, _ = equilibrium(tm, [0.3, -0.2])
    cfg = MPCConfig(horizon=10, dt=dt, weight_y=1e2, weight_du=1e-3, codegen=False, **kw)
    mpc = MPC(actuate(from_true(tm, out), act), cfg)
    R = np.tile(np.asarray(out(q_star)).ravel(), (steps + cfg.horizon + mpc.delay, 1))
    res = closed_loop(mpc, plant(tm, dt, actuator=act), np.zeros(2 * tm.n), R, steps,
                      u0=np.zeros(tm.m), actuator=act)
    return res, np.asarray(out(q_star)).ravel()


@pytest.mark.parametrize("text", ["0.1:0", "0.1:0.1", "0.1,0:0"])
def test_the_true_model_behind_an_actuator_reaches_a_step(msd_full_spec, text):
    act = Actuator.parse(text, 2)
    res, target = _loop(msd_full_spec, act)
    plain, _ = _loop(msd_full_spec, None)
    assert not res["diverged"] and np.all(res["success"])
    err = np.linalg.norm(res["y"] - target, axis=1)
    assert np.all(np.isfinite(err)) and err[-1] < 1e-3 * err[0], err[::5]
    # the commands differ from those for an arm without the actuator
    assert np.max(np.abs(res["u"] - plain["u"])) > 1e-3
    # the plant's actuator: its output follows the exact lag of the commands D steps earlier
    tau, delay = act.per_input(2)
    D = int(round(delay[0] / 0.05))
    sent = np.concatenate([np.zeros((D, 2)), res["u"]])[:len(res["u_arm"])]  # u_{k-D}
    arm = res["u_arm"]
    for j in range(2):
        if tau[j] == 0:  # no lag: the command D steps earlier itself
            np.testing.assert_allclose(arm[:, j], sent[:, j], atol=1e-12)
        else:
            a = np.exp(-0.05 / tau[j])
            want = a * arm[:-1, j] + (1 - a) * sent[:-1, j]
            np.testing.assert_allclose(arm[1:, j], want, rtol=1e-6, atol=1e-6)  # cvodes


@pytest.mark.parametrize("kw", [dict(solver="ipopt"), dict(offset_free=0.5),
                                dict(sensitivities="lifted")])
def test_solvers_and_estimates_behind_a_dead_time(msd_full_spec, kw):
    """IPOPT, the disturbance estimate and the lifted SQP see the same augmented model."""
    res, target = _loop(msd_full_spec, Actuator.parse("0.1:0.1", 2), **kw)
    err = np.linalg.norm(res["y"] - target, axis=1)
    assert not res["diverged"] and err[-1] < 1e-3 * err[0], err[::5]


def test_dead_times_the_controller_cannot_take_are_refused(msd_spec):
    tm = TrueModel(msd_spec)
    model = actuate(from_true(tm, tip_output(tm.spec)), Actuator.parse("0.1:0.07", 1))
    with pytest.raises(UserError, match="whole number of control steps"):
        MPC(model, MPCConfig(horizon=5, dt=0.05, codegen=False))


def test_a_run_with_an_actuator_controls_through_it(msd_spec, tmp_path):
    data = make_dataset(tmp_path / "msd.npz", trajectories=3, duration=2.0)
    runs = {}
    for name, act in (("lag", "0.1:0"), ("plain", "none")):
        cfg = TrainConfig(model=tiny_model_config("lagrangian"), epochs=3, batch_size=64,
                          lr=1e-2, test_trajectories=(2,), checkpoint_every=1000, actuator=act)
        train(data, cfg, tmp_path / name)
        runs[name] = tmp_path / name
    mpc = MPCConfig(horizon=8, dt=0.05, u_min=(-5.0,), u_max=(5.0,), codegen=False)
    control = ControlConfig(mpc=mpc, duration=0.5, references=("step",))
    with_act = compare(msd_spec, [runs["lag"]], tmp_path / "c1", control, names=["net"])
    without = compare(msd_spec, [runs["plain"]], None, control, names=["net"])
    assert with_act["plant"]["actuator"]["text"] == "0.1:0"
    assert "actuator" not in without["plant"]
    assert with_act["controllers"]["net"]["actuator"]["time_constant"] == [0.1]
    for name, met in with_act["results"]["step"].items():
        assert met["steps"] == 10 and not met["diverged"], name
        assert np.isfinite(met["error_rms"]) and np.isfinite(met["error_max"]), name
    u1 = with_act["traces"]["step"]["net"]["u"]
    u0 = without["traces"]["step"]["net"]["u"]
    assert np.max(np.abs(u1 - u0)) > 1e-6
    meta = json.loads((tmp_path / "c1" / "models" / "net" / "model.json").read_text())
    assert meta["actuator"]["text"] == "0.1:0"
    with np.load(tmp_path / "c1" / "traces" / "step.npz") as traces:
        assert traces["net__u_arm"].shape == (10, 1)
