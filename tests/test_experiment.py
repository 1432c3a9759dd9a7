"""``softpinn reproduce experiment --quick`` (bridge/tasks/experiment.py): the paper's experiment
on a simulated stand-in runs end to end, once, and leaves its report, tables and figures with
every number finite or marked diverged."""

from __future__ import annotations

import json
import math
import re

import pytest

from softpinn.bridge.tasks import ReproduceConfig
from softpinn.bridge.tasks.experiment import (
    PREPROCESSING,
    make_experiment_plan,
    rate_name,
    smoother,
)
from softpinn.symbolic.spec._spec import load_spec


def test_the_full_plan_follows_the_preset():
    spec = load_spec("experiment")
    plan = make_experiment_plan(spec, ReproduceConfig("experiment"))
    assert plan.main_rate == 5.0 and plan.rates == (5.0, 20.0, 50.0, 100.0)
    assert plan.sim_rate == 100.0 and plan.trajectories == 128 and plan.test_trajectories == 8
    assert plan.reset_every == 3.0 and plan.horizon == 5.0
    # RK4 sub-steps no longer than max_step = 0.1 s: the paper's 0.2 s step takes two
    assert dict(plan.substeps) == {"5Hz": 2, "20Hz": 1, "50Hz": 1, "100Hz": 1}
    assert plan.preprocessing["5Hz"] == {"none": "none", "movmean": "movmean:3",
                                         "polyfit": "polyfit:3:5", "savgol": "savgol:5:3"}
    assert plan.preprocessing["100Hz"]["movmean"] == "movmean:20"  # 0.2 s, as 20 at 100 Hz
    assert plan.preprocessing["100Hz"]["savgol"] == "savgol:81:3"  # cubics over 0.8 s
    assert plan.models["lagrangian"]["mass"] == (32, 2)  # at least MIN_WIDTH wide
    assert plan.models["blackbox"]["hidden"] == (60, 3)  # Table IV's 60*3
    assert plan.samples == 6000
    json.dumps(plan.to_dict())
    for name in PREPROCESSING:
        for rate in plan.rates:
            assert smoother(name, rate).split(":")[0] == name
    assert rate_name(5.0) == "5Hz"


@pytest.mark.parametrize("line", ["known_input = true", 'loss = "accel"'])
def test_recipe_settings_the_experiment_does_not_use_are_refused(tmp_path, line):
    """A [training.lagrangian] setting the experiment's pipeline would ignore is one line."""
    from softpinn.errors import UserError
    from softpinn.symbolic.spec._spec import preset_path

    text = preset_path("experiment").read_text().replace(
        "[training.lagrangian]\n", f"[training.lagrangian]\n{line}\n", 1)
    path = tmp_path / "exp.toml"
    path.write_text(text)
    key = line.split()[0]
    with pytest.raises(UserError, match=rf"\[training.lagrangian\] {key} is not used by"):
        make_experiment_plan(load_spec(path), ReproduceConfig("experiment"))


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    from softpinn.bridge.app import reproduce

    out = tmp_path_factory.mktemp("experiment")
    # its models side by side (--jobs 2): the checks below read what the workers wrote
    return reproduce(ReproduceConfig("experiment", quick=True, jobs=2), out)


def _finite_or_diverged(entry):
    if entry["mean"] is None:
        assert entry["diverged"] > 0  # no number only where a rollout left the finite numbers
    else:
        assert math.isfinite(entry["mean"]) and entry["mean"] >= 0


def test_quick_run_writes_the_report_tables_and_figures(quick):
    out = quick.out_dir
    text = quick.report.read_text(encoding="utf-8")
    assert "**These data are simulated.**" in text and "**This is a quick run**" in text
    for part in ("## Table IV", "## Raw and processed data", "## Sensor rate and preprocessing",
                 "## The learned bending matrices", "paper smoothing", "13.229 ± 60.762 (5s)"):
        assert part in text, part
    for stem in ("table_iv", "rates_truth", "rates_measurement", "bending"):
        for ext in ("md", "csv", "tex"):
            assert (out / "tables" / f"{stem}.{ext}").is_file()
    figures = {p.name for p in (out / "figures").glob("*.png")}
    assert {"raw_vs_processed.png", "sensor.png", "rates.png"} <= figures
    for prep in PREPROCESSING:
        assert {f"short_{prep}.png", f"reset_{prep}.png"} <= figures
    for name in figures:  # every figure is linked from the report
        assert f"figures/{name}" in text
    csv_text = (out / "record" / "5Hz" / "imu.csv").read_text()
    assert csv_text.startswith("# Simulated IMU")
    assert "traj,t,u0,u1,u2,u3,roll,pitch,yaw" in csv_text
    manifest = json.loads((out / "manifest.json").read_text())
    assert "report.md" in json.dumps(manifest)
    assert "models at a time (`--jobs 2`)" in text


def _baselines_at_the_networks_horizons(entry):
    """Issue 43: no motion and the linear models on the same imported bending coordinates and
    split, at the networks' horizons: 5 s, and the whole test trajectories with resets."""
    bl = entry["baselines"]
    pr = entry["models"]["lagrangian"]["predict"]
    for way, key in (("short", "prediction_error"), ("reset", "reset_error")):
        c = bl[way]
        assert c["train_trajectories"] == entry["import"]["train"]
        assert c["test_trajectories"] == entry["import"]["test"] == [10, 11]
        assert {s["kind"] for s in c["scores"]} == {"no_motion", "arx", "arx_lags",
                                                    "linear2", "linear2_rollout"}
        assert {s["horizon"] for s in c["scores"]} == {pr[key]["horizon_s"]}
        assert all(s["mean"] is None or s["mean"] >= 0 for s in c["scores"])
    assert bl["reset_every_s"] == pr["reset_error"]["reset_every_s"] == 3.0


def test_quick_run_reports_the_networks_beside_the_baselines(quick):
    out = quick.out_dir
    text = quick.report.read_text(encoding="utf-8")
    assert "## The networks against no motion and linear models" in text
    for way in ("short", "reset"):
        assert (out / "tables" / f"baselines_{way}.csv").is_file()
    head = "| sensor rate [Hz] | preprocessing | Lagrangian network | black box | no motion |"
    assert text.count(head) == 2
    # the opening verdict and the section say in how many combinations each network wins
    assert text.count("beats both the best linear model and no motion in") == 4
    # one verdict line per network and preprocessing at the paper's 5 Hz
    for prep in PREPROCESSING:
        for who in ("Lagrangian network", "black box"):
            assert re.search(rf"^- {who}, {prep}: at 5 s (beats|LOSES).*; with the state reset "
                             r"every 3 s, at [0-9.]+ s (beats|LOSES)", text, re.M), (who, prep)


def test_quick_run_numbers_are_finite_or_marked_diverged(quick):
    results = json.loads((quick.out_dir / "results.json").read_text())["results"]
    assert list(results["rates"]) == ["5Hz", "20Hz"]
    for per in results["rates"].values():
        assert set(per["preprocessing"]) == set(PREPROCESSING)
        for entry in per["preprocessing"].values():
            imp = entry["import"]
            assert imp["test"] == [10, 11] and imp["samples"] > 0
            assert 0 < imp["q_error_rms"] < 0.2  # the sensor's noise and bias, and smoothing
            for kind in ("lagrangian", "blackbox"):
                pr = entry["models"][kind]["predict"]
                for key in ("prediction_error", "prediction_error_truth", "reset_error",
                            "reset_error_truth"):
                    _finite_or_diverged(pr[key])
                assert pr["prediction_error"]["horizon_s"] == 5.0
                assert pr["reset_error"]["reset_every_s"] == 3.0
                assert pr["test_error"]["mean"] is None or math.isfinite(pr["test_error"]["mean"])
            _baselines_at_the_networks_horizons(entry)
            bend = entry["models"]["lagrangian"]["bending"]
            assert bend["points"] > 0 and set(bend["alpha"]["residual"]) == {"M", "D", "G", "A"}
    rec = results["rates"]["5Hz"]["record"]
    assert rec["sensor"]["rate_hz"] == 5.0
    assert all(0.005 < x < 0.02 for x in rec["noise_rms"])  # noise_std = 0.01 rad
