"""The simulated IMU of a spec's [sensor] table (symbolic/spec/_sensor.py): the table is
validated when
the spec loads, the recordings sample at the sensor's rate, their noise and bias have the stated
statistics, a seed reproduces them, and ``softpinn import`` reads them back."""

from __future__ import annotations

import numpy as np
import pytest

from softpinn.errors import UserError
from softpinn.symbolic.recorded._import import import_recordings
from softpinn.symbolic.spec import _orientation as ori
from softpinn.symbolic.spec._sensor import (
    SensorConfig,
    SensorError,
    parse_sensor,
    record,
    sensor_config,
    write_csv,
)
from softpinn.symbolic.spec._spec import SpecError, load_spec, spec_from_toml

ARM = """
name = "arm"
kind = "spatial-pcc"
actuation = "tendon"
[[segment]]
length = 0.2
mass = 0.1
radius = 0.02
actuator_radius = 1.0
stiffness = [1.0, 1.0, 50.0]
damping = [0.1, 0.1, 0.1]
"""


def trajectories(count=3, rate=100.0, duration=4.0):
    """Smooth analytic bending (dx, dy) with exact velocities, dL = 0.1 sin t, four inputs."""
    t1 = np.arange(int(round(duration * rate)) + 1) / rate
    t, q, qd, u, traj = [], [], [], [], []
    for k in range(count):
        a, w = 0.3 + 0.1 * k, 1.0 + 0.5 * k
        q.append(np.stack([a * np.sin(w * t1), 0.2 * np.cos(2 * t1), 0.1 * np.sin(t1)], 1))
        qd.append(np.stack([a * w * np.cos(w * t1), -0.4 * np.sin(2 * t1), 0.1 * np.cos(t1)], 1))
        u.append(np.stack([np.sin(t1 + j) for j in range(4)], 1))
        t.append(t1)
        traj.append(np.full(len(t1), k))
    return tuple(np.concatenate(x) for x in (t, q, qd, u, traj))


def sensor(**kw):
    return SensorConfig(**{"rate_hz": 20.0, **kw})


def test_the_experiment_preset_carries_an_imu():
    spec = load_spec("experiment")
    cfg = sensor_config(spec)
    assert cfg.kind == "imu" and cfg.rate_hz == 5.0 and cfg.output == "rpy"
    assert cfg.noise_std == (0.01, 0.01, 0.01) and len(cfg.bias_walk_std) == 3
    assert spec.to_dict()["sensor"]["rate_hz"] == 5.0
    assert "sensor" not in spec.physics_dict()  # the sensor is not physics
    assert spec.n == 3 and spec.m == 4 and spec.actuation == "tendon"


@pytest.mark.parametrize(
    ("table", "field", "message"),
    [
        ('kind = "camera"\nrate_hz = 5.0', "sensor.kind", "expected one of imu"),
        ("rate_hz = 5.0", "sensor.kind", "missing"),
        ('kind = "imu"', "sensor.rate_hz", "missing"),
        ('kind = "imu"\nrate_hz = -1.0', "sensor.rate_hz", "must be positive"),
        ('kind = "imu"\nrate_hz = 5.0\nnoise_std = [0.1, 0.2]', "sensor.noise_std",
         "one number or three"),
        ('kind = "imu"\nrate_hz = 5.0\nbias_walk_std = -0.1', "sensor.bias_walk_std",
         "must not be negative"),
        ('kind = "imu"\nrate_hz = 5.0\noutput = "euler"', "sensor.output", "expected one of"),
        ('kind = "imu"\nrate_hz = 5.0\nseed = -3', "sensor.seed", "integer from 0"),
        ('kind = "imu"\nrate_hz = 5.0\nnoise = 0.1', "sensor.noise", "unknown key"),
    ],
)
def test_a_bad_sensor_table_names_the_field(table, field, message):
    with pytest.raises(SpecError, match=rf"arm\.toml: field '{field}': .*{message}"):
        spec_from_toml(ARM + "[sensor]\n" + table + "\n", source="arm.toml")


def test_an_imu_needs_a_one_segment_spatial_arm():
    two = ARM + ARM[ARM.index("[[segment]]"):]
    with pytest.raises(SpecError, match=r"field 'sensor.kind': .*one-segment spatial-pcc arm "
                                        r"only; this model is spatial-pcc with 2 segments"):
        spec_from_toml(two + '[sensor]\nkind = "imu"\nrate_hz = 5.0\n', source="arm.toml")
    with pytest.raises(UserError, match="no \\[sensor\\] table"):
        sensor_config(spec_from_toml(ARM, source="arm.toml"))
    assert parse_sensor({}, kind="spatial-pcc", segments=1) is None


def test_noise_free_recordings_are_the_forward_kinematics_at_the_sensor_rate():
    spec = spec_from_toml(ARM, source="arm.toml")
    t, q, qd, u, traj = trajectories()
    rec = record(spec, sensor(rate_hz=20.0), t, q, qd, u, traj)
    for k in range(3):
        tk = rec.t[rec.traj == k]
        np.testing.assert_allclose(np.diff(tk), 0.05, atol=1e-12)
        assert tk[0] == 0.0 and len(tk) == 81  # 4 s at 20 Hz, both ends
    # on the simulated grid: exactly the samples
    rows = np.isin(np.round(t * 100), np.round(rec.t * 100))
    np.testing.assert_array_equal(rec.q_true, q[rows])
    np.testing.assert_array_equal(rec.u, u[rows])
    R = ori.rotation_of_bending(q[rows][:, :2], "delta", 1.0)
    np.testing.assert_allclose(ori.rpy_to_matrix(rec.orientation), R, atol=1e-12)
    np.testing.assert_array_equal(rec.bias, 0.0)
    # between simulated samples: cubic Hermite, close to the analytic curve
    off = record(spec, sensor(rate_hz=30.0), t, q, qd, u, traj)
    exact = 0.3 * np.sin(off.t[off.traj == 0])
    np.testing.assert_allclose(off.q_true[off.traj == 0, 0], exact, atol=1e-7)


def test_white_noise_and_bias_have_the_stated_statistics():
    spec = spec_from_toml(ARM, source="arm.toml")
    t, q, qd, u, traj = trajectories(count=40, duration=20.0)
    noisy = record(spec, sensor(noise_std=(0.01, 0.02, 0.03)), t, q, qd, u, traj)
    err = noisy.angles - noisy.angles_true
    np.testing.assert_allclose(err.std(axis=0), [0.01, 0.02, 0.03], rtol=0.05)
    np.testing.assert_allclose(err.mean(axis=0), 0.0, atol=1e-3)
    lag1 = np.mean(err[1:, 0] * err[:-1, 0]) / err[:, 0].var()
    assert abs(lag1) < 0.05  # white
    drift = record(spec, sensor(bias_walk_std=(0.0, 0.01, 0.05)), t, q, qd, u, traj)
    np.testing.assert_allclose(drift.angles - drift.angles_true, drift.bias, atol=1e-12)
    first = drift.t == 0.0
    np.testing.assert_array_equal(drift.bias[first], 0.0)  # zero when each recording starts
    last = np.flatnonzero(np.r_[drift.traj[1:] != drift.traj[:-1], True])
    # a random walk: variance sigma^2 T at the end (20 s), over the 40 trajectories
    np.testing.assert_allclose(drift.bias[last, 0], 0.0)
    var = np.mean(drift.bias[last, 1:] ** 2, axis=0)
    np.testing.assert_allclose(var / (np.array([0.01, 0.05]) ** 2 * 20.0), 1.0, rtol=0.5)
    steps = np.diff(drift.bias[:, 2])[np.diff(drift.traj) == 0]
    np.testing.assert_allclose(steps.std(), 0.05 * np.sqrt(0.05), rtol=0.05)


def test_a_seed_reproduces_the_recordings():
    spec = spec_from_toml(ARM, source="arm.toml")
    t, q, qd, u, traj = trajectories()
    cfg = sensor(noise_std=(0.01,) * 3, bias_walk_std=(0.01,) * 3, seed=7)
    a = record(spec, cfg, t, q, qd, u, traj)
    b = record(spec, cfg, t, q, qd, u, traj)
    np.testing.assert_array_equal(a.orientation, b.orientation)
    other = record(spec, sensor(noise_std=(0.01,) * 3, seed=8), t, q, qd, u, traj)
    assert not np.allclose(other.orientation, a.orientation)
    # trajectory 2 records the same whatever the other trajectories
    keep = traj == 2
    alone = record(spec, cfg, t[keep], q[keep], qd[keep], u[keep], traj[keep])
    np.testing.assert_array_equal(alone.orientation, a.orientation[a.traj == 2])


def test_the_recordings_import_back(tmp_path):
    spec = spec_from_toml(ARM, source="arm.toml")
    t, q, qd, u, traj = trajectories()
    for output in ("rpy", "quaternion"):
        rec = record(spec, sensor(output=output), t, q, qd, u, traj)
        assert rec.columns == (("roll", "pitch", "yaw") if output == "rpy"
                               else ("qw", "qx", "qy", "qz"))
        path = write_csv(tmp_path / f"imu-{output}.csv", rec, comment="simulated\nIMU")
        assert path.read_text().startswith("# simulated\n# IMU\ntraj,t,u0,u1,u2,u3,")
        res = import_recordings([path], spec, orientation_kind=output, test_trajectories=1)
        np.testing.assert_allclose(res.data.q[:, :2], rec.q_true[:, :2], atol=1e-9)
        np.testing.assert_array_equal(res.data.q[:, 2], 0.0)  # the stretch is not observed
        np.testing.assert_allclose(res.data.u, rec.u, atol=1e-15)
        assert res.data.meta["splits"]["test"] == [2]


def test_a_sensor_faster_than_the_simulation_is_refused():
    spec = spec_from_toml(ARM, source="arm.toml")
    t, q, qd, u, traj = trajectories(rate=10.0)
    with pytest.raises(SensorError, match="20 Hz is faster than the simulated trajectories"):
        record(spec, sensor(rate_hz=20.0), t, q, qd, u, traj)
