"""The Cosserat-rod stand-in (symbolic/standin/_cosserat.py, issue 43 item 4): the rod hangs
still without input, a tip moment bends it to the Euler-Bernoulli angle M L / (E I), the dead
time holds the tip still until the command arrives and the lag then follows exp(-t / tau), and
its recordings import through the documented path (``softpinn import --model experiment
--orientation quaternion``) with the bending sign of the experiment preset's tendons."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

pytest.importorskip("elastica")  # the optional extra "cosserat" (installed by the test extra)

from softpinn.bridge.cli import main  # noqa: E402
from softpinn.errors import UserError  # noqa: E402
from softpinn.symbolic import read_dataset  # noqa: E402
from softpinn.symbolic.standin import _cosserat as cs  # noqa: E402

RATE = 50.0


def steady(traj, seconds=0.5):
    return slice(-int(seconds * RATE), None)


def read_csv(path) -> dict[str, np.ndarray]:
    lines = [x for x in path.read_text().splitlines() if x and not x.startswith("#")]
    table = np.array([[float(v) for v in x.split(",")] for x in lines[1:]])
    return dict(zip(lines[0].split(","), table.T, strict=True))


@pytest.mark.parametrize("arm", [cs.CosseratArm(), cs.CosseratArm.upright()],
                         ids=["hanging", "upright"])
def test_the_arm_stays_straight_and_still_without_input(arm):
    traj = cs.simulate(arm, None, 2.0, RATE)
    assert np.max(traj.theta) < 1e-9
    np.testing.assert_allclose(traj.actuator, arm.amplitude)
    # gravity along the rod only stretches it (EA = 2.1 kN: 0.3 mm hanging)
    assert np.max(np.abs(traj.tip[:, :2])) < 1e-9
    assert np.max(np.abs(traj.tip[:, 2] - arm.length)) < 1e-3
    np.testing.assert_allclose(traj.quaternion, [[1, 0, 0, 0]] * len(traj.t), atol=1e-9)


@pytest.mark.parametrize("theta", [0.1, 1.0])
def test_a_tip_moment_bends_the_rod_to_the_euler_bernoulli_angle(theta):
    """Without gravity or tip mass a pure moment M bends the rod into an arc of tip angle
    M L / (E I) (exact also at large angles: the elastica under a pure moment is a circle)."""
    arm = cs.CosseratArm(gravity=0.0, tip_mass=0.0, tau=0.0, delay=0.0, damping=20.0,
                         rotational_damping=20.0, settle=0.0)
    M = theta * arm.bending_stiffness / arm.length
    # input 1 bends toward +y (90 degrees); input 3 pulls against it
    traj = cs.simulate(arm, lambda t: np.tile([0.0, 2 * M, 0.0, M], (len(t), 1)), 3.0, RATE)
    end = traj.bending()[steady(traj)]
    assert np.ptp(end[:, 1]) < 1e-3 * theta  # settled
    assert abs(end[-1, 1] / theta - 1) < 0.01
    assert abs(end[-1, 0]) < 1e-6 * theta
    # a circle: element i of n turned by i theta / n, so the tip sits at dl sum_i (0, sin, cos)
    # (the continuous arc's L (0, 1 - cos theta, sin theta) / theta within 1 / n)
    n, dl = arm.n_elements, arm.length / arm.n_elements
    turn = np.arange(1, n + 1) * theta / n
    arc = dl * np.array([0.0, np.sin(turn).sum(), np.cos(turn).sum()])
    np.testing.assert_allclose(traj.tip[-1], arc, atol=2e-3 * arm.length * theta)


def test_the_dead_time_holds_the_tip_still_and_the_lag_follows():
    arm = cs.CosseratArm(tau=0.2, delay=0.15)
    M, t_step = 0.2, 1.0
    traj = cs.simulate(arm, lambda t: np.outer(t >= t_step, [M, 0, 0, 0]), 2.0, RATE)
    before = traj.t < t_step + arm.delay[0] - 1e-9
    assert np.max(traj.theta[before]) < 1e-12
    assert np.max(np.abs(traj.actuator[before])) == 0
    after = ~before
    lag = M * (1 - np.exp(-(traj.t[after] - t_step - arm.delay[0]) / arm.tau[0]))
    # on the integration grid the step is a ramp over one step (2e-4 s): 1e-4 s late
    np.testing.assert_allclose(traj.actuator[after, 0], lag, atol=arm.time_step / arm.tau[0] * M)
    # it moves once the moment arrives, toward +x (input 0's direction)
    later = traj.t > t_step + arm.delay[0] + 0.1
    assert np.min(traj.theta[later]) > 0.01
    assert np.all(traj.bending()[later, 0] > 0)


def test_recordings_import_through_the_documented_path(tmp_path, capsys):
    arm = cs.CosseratArm()
    quick = cs.RecordSettings(n_trajectories=2, duration_s=3.0, rate_hz=RATE, seed=5)
    paths = cs.record_settings(arm, quick, tmp_path / "rec")
    assert [p.name for p in paths] == ["cosserat_000.csv", "cosserat_001.csv"]
    settings = json.loads((tmp_path / "rec" / cs.SETTINGS_FILE).read_text())
    assert settings["seed"] == 5 and settings["config"]["tau"] == [0.2] * 4
    assert settings["files"] == [p.name for p in paths]
    out = tmp_path / "data.npz"
    argv = ["import", *map(str, paths), *cs.IMPORT_ARGS, "--test-trajectories", "1",
            "--out", str(out)]
    assert main(argv) == 0
    assert "wrote" in capsys.readouterr().out
    data = read_dataset(out)
    meta = data.meta
    assert meta["trajectories"] == 2 and meta["rate"] == pytest.approx(RATE)
    assert meta["import"]["unobserved"] == ["dL1"]
    assert meta["import"]["max_twist_rad"] < 0.05  # follower moments twist it a little
    assert set(meta["import"]["files"][0]["ignored_columns"]) == {
        *(f"command{j}" for j in range(4)), *(f"actuator{j}" for j in range(4))}
    # the same q as the simulated arm's (the files keep 12 digits)
    seeds = [[5, k, 0] for k in range(2)]
    trajs = [cs.simulate(arm, cs.excitation(arm, 3.0, s), 3.0, RATE) for s in seeds]
    truth = np.concatenate([t.bending() for t in trajs])
    np.testing.assert_allclose(data.q[:, :2], truth, atol=1e-9)
    np.testing.assert_allclose(data.u, np.concatenate([t.command for t in trajs]), atol=1e-9)
    assert np.max(np.abs(truth)) > 0.2  # tens of degrees
    # the preset's tendon convention: input 0 bends toward +x, input 1 toward +y
    act = np.concatenate([t.actuator for t in trajs])
    for axis, (pull, push) in enumerate([(0, 2), (1, 3)]):
        net = act[:, pull] - act[:, push]
        assert np.corrcoef(net, data.q[:, axis])[0, 1] > 0.5


def test_noise_changes_the_sensor_not_the_motion_and_files_are_not_replaced(tmp_path):
    arm = cs.CosseratArm()
    clean = cs.record(arm, 1, 1.0, RATE, 0.0, 3, tmp_path / "clean")
    noisy = cs.record(arm, 1, 1.0, RATE, 0.01, 3, tmp_path / "noisy", inputs="actuator")
    a, b = (read_csv(p[0]) for p in (clean, noisy))
    for j in range(4):
        np.testing.assert_array_equal(a[f"command{j}"], b[f"command{j}"])
        np.testing.assert_array_equal(b[f"u{j}"], b[f"actuator{j}"])
    qa = np.stack([a[c] for c in ("qw", "qx", "qy", "qz")], 1)
    qb = np.stack([b[c] for c in ("qw", "qx", "qy", "qz")], 1)
    angle = 2 * np.arccos(np.clip(np.abs(np.sum(qa * qb, 1)), 0, 1))  # rotation between them
    assert 0.005 < np.sqrt(np.mean(angle**2)) / math.sqrt(3) < 0.02
    with pytest.raises(UserError, match="exists"):
        cs.record(arm, 1, 1.0, RATE, 0.0, 3, tmp_path / "clean")


def test_bad_settings_are_one_line_errors():
    with pytest.raises(UserError, match="^tau: "):
        cs.CosseratArm(tau=-1.0)
    with pytest.raises(UserError, match="^hanging: an upright arm .* buckles"):
        cs.CosseratArm(hanging=False, tip_mass=1.0)
    with pytest.raises(UserError, match="^signal: "):
        cs.CosseratArm(signal="chirp")
    assert cs.CosseratArm(delay=(0.1, 0.2, 0.3, 0.4)).delay == (0.1, 0.2, 0.3, 0.4)
