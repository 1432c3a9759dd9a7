"""analyze on an arm of one's own: a spec without a [data] box samples the q to analyse from
the run's data set (or --data) instead of failing ("no [data] q0_low/q0_high")."""

from __future__ import annotations

import json

from softpinn.bridge.cli import main


def test_analyze_a_spec_without_a_data_table(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("SOFTPINN_CACHE", str(tmp_path / "cache"))
    spec = tmp_path / "arm.toml"
    data = tmp_path / "arm.npz"
    run = tmp_path / "run"
    assert main(["init", "arm", "--segments", "1", "--planar", "--out", str(spec)]) == 0
    assert main(["simulate", str(spec), "--out", str(data), "--trajectories", "3",
                 "--duration", "0.5", "--no-compile", "--quiet"]) == 0
    assert main(["train", str(data), "--model", "lagrangian", "--out", str(run), "--epochs", "2",
                 "--width", "8", "--depth", "1", "--quiet", "--json"]) == 0
    capsys.readouterr()
    out = tmp_path / "an"
    assert main(["analyze", str(run), str(spec), "--points", "12", "--samples", "0",
                 "--transform", "alpha", "pointwise", "--out", str(out), "--json"]) == 0
    payload = json.loads(capsys.readouterr().out)
    assert len(payload["q"]) == 12 and (out / "report.md").is_file()
    # without the run's data set and without --data: one line saying what to give
    data.rename(tmp_path / "moved.npz")
    assert main(["analyze", str(run), str(spec), "--samples", "0", "--transform", "alpha",
                 "--out", str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "give --q or --data" in err[0]
