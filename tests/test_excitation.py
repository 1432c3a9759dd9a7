"""The inertial share of a data set's forces along the true M's eigenvectors, against task 1's
closed form (two masses on springs, M = diag(1, 1.8)), and the bad-input message."""

from __future__ import annotations

import numpy as np
import pytest

from softpinn.bridge.analysis.excitation import inertial_share
from softpinn.symbolic.model._true_model import TrueModel
from softpinn.symbolic.spec._spec import load_spec

# task1.toml: masses 1.0 and 1.8; k1 = 2.1 between the masses, k2 = 4.6 to the ground;
# b = 0.3 between the masses
M = np.diag([1.0, 1.8])
K = np.array([[2.1, -2.1], [-2.1, 2.1 + 4.6]])
B = 0.3 * np.array([[1.0, -1.0], [-1.0, 1.0]])


def test_task1_closed_form():
    rng = np.random.default_rng(0)
    q, qd = rng.normal(size=(200, 2)), rng.normal(size=(200, 2))
    u = np.zeros((200, 0))
    out = inertial_share(TrueModel(load_spec("task1")), q, qd, u)
    # M is diagonal: its eigenvectors are the coordinates, the lighter (1.0) first
    np.testing.assert_allclose(out["eigenvalue"], [1.0, 1.8], rtol=1e-12)
    inertial = -(q @ K.T) - qd @ B.T  # M q̈ = -K q - B q̇
    damping = qd @ B.T

    def rms(a):
        return np.sqrt(np.mean(a * a, axis=0))

    # an eigenvector's sign is free; rms does not see it
    np.testing.assert_allclose(out["inertial"], rms(inertial), rtol=1e-9)
    np.testing.assert_allclose(out["damping"], rms(damping), rtol=1e-9)
    np.testing.assert_allclose(out["rest"], rms(q @ K.T), rtol=1e-9)  # A u - G - C q̇ = -K q
    np.testing.assert_allclose(out["inertia_over_damping"], rms(inertial) / rms(damping),
                               rtol=1e-9)
    # corner frequencies vᵀBv / (2π λ): B's diagonal 0.3 over the masses 1.0 and 1.8
    np.testing.assert_allclose(out["corner_hz"], [0.3 / (2 * np.pi), 0.3 / (2 * np.pi * 1.8)],
                               rtol=1e-12)
    np.testing.assert_allclose(out["vectors"], np.eye(2), atol=1e-12)


def test_rows_must_agree():
    with pytest.raises(ValueError, match=r"q, qd, u: expected the same number N > 0 of rows, "
                                         r"got 3, 2, 3"):
        inertial_share(TrueModel(load_spec("task1")), np.zeros((3, 2)), np.zeros((2, 2)),
                       np.zeros((3, 0)))


def test_cli_table_json_and_refusals(tmp_path, capsys):
    """`softpinn excitation DATA MODEL` on task 1's system: the JSON holds inertial_share's
    numbers for the data's samples, the table one row per direction and a closing line; every
    mistake is one line with exit status 2."""
    import json

    from datagen import make_dataset

    from softpinn.bridge.analysis.excitation import WEAK
    from softpinn.bridge.analysis.forces import data_samples
    from softpinn.bridge.cli import main
    from softpinn.learn._data import load_dataset

    path = make_dataset(tmp_path / "msd.npz", forced=False, trajectories=3, duration=3.0)
    assert main(["excitation", str(path), "task1", "--samples", "50", "--json"]) == 0
    got = json.loads(capsys.readouterr().out)
    q, qd, u, _ = data_samples(load_dataset(path), None, count=50, seed=0)
    want = inertial_share(TrueModel(load_spec("task1")), q, qd, u)
    for key, value in want.items():
        np.testing.assert_allclose(got[key], value, rtol=1e-12)
    assert got["samples"] == 50 and got["trajectories"] == [0, 1, 2]
    assert main(["excitation", str(path), "task1", "--trajectories", "1"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("task1 on ") and "samples of 1 trajectory;" in lines[0]
    assert len(lines) == 2 + 2 + 1 and lines[2].split()[0] == "1" and lines[3].split()[0] == "2"
    one = data_samples(load_dataset(path), [1], count=2000, seed=0)[:3]
    weak = min(inertial_share(TrueModel(load_spec("task1")), *one)["inertia_over_damping"]) < WEAK
    assert lines[-1].startswith("weakly excited" if weak else "every direction shows")
    for argv, message in (
            ([str(tmp_path / "none.npz"), "task1"], "no such file"),
            ([str(path), "task4"], "model has n=3 coordinates, the file has n=2"),
            ([str(path), "task1", "--samples", "0"], "--samples: expected a positive count"),
            ([str(path), "task1", "--trajectories", "7"], "[7] are not in the data set"),
            ([str(path), "nomodel"], "unknown model 'nomodel'"),
            (["task1", str(path)], "is a data set and task1 a model; give the data set first")):
        assert main(["excitation", *argv]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and message in err[0], (argv, err)


def test_a_coordinate_the_recording_does_not_observe_is_said_so(tmp_path, capsys):
    """An import that could not measure a coordinate (a tip IMU's stretch, set to 0) records
    it in meta; the table marks the directions along it 'not observed' instead of a ratio of
    made-up numbers, and leaves them out of its verdict."""
    import json

    from datagen import make_dataset, write

    from softpinn.bridge.cli import main

    path = make_dataset(tmp_path / "msd.npz", forced=False, trajectories=3, duration=3.0)
    arrays = dict(np.load(path))
    meta = json.loads(str(arrays.pop("meta")))
    blind = load_spec("task1").coordinate_names[0]
    meta["import"] = {"unobserved": [blind]}
    path = write(tmp_path / "imu.npz", arrays, meta)
    assert main(["excitation", str(path), "task1", "--samples", "50"]) == 0
    lines = capsys.readouterr().out.splitlines()
    rows = [ln for ln in lines[2:] if ln.split()[0].isdigit()]
    assert any(blind in r and r.rstrip().endswith("not observed") for r in rows)
    assert any(ln.startswith(f"not observed: {blind} (the recording cannot measure it")
               for ln in lines)
    assert main(["excitation", str(path), "task1", "--samples", "50", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["unobserved"] == [blind]


def test_velocity_report_prints_an_undefined_ratio_as_a_dash():
    # a saved share holds NaN/inf as null: the study's table prints them, never fails on them
    from softpinn.bridge.challenges.velocity_report import _excitation_lines

    share = {"inertia_over_damping": [0.0779, None, 0.5], "eigenvalue": [5.5e-4, 6e-4, 0.1]}
    lines = _excitation_lines({"task5": {"variants": {"100Hz": {"excitation": share}}}})
    assert "| task5 | 100Hz | 0.00055, 0.0006 | 7.79 %, – |" in lines


def test_an_undamped_system_gets_one_sentence_not_a_table_of_dashes():
    from softpinn.bridge.analysis.excitation import markdown_lines

    share = {"vectors": [[1.0, 0.0], [0.0, 1.0]], "eigenvalue": [1.0, 2.0], "corner_hz": [0, 0],
             "inertial": [0.3, 0.2], "damping": [0.0, 0.0], "rest": [0.1, 0.1],
             "inertia_over_damping": [None, None]}
    text = " ".join(markdown_lines(share, heading=None))
    assert "has no damping" in text and "|" not in text
