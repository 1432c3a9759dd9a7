"""Actuator dynamics between recorded commands and the arm (issue 43, item 2): the filter against
closed forms, its text form and errors, the identification from data, and a run that trains and
predicts through it."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
from datagen import blackbox_train_config, make_dataset

from softpinn.actuator import Actuator, lag
from softpinn.bridge.cli import main
from softpinn.errors import UserError
from softpinn.learn import TrainConfig, evaluate, identify_actuator, load_dataset, predict, train
from softpinn.learn._actuator import resolve_actuator, with_actuator


def test_lag_of_a_ramp_is_the_closed_form():
    # τ ẏ = t - y, y(0) = 0: y = t - τ (1 - e^{-t/τ}); exact for inputs linear between samples
    t = np.linspace(0.0, 2.0, 101)
    tau = 0.3
    y = lag(t, t.copy(), tau)
    assert np.allclose(y, t - tau * (1 - np.exp(-t / tau)), rtol=0, atol=1e-13)


def test_uneven_samples_give_the_same_values_as_even_ones():
    rng = np.random.default_rng(0)
    t = np.linspace(0.0, 3.0, 151)
    c = rng.normal(size=151)
    even = lag(t, c, 0.2)
    t_uneven = t.copy()
    t_uneven[-1] += 1e-7  # not uniform: the recursion instead of the IIR filter
    uneven = lag(t_uneven, c, 0.2)
    assert np.allclose(even[:-1], uneven[:-1], rtol=0, atol=1e-12)


def test_delay_shifts_and_holds_the_first_command():
    t = np.arange(0.0, 1.0, 0.01)
    u = np.stack([np.sin(3 * t), t], axis=1)
    y = Actuator((0.0,), (0.1,)).apply(t, u)
    assert np.allclose(y[10:], u[:-10], atol=1e-12)
    assert np.allclose(y[:10], u[0], atol=1e-12)


def test_per_input_values_and_trajectories_are_independent():
    t = np.tile(np.arange(0.0, 1.0, 0.02), 2)
    traj = np.repeat([0, 1], 50)
    u = np.random.default_rng(1).normal(size=(100, 2))
    act = Actuator.parse("0.1,0:0,0.04", 2)
    y = act.apply_trajectories(t, u, traj)
    for k in (0, 1):
        rows = traj == k
        assert np.allclose(y[rows, 0], lag(t[rows], u[rows, 0], 0.1))
        assert np.allclose(y[rows, 1], np.interp(t[rows] - 0.04, t[rows], u[rows, 1]))


@pytest.mark.parametrize("text, message", [
    ("0.2", "expected TAU:DELAY"),
    ("a:0.1", "time constant must be a number"),
    ("-0.1:0", "between 0 and 60"),
    ("0.1,0.2,0.3:0", "has 3 values; the data have 2 inputs"),
    ("0.1:5e3", "between 0 and 60"),
])  # fmt: skip
def test_bad_text_is_refused_in_one_line(text, message):
    with pytest.raises(UserError, match=message) as err:
        Actuator.parse(text, 2)
    assert "\n" not in str(err.value)


def test_text_round_trip():
    for text in ("none", "0.2:0.15", "0.1,0.2:0,0.05"):
        assert Actuator.parse(text).text() == text
    act = Actuator.from_dict({"time_constant": [0.1, 0.2], "delay": 0.05})
    assert Actuator.from_dict(act.to_dict()) == act
    with pytest.raises(UserError, match="unknown key"):
        Actuator.from_dict({"tau": 0.1})


# ---------------------------------------------------------------------------------- identify


def _record(actuator: Actuator | None, *, seed=0, trajectories=5, duration=12.0, dt=0.02):
    rng = np.random.default_rng(seed)
    K = np.diag([4.0, 9.0])
    D = np.diag([0.8, 1.2])
    B = np.array([[1.0, 0.3], [-0.2, 1.0]])
    rows = {k: [] for k in ("t", "q", "qd", "qdd", "u", "traj")}
    for k in range(trajectories):
        t = np.arange(0.0, duration, dt)
        f = rng.uniform(0.1, 1.0, (2, 4))
        ph = rng.uniform(0, 2 * np.pi, (2, 4))
        u = np.stack([np.sin(2 * np.pi * f[j] * t[:, None] + ph[j]).sum(1) for j in range(2)], 1)
        y = u if actuator is None else actuator.apply(t, u)
        q, qd = np.zeros(2), np.zeros(2)
        Q, QD, QDD = [], [], []
        sub = 20
        h = dt / sub
        for i in range(len(t)):  # RK4 on a finer grid, the actuator output linear between samples
            acc = lambda q, qd, yy: B @ yy - K @ q - D @ qd
            Q.append(q.copy()), QD.append(qd.copy()), QDD.append(acc(q, qd, y[i]))
            if i + 1 == len(t):
                break
            for s in range(sub):
                y0 = y[i] + (y[i + 1] - y[i]) * s / sub
                ym = y[i] + (y[i + 1] - y[i]) * (s + 0.5) / sub
                y1 = y[i] + (y[i + 1] - y[i]) * (s + 1) / sub
                k1q, k1v = qd, acc(q, qd, y0)
                k2q, k2v = qd + h / 2 * k1v, acc(q + h / 2 * k1q, qd + h / 2 * k1v, ym)
                k3q, k3v = qd + h / 2 * k2v, acc(q + h / 2 * k2q, qd + h / 2 * k2v, ym)
                k4q, k4v = qd + h * k3v, acc(q + h * k3q, qd + h * k3v, y1)
                q = q + h / 6 * (k1q + 2 * k2q + 2 * k3q + k4q)
                qd = qd + h / 6 * (k1v + 2 * k2v + 2 * k3v + k4v)
        for key, val in (("t", t), ("q", Q), ("qd", QD), ("qdd", QDD), ("u", u),
                         ("traj", np.full(len(t), k))):
            rows[key].append(np.asarray(val))
    return {k: np.concatenate(v) for k, v in rows.items()}


def _save(path, arrays, meta):
    np.savez(path, **arrays, meta=np.array(json.dumps(meta)))
    return load_dataset(path)


def test_identify_finds_a_lag_and_dead_time(tmp_path):
    truth = Actuator((0.2,), (0.1,))
    data = _save(tmp_path / "lagged.npz", _record(truth), {"source": "import", "rate": 50.0})
    act, report = identify_actuator(data, [0, 1, 2, 3])
    tau, delay = act.per_input(2)
    assert act.source == "identified" and "better" in report
    assert np.all(np.abs(delay - 0.1) <= 0.02 + 1e-9), act
    assert np.all(np.abs(tau - 0.2) <= 0.06), act


def test_identify_keeps_none_where_the_inputs_act_at_once(tmp_path):
    data = _save(tmp_path / "direct.npz", _record(None, trajectories=4), {"source": "import"})
    act, report = identify_actuator(data, [0, 1, 2])
    assert act.is_identity and "none kept" in report


def test_auto_reads_the_file_then_identifies_imports_only(tmp_path):
    arrays = _record(None, trajectories=3, duration=5.0)
    simulated = _save(tmp_path / "sim.npz", arrays, {"source": "simulate"})
    assert resolve_actuator("auto", simulated, [0, 1])[0].is_identity
    declared = _save(tmp_path / "decl.npz", arrays,
                     {"source": "import", "actuator": {"time_constant": [0.3, 0.3],
                                                       "delay": [0.0, 0.1]}})
    act, note = resolve_actuator("auto", declared, [0, 1])
    assert act.per_input(2)[1].tolist() == [0.0, 0.1] and "metadata" in note
    assert resolve_actuator("0.1:0", simulated, [0])[0].text() == "0.1:0"


# -------------------------------------------------------------------------- train and predict


@pytest.fixture(scope="module")
def msd(tmp_path_factory):
    return make_dataset(tmp_path_factory.mktemp("act") / "msd.npz", trajectories=5, duration=3.0)


def test_a_run_records_its_actuator_and_predict_applies_it(msd, tmp_path):
    cfg = dataclasses.replace(blackbox_train_config(epochs=1), actuator="0.1:0.04")
    train(msd, cfg, tmp_path / "run")
    info = json.loads((tmp_path / "run" / "config.json").read_text())
    assert info["train"]["actuator"] == "0.1:0.04"
    assert info["actuator"]["time_constant"] == [0.1] and info["actuator"]["setting"] == "0.1:0.04"
    res = predict(tmp_path / "run", msd, horizon=1.0, trajectories="all")
    from softpinn.learn import load_run

    run = load_run(tmp_path / "run")
    data = load_dataset(msd)
    direct = evaluate(run.model, with_actuator(data, Actuator((0.1,), (0.04,))),
                      data.trajectory_ids.tolist(), horizon=1.0)
    plain = evaluate(run.model, data, data.trajectory_ids.tolist(), horizon=1.0)
    assert res.rollout_errors == pytest.approx(direct.rollout_errors, rel=1e-12)
    assert not math.isclose(res.rollout_errors[0], plain.rollout_errors[0], rel_tol=1e-6)


def test_train_config_refuses_a_bad_actuator():
    with pytest.raises(UserError, match="actuator"):
        dataclasses.replace(blackbox_train_config(epochs=1), actuator="fast")
    assert TrainConfig.from_dict({**blackbox_train_config(epochs=1).to_dict()}).actuator == "auto"


def test_cli_bad_actuator_is_one_line_exit_2(msd, tmp_path, capsys):
    code = main(["train", str(msd), "--model", "blackbox", "--epochs", "1", "--actuator",
                 "0.1:x", "--out", str(tmp_path / "r"), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "delay must be a number" in err[0]
    assert not (tmp_path / "r").exists()


def test_cli_linear_run_applies_the_actuator(msd, tmp_path, capsys):
    assert main(["train", str(msd), "--model", "linear", "--actuator", "0.2:0.1",
                 "--out", str(tmp_path / "lin")]) == 0
    out = capsys.readouterr().out
    assert "actuator: lag 0.2 s after a dead time 0.1 s" in out
    info = json.loads((tmp_path / "lin" / "config.json").read_text())
    assert info["actuator"]["text"] == "0.2:0.1"


# ------------------------------------------------------------- settings chosen for recordings


def test_recordings_get_a_budget_and_say_so(tmp_path, capsys):
    arrays = _record(None, trajectories=4, duration=4.0)
    path = tmp_path / "rec.npz"
    _save(path, arrays, {"source": "import", "rate": 50.0, "splits": {"train": [0, 1, 2],
                                                                     "test": [3]}})
    code = main(["train", str(path), "--model", "blackbox", "--hidden", "8", "1",
                 "--actuator", "none", "--validation", "0", "--out", str(tmp_path / "r"),
                 "--quiet"])
    err = capsys.readouterr().err
    assert code == 0 and "settings for recorded data" in err
    info = json.loads((tmp_path / "r" / "config.json").read_text())["train"]
    # 3 trajectories of 200 samples: 597 pairs, batch 64, 9 steps an epoch: 1000 epochs cap
    assert info["epochs"] == 1000 and "epochs 1000" in err
    assert info["lr"] == 2e-3 and info["input_hold"] == "linear"
    # held-out rollouts pick the epoch: 5 s at 50 Hz, capped by the 4 s test trajectory
    assert (info["test_with"], info["test_steps"]) == ("rollout", 199)


def test_recording_defaults_leave_what_the_user_gave(tmp_path):
    from softpinn.learn import recording_defaults

    data = _save(tmp_path / "r.npz", _record(None, trajectories=2, duration=2.0),
                 {"source": "import"})
    chosen, why = recording_defaults(data, 6400, "lagrangian", {"lr"})
    assert chosen == {"epochs": 100, "input_hold": "linear", "test_with": "rollout"}
    assert "10,000" in why and "held-out rollouts of up to 5 s" in why
    kept, _ = recording_defaults(data, 6400, "lagrangian", {"test_with"})
    assert "test_with" not in kept
    # --test-steps alone on an import: its rollouts pick, of the length given
    steps, why = recording_defaults(data, 6400, "lagrangian", {"test_steps"})
    assert steps["test_with"] == "rollout" and "rollouts of --test-steps steps" in why
    sim = _save(tmp_path / "s.npz", _record(None, trajectories=2, duration=2.0),
                {"source": "simulate"})
    assert recording_defaults(sim, 6400, "lagrangian", set()) == ({}, None)


def test_inputs_far_from_unit_scale_are_warned(tmp_path):
    from softpinn.learn._advice import scale_warnings

    arrays = _record(None, trajectories=2, duration=2.0)
    ok = _save(tmp_path / "ok.npz", arrays, {})
    assert scale_warnings(ok) == []
    pascal = _save(tmp_path / "pa.npz", {**arrays, "u": arrays["u"] * 1e5}, {})
    (message,) = scale_warnings(pascal)
    assert message.startswith("the data's inputs u have rms") and "rescale" in message


def test_auto_goes_on_without_one_where_the_recordings_are_too_short(tmp_path):
    short = _save(tmp_path / "short.npz", _record(None, trajectories=3, duration=1.5),
                  {"source": "import"})
    with pytest.raises(UserError, match="shorter than 2 s"):
        resolve_actuator("identify", short, [0, 1])
    act, note = resolve_actuator("auto", short, [0, 1])
    assert act.is_identity and "goes on without one" in note
