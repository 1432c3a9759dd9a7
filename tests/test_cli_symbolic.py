"""The symbolic CLI commands end to end: models, matrices, derive, simulate, and their one-line
errors (exit status 2, ``softpinn: error: ...`` on stderr)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from softpinn.bridge.cli import main
from softpinn.symbolic.simulation._datasets import read_dataset


@pytest.fixture(autouse=True)
def _cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("SOFTPINN_CACHE", str(tmp_path_factory.getbasetemp() / "cli-cache"))


def run(capsys, *argv):
    status = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return status, out, err


def test_models(capsys):
    status, out, _ = run(capsys, "models", "--json")
    assert status == 0
    rows = {r["name"]: r for r in json.loads(out)["models"]}
    assert rows["task5"] == {**rows["task5"], "kind": "spatial-pcc", "n": 6, "m": 6}
    assert rows["task1"]["m"] == 0 and rows["task3"]["n"] == 2
    status, out, _ = run(capsys, "models")
    assert status == 0 and "task4" in out and "spatial-pcc" in out


def test_matrices_json(capsys):
    status, out, _ = run(capsys, "matrices", "task2", "--q", 0.1, 0.2, "--json")
    assert status == 0
    d = json.loads(out)
    assert set(d) >= {"q", "M", "M_inv", "G", "D", "A", "energy"} and "qdd" not in d
    M = np.array(d["M"])
    np.testing.assert_allclose(M, [[2.0, np.cos(0.1 - 0.2)], [np.cos(0.1 - 0.2), 1.0]])
    np.testing.assert_allclose(np.array(d["M_inv"]) @ M, np.eye(2), atol=1e-12)
    status, out, _ = run(
        capsys,
        "matrices",
        "task4",
        "--q",
        1,
        0.2,
        0.15,
        "--qd",
        0.1,
        0,
        0,
        "--u",
        0.1,
        0.2,
        0.3,
        "--json",
    )
    d = json.loads(out)
    assert np.array(d["A"]).shape == (3, 3) and np.array(d["C"]).shape == (3, 3)
    assert len(d["qdd"]) == 3 and d["u"] == [0.1, 0.2, 0.3]
    status, out, _ = run(capsys, "matrices", "task4", "--q", 1, 0.2, 0.15)
    assert status == 0 and "M =" in out and "G =" in out and "energy V [J]" in out
    assert "-0.000000e+00" not in out
    # a configuration no arm can take: a note (the equations still evaluate)
    status, out, err = run(capsys, "matrices", "task4", "--q", 0.01, 0.005, -2)
    assert status == 0 and "dL1 = -2 makes segment 1 -1.8 m long" in err


def test_derive_writes_everything(capsys, tmp_path):
    out_dir = tmp_path / "eom"
    status, out, _ = run(capsys, "derive", "task1", "--out", out_dir, "--json")
    assert status == 0
    summary = json.loads(out)
    files = {p.name for p in out_dir.iterdir()}
    assert {"softpinn_eom.c", "softpinn_eom.so", "summary.json", "forward.casadi"} <= files
    assert summary["model"] == "task1" and summary["n"] == 2
    assert {"derive", "functions", "generate_c", "compile"} <= set(summary["timings_s"])
    fwd = summary["functions"]["forward"]
    assert fwd["n_nodes"] > 0 and fwd["sx_nodes"] > 0
    # a second derive into the same directory is fine; into a foreign one it needs --force
    assert run(capsys, "derive", "task1", "--out", out_dir)[0] == 0
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("keep")
    status, _, err = run(capsys, "derive", "task1", "--out", foreign)
    assert status == 2 and "not empty" in err and "--force" in err
    # a summary.json that derive did not write makes no earlier derive output
    (foreign / "summary.json").write_text('{"files": ["notes.txt"]}')
    (foreign / "softpinn_eom.c").write_text("my code")
    status, _, err = run(capsys, "derive", "task1", "--out", foreign)
    assert status == 2 and "holds no earlier derive output" in err
    assert (foreign / "softpinn_eom.c").read_text() == "my code"
    # --force writes beside them; the foreign summary's "files" are not removed
    assert run(capsys, "derive", "task1", "--out", foreign, "--force")[0] == 0
    assert (foreign / "notes.txt").read_text() == "keep"


def test_simulate_and_resampled_siblings(capsys, tmp_path):
    path = tmp_path / "t5.npz"
    status, out, err = run(
        capsys,
        "simulate",
        "task5",
        "--out",
        path,
        "--trajectories",
        2,
        "--duration",
        0.2,
        "--seed",
        3,
    )
    assert status == 0, err
    d = read_dataset(path)
    assert d.meta["rate"] == 1000.0 and len(d) == 2 * 200 and d.q.shape == (400, 6)
    assert d.meta["seed"] == 3
    # the preset's settle time: recording starts 1 s after release
    assert d.meta["simulation"]["settle"] == 1.0 and d.t[0] == 1.0
    for rate, count in ((50, 10), (100, 20)):
        sub = read_dataset(tmp_path / f"t5_{rate}hz.npz")
        assert sub.meta["rate"] == rate and len(sub) == 2 * count
        np.testing.assert_array_equal(sub.q[:count], d.q[: 200 : 1000 // rate])
    assert "wrote" in out and "t5_50hz.npz" in out
    # existing output without --force
    status, _, err = run(
        capsys, "simulate", "task5", "--out", path, "--trajectories", 1, "--duration", 0.1
    )
    assert status == 2 and err.strip().startswith("softpinn: error: --out") and "--force" in err
    status, _, err = run(
        capsys,
        "simulate",
        "task5",
        "--out",
        path,
        "--trajectories",
        1,
        "--duration",
        0.1,
        "--force",
        "--quiet",
    )
    assert status == 0 and err == ""


def test_simulate_rk4_with_noise(capsys, tmp_path):
    path = tmp_path / "rk.npz"
    status, _, err = run(
        capsys,
        "simulate",
        "task3",
        "--out",
        path,
        "--dt",
        0.001,
        "--rate",
        100,
        "--duration",
        0.5,
        "--trajectories",
        2,
        "--noise",
        0.001,
        "--quiet",
    )
    assert status == 0, err
    d = read_dataset(path)
    assert d.meta["simulation"]["integrator"] == "rk4" and d.meta["simulation"]["dt"] == 0.001
    assert d.meta["noise"]["sigma"] == 0.001 and d.u.shape == (100, 1)


@pytest.mark.parametrize(
    "argv,message",
    [
        (["matrices", "task9", "--q", "0"], "unknown model 'task9'"),
        (["matrices", "task4", "--q", "1", "2"], "--q: model 'task4' needs 3 values, got 2"),
        (["matrices", "task2", "--q", "1", "2", "--qd", "1"], "--qd: model 'task2' needs 2 values"),
        (
            ["matrices", "task4", "--q", "1", "2", "3", "--qd", "0", "0", "0", "--u", "1"],
            "--u: model 'task4' needs 3 values, got 1",
        ),
        (["matrices", "nosuch.toml", "--q", "0"], "nosuch.toml: no such spec file"),
        (
            ["simulate", "task1", "--out", "{tmp}/a.npz", "--duration", "-1"],
            "--duration: must be positive, got -1.0",
        ),
        (["simulate", "task1", "--out", "{tmp}/a.npz", "--rate", "0"], "--rate: must be positive"),
        (
            [
                "simulate",
                "task1",
                "--out",
                "{tmp}/a.npz",
                "--dt",
                "0.003",
                "--rate",
                "100",
                "--duration",
                "1",
            ],
            "whole multiple of dt",
        ),
        (
            [
                "simulate",
                "task1",
                "--out",
                "{tmp}/a.npz",
                "--dt",
                "0.001",
                "--integrator",
                "cvodes",
            ],
            "--dt: is the fixed step of --integrator rk4",
        ),
        (
            ["simulate", "task1", "--out", "{tmp}/a.txt"],
            "--out {tmp}/a.txt: a dataset file must end",
        ),
        (
            ["simulate", "task1", "--out", "{tmp}/a.npz", "--trajectories", "0"],
            "--trajectories: must be at least 1",
        ),
        (["simulate", "task1", "--out", "{tmp}/a.npz", "--noise", "-0.1"], "--noise: must be"),
        (
            ["simulate", "task1", "--out", "{tmp}/a.npz", "--settle", "-1"],
            "--settle: must be a non-negative number of seconds, got -1.0",
        ),
        (
            ["simulate", "task1", "--out", "{tmp}/a.npz", "--settle", "0.013", "--rate", "50"],
            "settle: 0.013 s is not a whole number of samples at 50 Hz",
        ),
        (
            ["simulate", "{tmp}/bad.toml", "--out", "{tmp}/a.npz"],
            "field 'masses[0]': must be positive",
        ),
        (
            ["simulate", "{tmp}/baddata.toml", "--out", "{tmp}/a.npz"],
            "baddata.toml: field 'data.rates': rates must be positive",
        ),
        (["derive", "task1", "--out", "{tmp}/d", "--timeout", "0"], "--timeout: must be positive"),
    ],
)
def test_one_line_errors(capsys, tmp_path, argv, message):
    (tmp_path / "bad.toml").write_text(
        'kind = "mass-spring-damper"\nmasses = [-1.0, 1.0]\nsprings = [1.0, 1.0]\n'
    )
    (tmp_path / "baddata.toml").write_text(
        'kind = "mass-spring-damper"\nmasses = [1.0, 1.0]\nsprings = [1.0, 1.0]\n'
        "[data]\nrates = [0.0]\n"
    )
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    status, out, err = run(capsys, *argv)
    assert status == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("softpinn: error: ")
    assert message.replace("{tmp}", str(tmp_path)) in lines[0]
    assert not (tmp_path / "a.npz").exists()


def test_simulate_singularity_is_one_line(capsys, tmp_path):
    spec = tmp_path / "pt.toml"
    spec.write_text(
        'name = "pt"\nkind = "spatial-pcc"\nparameterization = "phi-theta"\n'
        'gravity = [0.0, 0.0, 9.81]\nactuation = "none"\n'
        "[[segment]]\nlength = 0.2\nmass = 0.3\nstiffness = [0.0, 1.0, 1.0]\n"
        "[data]\nq0_low = [0.3, 0.0, 0.0]\nq0_high = [0.3, 0.0, 0.0]\n"
    )
    status, _, err = run(
        capsys,
        "simulate",
        spec,
        "--out",
        tmp_path / "pt.npz",
        "--duration",
        1,
        "--trajectories",
        1,
        "--quiet",
    )
    assert status == 2
    assert err.count("\n") == 1 and err.startswith("softpinn: error: trajectory 0:")
    assert "t = 0 s" in err and "delta" in err
    assert not (tmp_path / "pt.npz").exists()


def test_derive_without_compiler_warns_in_one_line(capsys, tmp_path, monkeypatch):
    """No default compiler ($CC, gcc, cc): C source, no library, one warning line."""
    monkeypatch.setenv("CC", str(tmp_path / "no-cc"))
    monkeypatch.setenv("PATH", str(tmp_path / "empty-bin"))
    status, out, err = run(capsys, "derive", "task1", "--out", tmp_path / "d")
    assert status == 0
    assert err.strip().splitlines() == [
        "softpinn: warning: no C compiler found (compiler setting: default); "
        "wrote the C source but no shared library"
    ]
    assert (tmp_path / "d" / "softpinn_eom.c").is_file()
    assert not (tmp_path / "d" / "softpinn_eom.so").exists()


def test_derive_with_a_named_compiler_that_does_not_exist_is_refused(capsys, tmp_path):
    """--compiler names a compiler: a missing one is a mistake, not a reason to fall back."""
    status, _, err = run(
        capsys, "derive", "task1", "--out", tmp_path / "d", "--compiler", tmp_path / "no-cc"
    )
    assert status == 2
    assert err.count("\n") == 1
    assert err.startswith(f"softpinn: error: --compiler {tmp_path / 'no-cc'}: no such compiler")
    assert not (tmp_path / "d").exists()
