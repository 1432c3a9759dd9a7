"""softpinn import (symbolic/recorded/_csv.py, symbolic/recorded/_import.py,
bridge/cli/_import_run.py): a simulated
data set written as CSV (configurations; tip orientation as quaternions and as roll-pitch-yaw)
and imported back gives the same q, q̇ to the smoother's accuracy; every bad file is refused in
one line naming the file, line and column, with exit status 2."""

from __future__ import annotations

import json

import numpy as np
import pytest

from softpinn.bridge.cli import main
from softpinn.learn._data import load_dataset
from softpinn.symbolic.recorded._csv import RecordingError
from softpinn.symbolic.recorded._import import import_recordings
from softpinn.symbolic.simulation._datafile import read_dataset
from softpinn.symbolic.simulation._datasets import make_dataset
from softpinn.symbolic.spec import _orientation as ori


@pytest.fixture(scope="module")
def sim():
    """Task 4 (one spatial segment, delta, m = 3): 2 trajectories of 1 s at 1 kHz, recorded
    after 0.5 s of settling (past the release transient)."""
    return make_dataset("task4", trajectories=2, duration=1.0, rate=1000.0, settle=0.5,
                        compile=False)


def write_csv(path, columns: dict[str, np.ndarray]):
    names = list(columns)
    table = np.stack([np.asarray(columns[c], dtype=float) for c in names], 1)
    np.savetxt(path, table, delimiter=",", header=",".join(names), comments="", fmt="%.17g")
    return path


def columns(d, *, state="q", traj=True, rows=slice(None)):
    out = {}
    if traj:
        out["traj"] = d.traj[rows]
    out["t"] = d.t[rows]
    for j in range(d.u.shape[1]):
        out[f"u{j}"] = d.u[rows, j]
    if state == "q":
        out.update({f"q{j}": d.q[rows, j] for j in range(d.q.shape[1])})
    else:
        R = ori.rotation_of_bending(d.q[rows, :2], "delta", 1.0)
        if state == "quaternion":
            out.update(zip(("qw", "qx", "qy", "qz"), ori.matrix_to_quaternion(R).T, strict=True))
        else:
            out.update(zip(("roll", "pitch", "yaw"), ori.matrix_to_rpy(R).T, strict=True))
    return out


def rel(a, b, rows=slice(None)):
    """max |a - b| over the rows, per column, relative to max |b| of that column."""
    return np.max(np.abs(a[rows] - b[rows]) / np.maximum(np.abs(b).max(0), 1e-300))


@pytest.mark.parametrize(
    "smooth,tol_q,tol_qd",
    [("none", 1e-15, 1e-4), ("savgol:21:3", 1e-6, 1e-4), ("polyfit:3:50", 1e-4, 2e-3)],
)
def test_configurations_round_trip(sim, tmp_path, smooth, tol_q, tol_qd):
    path = write_csv(tmp_path / "rec.csv", columns(sim))
    data = import_recordings([path], "task4", smooth=smooth).data
    np.testing.assert_array_equal(data.t, sim.t)
    np.testing.assert_array_equal(data.traj, sim.traj)
    np.testing.assert_array_equal(data.u, sim.u)
    assert rel(data.q, sim.q) <= tol_q
    assert rel(data.qd, sim.qd) <= tol_qd
    assert rel(data.p, sim.p) <= tol_qd  # M(q) q̇ with task 4's mass matrix
    assert rel(data.qdd, sim.qdd, slice(5, -5)) <= 50 * tol_qd
    meta = data.meta
    assert meta["import"]["smooth"]["text"] == smooth and meta["rate"] == pytest.approx(1000.0)
    assert meta["coordinates"] == ["dx1", "dy1", "dL1"] and meta["spec"]["name"] == "task4"


def test_movmean_is_exact_inside_for_what_it_averages(sim, tmp_path):
    path = write_csv(tmp_path / "rec.csv", columns(sim))
    data = import_recordings([path], "task4", smooth="movmean:5").data
    inside = np.r_[5:995, 1005:1995]  # the first and last W/2 samples average fewer samples
    assert rel(data.q, sim.q, inside) <= 1e-4
    assert rel(data.qd, sim.qd, inside) <= 1e-3


def test_one_file_per_trajectory_equals_a_traj_column(sim, tmp_path):
    a = write_csv(tmp_path / "a.csv", columns(sim, traj=False, rows=sim.traj == 0))
    b = write_csv(tmp_path / "b.csv", columns(sim, traj=False, rows=sim.traj == 1))
    both = write_csv(tmp_path / "both.csv", columns(sim))
    split = import_recordings([a, b], "task4", smooth="savgol:11:3").data
    joint = import_recordings([both], "task4", smooth="savgol:11:3").data
    for key in ("t", "q", "qd", "qdd", "p", "u", "traj"):
        np.testing.assert_array_equal(getattr(split, key), getattr(joint, key))
    sources = split.meta["import"]["trajectories"]
    assert [s["file"] for s in sources] == [str(a), str(b)] and sources[0]["lines"] == [2, 1001]


@pytest.mark.parametrize("kind", ["quaternion", "rpy"])
def test_orientation_round_trip(sim, tmp_path, kind):
    path = write_csv(tmp_path / "imu.csv", columns(sim, state=kind))
    result = import_recordings([path], "task4", orientation_kind=kind, smooth="savgol:21:3")
    data = result.data
    assert rel(data.q[:, :2], sim.q[:, :2]) <= 1e-6
    assert rel(data.qd[:, :2], sim.qd[:, :2]) <= 1e-4
    np.testing.assert_array_equal(data.q[:, 2], 0.0)  # the stretch is not observable
    np.testing.assert_array_equal(data.qd[:, 2], 0.0)
    record = data.meta["import"]
    assert record["unobserved"] == ["dL1"] and record["orientation"] == kind
    assert record["max_twist_rad"] < 1e-9
    assert any("not observable" in note for note in result.notes)


def test_observed_only_leaves_out_the_stretch(sim, tmp_path, capsys):
    path = write_csv(tmp_path / "imu.csv", columns(sim, state="quaternion"))
    full = import_recordings([path], "task4", orientation_kind="quaternion",
                             smooth="savgol:21:3").data
    result = import_recordings([path], "task4", orientation_kind="quaternion",
                               smooth="savgol:21:3", observed_only=True)
    data = result.data
    assert data.q.shape[1] == data.qd.shape[1] == data.p.shape[1] == 2
    np.testing.assert_array_equal(data.q, full.q[:, :2])
    np.testing.assert_array_equal(data.p, full.p[:, :2])  # M_bb q̇_b: the stretch rate is 0
    assert data.meta["n"] == 2 and data.meta["coordinates"] == ["dx1", "dy1"]
    assert data.meta["import"]["dropped"] == ["dL1"]
    assert any("--observed-only leaves out the stretch dL1" in note for note in result.notes)
    out = tmp_path / "obs.npz"
    assert main(["import", str(path), "--model", "task4", "--orientation", "quaternion",
                 "--observed-only", "--out", str(out)]) == 0
    assert load_dataset(out).n == 2


def test_resampling_to_a_divisor_of_the_rate_gives_the_recorded_samples(sim, tmp_path):
    path = write_csv(tmp_path / "rec.csv", columns(sim))
    data = import_recordings([path], "task4", rate=250.0, test_trajectories=1).data
    rows = np.r_[0:1000:4, 1000:2000:4]
    np.testing.assert_allclose(data.t, sim.t[rows], atol=1e-12)
    np.testing.assert_allclose(data.q, sim.q[rows], atol=1e-12)
    assert rel(data.qd, sim.qd[rows]) <= 1e-4
    assert data.meta["rate"] == 250.0 and data.meta["samples_per_trajectory"] == 250
    assert data.meta["splits"] == {"train": [0], "test": [1], "blackbox_train": [0]}


def test_non_uniform_times_are_kept_or_resampled(sim, tmp_path):
    rng = np.random.default_rng(0)
    keep = np.sort(rng.choice(1000, 400, replace=False))
    rows = np.r_[keep, 1000 + keep]
    path = write_csv(tmp_path / "jitter.csv", columns(sim, rows=rows))
    data = import_recordings([path], "task4", smooth="savgol:9:3").data
    assert data.meta["rate"] is None and len(data) == 800
    assert rel(data.qd, sim.qd[rows], np.r_[5:395, 405:795]) <= 1e-3
    even = import_recordings([path], "task4", smooth="savgol:9:3", rate=100.0).data
    assert even.meta["rate"] == 100.0
    np.testing.assert_allclose(np.diff(even.t[even.traj == 0]), 0.01, atol=1e-12)


def test_cli_writes_a_dataset_the_learning_side_loads(sim, tmp_path, capsys):
    path = write_csv(tmp_path / "rec.csv", columns(sim, state="quaternion"))
    out = tmp_path / "data.npz"
    argv = ["import", str(path), "--model", "task4", "--out", str(out), "--orientation",
            "quaternion", "--smooth", "movmean:20", "--rate", "100", "--test-trajectories", "1"]
    assert main(argv) == 0
    stdout, stderr = capsys.readouterr()
    assert f"task4: wrote {out} (2 trajectories, 200 samples, 100 Hz" in stdout
    assert "--test-trajectories 1" in stdout
    assert stderr.startswith("softpinn: note: orientation determines the bending (dx1, dy1) only")
    loaded = load_dataset(out, n=3, m=3)
    assert len(loaded.t) == 200
    meta = read_dataset(out).meta
    assert meta["import"]["smooth"] == {
        "method": "movmean", "text": "movmean:20", "window_samples": 20, "differences": 2,
        "derivatives": "central differences (numpy.gradient with t)"}
    assert meta["import"]["resample"]["rate"] == 100.0
    assert meta["import"]["files"][0]["sha256"]
    # never overwrite without --force
    assert main(argv) == 2
    assert capsys.readouterr().err == (
        f"softpinn: error: --out {out}: file exists (use --force to overwrite)\n")
    assert main([*argv, "--force", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["orientation"] == "quaternion"


def test_fourth_order_differences_at_a_low_rate(sim, tmp_path, capsys):
    # every 20th sample (50 Hz): the second-order differences' bias dominates, the fourth-order
    # ones are 10x closer to the true velocities inside the trajectories; the order is recorded
    rows = slice(None, None, 20)
    path = write_csv(tmp_path / "rec.csv", columns(sim, rows=rows))
    errs = {}
    for order in (2, 4):
        out = tmp_path / f"d{order}.npz"
        assert main(["import", str(path), "--model", "task4", "--out", str(out),
                     "--differences", str(order)]) == 0
        data = read_dataset(out)
        # inside each trajectory (the two samples at each end take second order's either way)
        inside = np.ones(len(data.t), bool)
        for k in np.unique(data.traj):
            at = np.flatnonzero(data.traj == k)
            inside[at[:2]] = inside[at[-2:]] = False
        errs[order] = rel(data.qd[inside], sim.qd[rows][inside])
        smooth = data.meta["import"]["smooth"]
        assert smooth["differences"] == order and smooth["text"] == "none"
    assert errs[4] < errs[2] / 10, errs
    capsys.readouterr()
    # too few samples for the 5-point differences: one line, naming the order
    short = write_csv(tmp_path / "short.csv", columns(sim, rows=slice(0, 4)))
    assert main(["import", str(short), "--model", "task4", "--out", str(tmp_path / "s.npz"),
                 "--differences", "4"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "smoothing none, differences 4 needs at least 5" in err
    assert not (tmp_path / "s.npz").exists()
    with pytest.raises(SystemExit) as exc:
        main(["import", str(path), "--model", "task4", "--out", str(tmp_path / "x.npz"),
              "--differences", "3"])
    assert exc.value.code == 2
    assert "--differences: invalid choice: 3" in capsys.readouterr().err


# --------------------------------------------------------------------------------------------
# Bad files: one line naming the file, the line and the column; exit status 2

GOOD = "t,u0,u1,u2,q0,q1,q2\n0.0,0,0,0,0.1,0.2,0.0\n0.1,0,0,0,0.1,0.2,0.0\n0.2,0,0,0,0.1,0.2,0.0\n"


@pytest.mark.parametrize(
    "text,extra,message",
    [
        ("", [], "{f}: empty file (expected a header row such as 't,u0,q0')"),
        ("t,u0,u1,u2,q0,q1,q2\n", [], "{f}: no data rows after the header (line 1)"),
        ("\0\1\2binary", [], "{f}: not a CSV file (binary data)"),
        (b"t,q0\n\xff\xfe\n", [], "{f}: not a CSV file (not UTF-8 text"),
        ("t;u0;q0\n0;0;0\n", [], "{f}, line 1: not a CSV file: the header 't;u0;q0' has one "
         "column (columns are separated by commas)"),
        ("0.0,1.0,2.0\n", [], "{f}, line 1: expected a header row of column names, got the "
         "number '0.0' in column 1"),
        (GOOD.replace("t,", "time,"), [], "{f}, column 't': missing column (time in seconds"),
        (GOOD.replace(",q1", ",x1"), [], "{f}, column 'q1': missing column (model task4 has "
         "n = 3 coordinates: q0 .. q2; the header has t, u0, u1, u2, q0, x1, q2)"),
        (GOOD.replace("u2,", "u2,u3,").replace("0,0,0,", "0,0,0,0,"), [],
         "{f}, column 'u3': model task4 has m = 3 inputs (u0 .. u2); the file has 4 input "
         "columns"),
        (GOOD.replace("u2,", "x,"), [], "{f}, column 'u2': missing column (model task4 has "
         "m = 3 inputs: u0 .. u2; the header has t, u0, u1, x, q0, q1, q2)"),
        (GOOD.replace("q2\n", "q2,q3\n").replace(",0.0\n", ",0.0,0.0\n"), [],
         "{f}, column 'q3': model task4 has n = 3 coordinates (q0 .. q2); the file has 4 q "
         "columns"),
        (GOOD.replace("0.2,0,0,0", "0.05,0,0,0"), [], "{f}, line 4, column 't': time 0.05 s is "
         "not after the previous sample's 0.1 s: time must increase within a trajectory"),
        (GOOD.replace("0.1,0.2,0.0\n0.2", "nan,0.2,0.0\n0.2"), [],
         "{f}, line 3, column 'q0': nan (values must be finite)"),
        (GOOD.replace("0.1,0,0,0,0.1", "0.1,0,,0,0.1"), [], "{f}, line 3, column 'u1': empty "
         "value"),
        (GOOD.replace("0.1,0,0,0,0.1", "0.1,0,abc,0,0.1"), [], "{f}, line 3, column 'u1': not "
         "a number: 'abc'"),
        (GOOD.replace("0.1,0,0,0,0.1,0.2,0.0", "0.1,0,0,0,0.1,0.2"), [],
         "{f}, line 3: 6 fields, the header (line 1) has 7"),
        ("traj," + GOOD.replace("\n0", "\n0.5,0").replace("\n0.5,0.2", "\n1,0.2"), [],
         "{f}, line 2, column 'traj': trajectory ids must be integers, got '0.5'"),
        (GOOD, ["--smooth", "savgol:5:2"], "{f}, lines 2-4: 3 samples; smoothing savgol:5:2 "
         "needs at least 5 per trajectory"),
        ("t,u0,u1,u2,qw,qx,qy,qz\n0,0,0,0,1,0,0,0\n1,0,0,0,0.5,0,0,0\n", ["--orientation",
         "quaternion"], "{f}, line 3, column 'qw': quaternion (qw, qx, qy, qz) has norm 0.5; "
         "expected a unit quaternion"),
        ("t,u0,u1,u2,qw,qx,qy,qz\n0,0,0,0,1,0,0,0\n1,0,0,0,1,0,0,0\n", [],
         "{f}, column 'q0': missing column (the file has qw, qx, qy, qz: to import tip "
         "orientation, add --orientation quaternion)"),
        ("t,u0,u1,u2,roll,pitch\n0,0,0,0,0,0\n1,0,0,0,0,0\n", ["--orientation", "rpy"],
         "{f}, column 'yaw': missing column (--orientation rpy reads roll, pitch, yaw)"),
        ("t,u0,u1,u2,qw,qx,qy,qz\n0,0,0,0,1,0,0,0\n1,0,0,0,0,0,1,0\n", ["--orientation",
         "quaternion"], "{f}, line 3, column 'qw': the tip is bent by 180 degrees"),
        (GOOD, ["--test-trajectories", "1"], "--test-trajectories: must be in 0 .. 0 (the "
         "files hold 1 trajectories), got 1"),
        (GOOD, ["--smooth", "gauss:3"], "--smooth: expected none | movmean:W | savgol:W:P | "
         "polyfit:DEG:W, got 'gauss:3'"),
        (GOOD, ["--rate", "-5"], "--rate: must be a positive number of Hz, got -5.0"),
    ],
)
def test_bad_files_are_one_line(tmp_path, capsys, text, extra, message):
    f = tmp_path / "rec.csv"
    if isinstance(text, bytes):
        f.write_bytes(text)
    else:
        f.write_text(text)
    out = tmp_path / "d.npz"
    status = main(["import", str(f), "--model", "task4", "--out", str(out), *extra])
    err = capsys.readouterr().err
    assert status == 2
    assert err.count("\n") == 1 and err.startswith("softpinn: error: "), err
    assert message.format(f=f) in err, err
    assert not out.exists()


def test_bad_models_and_missing_files(tmp_path, capsys):
    f = write_csv(tmp_path / "imu.csv", {"t": [0.0, 1.0], **{f"u{j}": [0.0, 0.0] for j in
                                                               range(6)},
                                         "qw": [1.0, 1.0], "qx": [0.0, 0.0], "qy": [0.0, 0.0],
                                         "qz": [0.0, 0.0]})
    out = str(tmp_path / "d.npz")
    assert main(["import", str(f), "--model", "task5", "--out", out, "--orientation",
                 "quaternion"]) == 2
    assert capsys.readouterr().err == (
        "softpinn: error: --orientation: --orientation quaternion needs a one-segment "
        "spatial-pcc model (the tip rotation determines the bending of one segment only); "
        "model task5 is spatial-pcc with 2 segments\n")
    assert main(["import", str(tmp_path / "nope.csv"), "--model", "task4", "--out", out]) == 2
    assert capsys.readouterr().err == f"softpinn: error: {tmp_path / 'nope.csv'}: no such file\n"
    with pytest.raises(RecordingError, match="no recording files given"):
        import_recordings([], "task4")


def test_unactuated_models_take_no_input_columns(tmp_path):
    t = np.linspace(0, 1, 11)
    f = write_csv(tmp_path / "msd.csv", {"t": t, "q0": np.sin(t), "q1": np.cos(t)})
    data = import_recordings([f], "task1").data
    assert data.u.shape == (11, 0) and data.meta["m"] == 0
    g = write_csv(tmp_path / "msd_u.csv", {"t": t, "u0": t, "q0": t, "q1": t})
    with pytest.raises(RecordingError, match=r"column 'u0': model task1 has m = 0 inputs; the "
                       r"file has 1 input columns"):
        import_recordings([g], "task1")


def test_recorded_velocities_are_used(sim, tmp_path):
    cols = columns(sim)
    cols.update({f"qd{j}": sim.qd[:, j] for j in range(3)})
    data = import_recordings([write_csv(tmp_path / "v.csv", cols)], "task4").data
    np.testing.assert_array_equal(data.qd, sim.qd)
    assert data.meta["import"]["velocities"] == "the qd columns, smoothed"
    cols.pop("qd2")
    with pytest.raises(RecordingError, match=r"column 'qd2': missing column"):
        import_recordings([write_csv(tmp_path / "w.csv", cols)], "task4")


def test_notes_on_units_and_a_file_given_twice(tmp_path):
    """What the data cannot refuse but is likely a mistake gets a note: the same file twice,
    times in milliseconds, angles in degrees; radians and seconds get none."""
    t = np.arange(0.0, 2.0, 0.01)
    good = {"t": t, "u0": 0.1 * np.sin(t), "q0": 0.5 * np.sin(3 * t), "q1": 0.01 * np.cos(t)}
    path = write_csv(tmp_path / "good.csv", good)
    assert import_recordings([path], "task3").notes == []
    notes = import_recordings([path, path], "task3").notes
    assert any("is the same recording as" in n and "appear twice" in n for n in notes)
    ms = write_csv(tmp_path / "ms.csv", {**good, "t": 1000 * t})
    assert any("times step by 10 (median)" in n and "divide t by 1000" in n
               for n in import_recordings([ms], "task3").notes)
    deg = write_csv(tmp_path / "deg.csv", {**good, "q0": np.degrees(good["q0"]) * 4})
    assert any(n.startswith("theta1 reaches") and "if these are degrees" in n
               for n in import_recordings([deg], "task3").notes)


# --------------------------------------------------------------------------------------------
# A hanging arm recorded in a z-up world (docs/import.md, "Recording a real arm")


def qmul(a, b):
    """Hamilton products a ⊗ b of quaternions (N, 4) or (4,), ordered (w, x, y, z)."""
    a, b = np.broadcast_arrays(np.asarray(a, float), np.asarray(b, float))
    w1, x1, y1, z1 = np.moveaxis(a, -1, 0)
    w2, x2, y2, z2 = np.moveaxis(b, -1, 0)
    return np.stack([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
                     w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                     w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2], -1)


def qinv(q):
    return np.asarray(q, float) * np.array([1.0, -1.0, -1.0, -1.0])


QX_PI = np.array([0.0, 1.0, 0.0, 0.0])  # the rotation by pi about x


def test_a_hanging_arm_recorded_with_z_up_imports_with_the_documented_conversion(tmp_path):
    """A hanging arm filmed by a tracker whose world z points up: the tip bends by theta toward
    the world azimuth psi, so its tangent is (sin theta cos psi, sin theta sin psi, -cos theta)
    in the world. The arm's base frame (what import expects: z along the straight arm, from base
    to tip, i.e. down) is the world turned by pi about x: x_B = x_W, y_B = -y_W, z_B = -z_W, so
    the bending there is dx = d theta cos psi, dy = -d theta sin psi. The raw reading q_raw (the
    tracker's body frame, identity when the arm hangs straight) converts by
    q_arm = q_x(pi) ⊗ q_raw ⊗ q_x(pi)^-1 = (w, x, -y, -z); in general
    q_arm = q_x(pi) ⊗ q_raw ⊗ q_rest^-1 ⊗ q_x(pi)^-1 with q_rest the reading when the arm hangs
    straight (a sensor mounted any way). Unconverted, the bending imports mirrored (dx flips)."""
    t = np.linspace(0.0, 2.0, 201)
    theta = 0.6 * np.sin(np.pi * t / 2.0) ** 2 + 0.05  # rad, away from 0 and pi
    psi = 0.3 + 2.0 * t  # the bending direction turns about the arm
    # the raw body rotation: the straight arm's tangent (0, 0, -1) turned by theta about the
    # world axis (0, 0, -1) x t = (sin psi, -cos psi, 0): no twist, as constant curvature
    axis = np.stack([np.sin(psi), -np.cos(psi), np.zeros_like(psi)], 1)
    q_raw = np.hstack([np.cos(theta / 2)[:, None], np.sin(theta / 2)[:, None] * axis])
    tangent = ori.quaternion_to_matrix(q_raw) @ np.array([0.0, 0.0, -1.0])
    np.testing.assert_allclose(tangent, np.stack([np.sin(theta) * np.cos(psi),
                                                  np.sin(theta) * np.sin(psi),
                                                  -np.cos(theta)], 1), atol=1e-12)
    q_arm = qmul(qmul(QX_PI, q_raw), qinv(QX_PI))
    np.testing.assert_allclose(q_arm, q_raw * np.array([1.0, 1.0, -1.0, -1.0]), atol=1e-15)
    # a sensor mounted with its z along the tangent and turned by 0.7 rad about it: the reading
    # at rest q_rest removes the mounting
    mount = qmul(QX_PI, np.array([np.cos(0.35), 0.0, 0.0, np.sin(0.35)]))
    q_rest = mount
    q_mounted = qmul(q_raw, mount)
    q_general = qmul(qmul(qmul(QX_PI, q_mounted), qinv(q_rest)), qinv(QX_PI))
    np.testing.assert_allclose(np.abs(np.sum(q_general * q_arm, 1)), 1.0, atol=1e-12)

    d = 1.0  # task 4: a hanging one-segment arm with d = 1 (dx, dy in rad)
    expected = np.stack([d * theta * np.cos(psi), -d * theta * np.sin(psi)], 1)
    u = np.zeros((len(t), 3))
    for name, quat in (("arm", q_arm), ("general", q_general), ("raw", q_raw)):
        cols = {"t": t, "u0": u[:, 0], "u1": u[:, 1], "u2": u[:, 2]}
        cols.update(zip(("qw", "qx", "qy", "qz"), np.asarray(quat).T, strict=True))
        path = write_csv(tmp_path / f"{name}.csv", cols)
        data = import_recordings([path], "task4", orientation_kind="quaternion").data
        if name == "raw":  # unconverted: mirrored about the base's y-z plane, silently
            np.testing.assert_allclose(data.q[:, 0], -expected[:, 0], atol=1e-9)
            np.testing.assert_allclose(data.q[:, 1], expected[:, 1], atol=1e-9)
        else:
            np.testing.assert_allclose(data.q[:, :2], expected, atol=1e-9)
            assert data.meta["import"]["max_twist_rad"] < 1e-9


def test_a_one_coordinate_arm_imports(tmp_path):
    """n = 1 (a one-mass spring-damper): p = M q̇ keeps its (N, 1) shape (TrueModel used to
    squeeze every 1 x 1 output to a number, and the import failed in momentum)."""
    spec = tmp_path / "one.toml"
    spec.write_text('name = "one-mass"\nkind = "mass-spring-damper"\nmasses = [1.5]\n'
                    'springs = [2.0]\ndampers = [0.3]\nactuation = [[1.0]]\n')
    t = np.linspace(0, 1, 21)
    f = write_csv(tmp_path / "one.csv", {"t": t, "u0": np.cos(t), "q0": np.sin(t)})
    data = import_recordings([f], str(spec)).data
    assert data.q.shape == data.p.shape == (21, 1)
    np.testing.assert_allclose(data.p, 1.5 * data.qd, rtol=1e-14)
    from softpinn.symbolic import TrueModel, load_spec

    tm = TrueModel(load_spec(str(spec)), compiled=False)
    assert np.shape(tm.G([0.1])) == (1,) and np.shape(tm.G([[0.1], [0.2]])) == (2, 1)
    assert isinstance(tm.energy([0.1], [0.2]), float)
    assert np.shape(tm.energy([[0.1], [0.2]], [[0.1], [0.2]])) == (2,)
