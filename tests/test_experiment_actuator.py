"""``softpinn reproduce experiment --actuator TAU:DELAY`` (issue 43): the experiment's stand-in with
a lag and a dead time between the tendons' commands and the arm, known to the models. The flag is
refused in one line where it does not apply; a quick run (one rate, two preprocessings, a few
epochs: the rest is ``tests/test_experiment.py``'s) simulates the arm behind the actuator, records
the commands as u, imports with ``meta["actuator"]``, gives the networks and the baselines the
actuator, and says so in its report."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from softpinn.bridge.cli import main
from softpinn.bridge.tasks import ReproduceConfig
from softpinn.bridge.tasks import experiment as experiment_mod
from softpinn.bridge.tasks.experiment import experiment_spec, make_experiment_plan
from softpinn.errors import UserError
from softpinn.learn import load_dataset
from softpinn.symbolic import load_spec

ACT = "0.1:0.06"


@pytest.mark.parametrize(("kw", "message"), [
    (dict(task="task1", actuator=ACT), r"^--actuator: only the experiment's stand-in takes it"),
    (dict(task="cosserat", actuator=ACT), r"^--actuator: only the experiment's stand-in"),
    (dict(task="experiment", actuator="0.1"), r"^--actuator: expected TAU:DELAY"),
    (dict(task="experiment", actuator="fast:0.1"), r"^--actuator: time constant must be"),
    (dict(task="experiment", actuator="0.1:90"), r"^--actuator: delay must be between 0 and"),
])
def test_bad_actuators_are_refused_in_one_line(kw, message):
    with pytest.raises(UserError, match=message) as err:
        ReproduceConfig(**kw)
    assert "\n" not in str(err.value)


def test_one_value_per_input_must_match_the_arms_inputs():
    spec = load_spec("experiment")  # four tendons
    with pytest.raises(UserError, match=r"^--actuator: time constant has 2 values; the data "
                                        r"have 4 inputs"):
        make_experiment_plan(spec, ReproduceConfig("experiment", actuator="0.1,0.2:0.05"))


def test_the_command_line_refuses_it_for_another_task(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["reproduce", "task1", "--quick", "--out", str(out), "--actuator", ACT]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("softpinn: error: --actuator: only the experiment's stand-in")
    assert len(err.splitlines()) == 1 and not out.exists()


def test_help_names_the_option_without_heavy_imports():
    code = ("import sys\nfrom softpinn.bridge.cli import main\n"
            "try:\n    main(['reproduce', '--help'])\nexcept SystemExit:\n    pass\n"
            "print('HEAVY', [m for m in ('jax', 'casadi') if m in sys.modules])\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert "--actuator TAU:DELAY" in out and "HEAVY []" in out


def test_the_plan_and_the_spec_carry_the_actuator():
    spec = load_spec("experiment")
    plain = make_experiment_plan(spec, ReproduceConfig("experiment", quick=True))
    assert plain.actuator is None and "actuator" not in plain.to_dict()  # plan.json as before
    assert experiment_spec(spec, plain) is spec
    none = make_experiment_plan(spec, ReproduceConfig("experiment", quick=True, actuator="none"))
    assert none.actuator is None
    plan = make_experiment_plan(spec, ReproduceConfig("experiment", quick=True, actuator=ACT))
    assert plan.to_dict()["actuator"] == {"time_constant": [0.1], "delay": [0.06]}
    assert plan.actuator_dynamics(spec.m).text() == ACT
    lagged = experiment_spec(spec, plan)
    assert lagged.actuator_meta() == {"time_constant": [0.1] * 4, "delay": [0.06] * 4}
    # every stage's settings differ from a run without it (no stale stage is reused)
    assert experiment_mod._record_settings(plan, 5.0) != experiment_mod._record_settings(plain,
                                                                                          5.0)
    rec = {"csv": "$OUT/record/5Hz/imu.csv", "sensor": plain.sensor}
    assert (experiment_mod._import_settings(plan, rec, "none", "none")["actuator"]
            == plan.actuator)
    assert "actuator" not in experiment_mod._import_settings(plain, rec, "none", "none")


def _path(path: str, out) -> str:
    return path.replace("$OUT", str(out))


def _small(plan):
    """The quick plan at the paper's 5 Hz alone, with no preprocessing and Savitzky-Golay."""
    rn = f"{plan.main_rate:g}Hz"
    keep = ("none", "savgol")
    return dataclasses.replace(
        plan, rates=(plan.main_rate,), substeps={rn: plan.substeps[rn]},
        preprocessing={rn: {p: plan.preprocessing[rn][p] for p in keep}})


@pytest.fixture(scope="module")
def lagged(tmp_path_factory):
    from softpinn.bridge.app import reproduce

    out = tmp_path_factory.mktemp("experiment_actuator")
    with pytest.MonkeyPatch.context() as mp:
        made = experiment_mod.make_experiment_plan
        mp.setattr(experiment_mod, "make_experiment_plan", lambda s, c: _small(made(s, c)))
        return reproduce(ReproduceConfig("experiment", quick=True, epochs=3, actuator=ACT), out)


def test_a_quick_run_with_an_actuator(lagged):
    out = lagged.out_dir
    plan = json.loads((out / "plan.json").read_text())
    assert plan["actuator"] == {"time_constant": [0.1], "delay": [0.06]}
    results = json.loads((out / "results.json").read_text())["results"]
    assert results["actuator"]["text"] == ACT
    assert results["actuator"]["delay"] == [0.06] * 4
    entry = results["rates"]["5Hz"]["preprocessing"]["savgol"]
    # the imported data: the commands as u, the actuator in meta
    data = load_dataset(_path(entry["import"]["path"], out))
    assert data.meta["actuator"] == {"time_constant": [0.1] * 4, "delay": [0.06] * 4}
    assert data.meta["source"] == "import" and data.m == 4
    sim = load_dataset(_path(results["data"]["path"], out))
    assert sim.meta["actuator"]["delay"] == [0.06] * 4
    # u holds the commands: the simulated file's and the imported file's are the same
    ts, us = sim.t[sim.traj == 0], sim.u[sim.traj == 0]
    ti, ui = data.t[data.traj == 0], data.u[data.traj == 0]
    idx = np.searchsorted(ts, ti - 1e-9)
    assert np.allclose(ts[idx], ti) and np.allclose(us[idx], ui)
    csv_text = (out / "record" / "5Hz" / "imu.csv").read_text()
    assert f"(train with --actuator {ACT})" in csv_text.splitlines()[0]
    # the networks were given it, known
    for kind in ("lagrangian", "blackbox"):
        model = entry["models"][kind]
        assert model["train"]["config"]["actuator"] == ACT
        run_cfg = json.loads((Path(_path(model["train"]["run"], out)) /
                              "config.json").read_text())
        assert run_cfg["train"]["actuator"] == ACT
        pr = model["predict"]
        assert pr["prediction_error"]["count"] == 2
    assert {s["kind"] for s in entry["baselines"]["short"]["scores"]} == {
        "no_motion", "arx", "arx_lags", "linear2", "linear2_rollout"}
    text = lagged.report.read_text(encoding="utf-8")
    assert ("**Actuator: lag 0.1 s after a dead time 0.06 s (known to the models)** "
            f"(`--actuator {ACT}`)") in text
    assert "own dynamics (here the known lag and dead time above)" in text
