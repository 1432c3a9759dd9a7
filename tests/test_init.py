"""An arm of one's own: softpinn init writes a commented template spec that loads and simulates
(symbolic/recorded/_template.py); a spec without [data] simulates with defaults from its physics
(symbolic/simulation/_defaults.py) instead of identical trajectories from q = 0; and the whole path
spec -> init -> simulate -> CSV -> import for a 3-segment arm."""

from __future__ import annotations

import dataclasses
import json
import logging

import numpy as np
import pytest

from softpinn.bridge.cli import main
from softpinn.learn._data import load_dataset
from softpinn.symbolic.simulation._datafile import read_dataset
from softpinn.symbolic.simulation._datasets import make_dataset, plan_dataset
from softpinn.symbolic.simulation._datatable import DataError, data_config
from softpinn.symbolic.simulation._defaults import physics_data_table
from softpinn.symbolic.spec._spec import load_spec, spec_from_dict, spec_from_toml


@pytest.fixture(autouse=True)
def _cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("SOFTPINN_CACHE", str(tmp_path_factory.getbasetemp() / "init-cache"))


def run(capsys, *argv):
    status = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return status, out, err


def commented_data_table(text: str) -> dict:
    """The template's commented-out [data] block, uncommented and parsed."""
    import tomllib

    lines = text.splitlines()
    start = lines.index("# [data]")
    body = []
    for line in lines[start + 1:]:
        if not line.startswith("# ") or " = " not in line:
            break
        body.append(line[2:])
    return tomllib.loads("\n".join(body))


def test_path_init_simulate_import_for_a_three_segment_arm(tmp_path, capsys, caplog):
    spec_file = tmp_path / "arm3.toml"
    status, out, _ = run(capsys, "init", "arm3", "--segments", 3, "--out", spec_file)
    assert status == 0 and f"arm3: wrote {spec_file} (3-segment spatial-pcc, n = 9, m = 12" in out
    text = spec_file.read_text()
    spec = load_spec(spec_file)
    assert spec.n == 9 and spec.m == 12 and spec.actuation == "tendon" and not spec.data
    assert text.count("[[segment]]") == 3 and "# [data]" in text
    # the commented [data] block is what simulate will use for the physics as written
    shown = commented_data_table(text)
    assert set(shown) >= {"rate", "duration", "q0_low", "q0_high", "signal", "amplitude_high"}
    data_config(spec, shown)
    table, _ = physics_data_table(spec)
    assert shown["rate"] == table["rate"] and shown["q0_high"] == table["q0_high"]

    npz = tmp_path / "arm3.npz"
    with caplog.at_level(logging.WARNING, logger="softpinn.symbolic"):
        status, out, err = run(capsys, "simulate", spec_file, "--out", npz, "--trajectories", 2,
                               "--duration", 0.2, "--rate", 1000, "--no-compile", "--quiet")
    assert status == 0, err
    assert "arm3: no [data] table: defaults from its physics" in caplog.text
    sim = read_dataset(npz)
    assert sim.meta["data_defaults"].startswith("arm3: no [data] table")
    assert sim.meta["signal_kind"] == "multisine" and sim.meta["spec"]["data"]["seed"] == 0
    assert not np.array_equal(sim.q[sim.traj == 0], sim.q[sim.traj == 1])
    assert np.all(np.abs(sim.q[:, 2::3]) < 0.05)  # stretch: a fraction of the 0.2 m segments

    csv = tmp_path / "arm3.csv"
    names = ["traj", "t", *(f"u{j}" for j in range(12)), *(f"q{j}" for j in range(9))]
    np.savetxt(csv, np.c_[sim.traj, sim.t, sim.u, sim.q], delimiter=",", header=",".join(names),
               comments="", fmt="%.17g")
    back = tmp_path / "back.npz"
    status, out, err = run(capsys, "import", csv, "--model", spec_file, "--out", back,
                           "--test-trajectories", 1)
    assert status == 0, err
    data = load_dataset(back, n=9, m=12)
    np.testing.assert_array_equal(data.q, sim.q)
    np.testing.assert_array_equal(data.u, sim.u)
    # central differences of exact samples at 1 kHz; the fastest mode (stretch) is 35 Hz
    inside = np.r_[2:198, 202:398]
    scale = np.abs(sim.qd).max(0)
    assert np.max(np.abs(data.qd[inside] - sim.qd[inside]) / scale) < 0.02


@pytest.mark.parametrize(
    "argv,kind,n,m",
    [
        (["--segments", "1"], "spatial-pcc", 3, 4),
        (["--segments", "2", "--planar", "--hanging"], "planar-pcc", 4, 4),
        (["--segments", "1", "--hanging", "--actuation", "generalized"], "spatial-pcc", 3, 3),
        (["--segments", "2", "--spatial", "--actuation", "tip-wrench"], "spatial-pcc", 6, 6),
        (["--segments", "2", "--actuation", "chambers"], "spatial-pcc", 6, 6),
        (["--segments", "1", "--hanging", "--actuation", "chambers", "--angles", "0", "90", "180",
          "270"], "spatial-pcc", 3, 4),
        (["--segments", "2", "--actuation", "torques"], "spatial-pcc", 6, 4),
        (["--segments", "2", "--planar", "--actuation", "torques"], "planar-pcc", 4, 2),
        (["--segments", "2", "--actuation", "tendons", "--inputs", "3"], "spatial-pcc", 6, 6),
        (["--segments", "2", "--actuation", "tendons", "--angles", "45", "225"], "spatial-pcc",
         6, 4),
    ],
)
def test_variants_load_and_plan(tmp_path, capsys, argv, kind, n, m):
    out = tmp_path / "x.toml"
    status, _, err = run(capsys, "init", "x", *argv, "--out", out)
    assert status == 0, err
    spec = load_spec(out)
    assert (spec.kind, spec.n, spec.m) == (kind, n, m)
    hanging = "--hanging" in argv
    g = spec.gravity[-1]
    assert (g > 0) == hanging
    plan = plan_dataset(spec)
    assert plan.data.signal == "multisine" and plan.trajectories == 10


def test_init_errors(tmp_path, capsys):
    out = tmp_path / "a.toml"
    out.write_text("mine\n")
    cases = [
        (["init", "a", "--segments", 1, "--out", out],
         f"--out {out}: file exists (use --force to overwrite)"),
        (["init", "a", "--segments", 0, "--out", tmp_path / "b.toml"],
         "--segments: must be a whole number >= 1, got 0"),
        (["init", "a b", "--segments", 1, "--out", tmp_path / "b.toml"],
         "name: use letters, digits, '_', '-' or '.', got 'a b'"),
        (["init", "a", "--segments", 1, "--planar", "--actuation", "tendon", "--out",
          tmp_path / "b.toml"], "--actuation: a planar arm takes one of generalized, torques, "
         "none, got 'tendon'"),
        (["init", "a", "--segments", 1, "--actuation", "torques", "--inputs", 3, "--out",
          tmp_path / "b.toml"], "--inputs: only --actuation tendons or chambers take a number "
         "of inputs per segment; torques has a fixed number"),
        (["init", "a", "--segments", 1, "--actuation", "chambers", "--inputs", 3, "--angles", 0,
          120, "--out", tmp_path / "b.toml"], "--inputs: 3 inputs per segment but 2 angles; "
         "give as many angles as inputs"),
        (["init", "a", "--segments", 1, "--actuation", "chambers", "--angles", 0, 360, "--out",
          tmp_path / "b.toml"], "--angles: two actuators at the same angle (mod 360), got "
         "[0.0, 360.0]"),
        (["init", "a", "--segments", 1, "--angles", 0, 90, "--actuation", "generalized",
          "--out", tmp_path / "b.toml"], "--angles: only --actuation tendons or chambers are "
         "placed at angles; generalized has none"),
        (["init", "a", "--segments", 1, "--out", tmp_path / "b.txt"],
         f"--out {tmp_path / 'b.txt'}: a spec file must end in .toml"),
    ]
    for argv, message in cases:
        status, _, err = run(capsys, *argv)
        assert status == 2 and err == f"softpinn: error: {message}\n", err
    assert out.read_text() == "mine\n"
    assert run(capsys, "init", "a", "--segments", 1, "--out", out, "--force")[0] == 0
    assert load_spec(out).name == "a"


def test_chambers_push_away_and_stretch_with_the_documented_matrix(tmp_path, capsys):
    """Three pneumatic chambers at 0/120/240 deg: the template's constant A is 1000 S (-cos a,
    -sin a, 1) [N/kPa] per chamber on its own segment's (dx, dy, dL); a pressure in the chamber
    at 0 deg bends the segment away from it (toward -x) and stretches it; the arm simulates."""
    from softpinn.symbolic.model._true_model import TrueModel
    from softpinn.symbolic.recorded._template import CHAMBER_AREA

    out = tmp_path / "pneu.toml"
    status, text, err = run(capsys, "init", "pneu", "--segments", 2, "--hanging", "--actuation",
                            "chambers", "--angles", 0, 120, 240, "--out", out)
    assert status == 0, err
    assert "m = 6, actuation chambers (a constant 6 x 6 matrix)" in text
    spec = load_spec(out)
    assert spec.actuators_per_segment == 3 and "gauge pressures [kPa]" in out.read_text()
    S = 1000 * CHAMBER_AREA
    expected = np.zeros((6, 6))
    for i in range(2):
        for j, a in enumerate(np.radians([0, 120, 240])):
            expected[3 * i:3 * i + 3, 3 * i + j] = S * np.array([-np.cos(a), -np.sin(a), 1.0])
    tm = TrueModel(spec, compiled=False)
    q = np.array([0.004, -0.002, 0.01, -0.003, 0.005, 0.0])
    A = np.asarray(tm.A(q)).reshape(6, 6)
    np.testing.assert_allclose(A, expected, rtol=1e-5, atol=1e-12)  # 6 digits, constant in q
    # 10 kPa in chamber 1 of segment 2 from rest: the tip segment bends toward -x, stretches
    z = np.zeros(6)
    u = np.zeros(6)
    u[3] = 10.0
    qdd = np.asarray(tm.qdd(z, z, u)).ravel() - np.asarray(tm.qdd(z, z, 0 * u)).ravel()
    assert qdd[3] < 0 and abs(qdd[4]) < 1e-9 * abs(qdd[3]) and qdd[5] > 0
    npz = tmp_path / "pneu.npz"
    status, _, err = run(capsys, "simulate", out, "--out", npz, "--trajectories", 2,
                         "--duration", 0.2, "--no-compile", "--quiet")
    assert status == 0, err
    sim = read_dataset(npz)
    assert sim.u.shape[1] == 6 and np.all(np.isfinite(sim.q))


def test_tendons_at_angles_match_the_named_tendon_actuation():
    """`--actuation tendons --angles 0 90 180 270` writes the constant matrix that actuation =
    "tendon" derives as -(d l / dq)^T for four evenly spaced tendons (three segments, so the
    routing through lower segments at (i - k) 180/a_dof deg is checked too); torques are 1/d."""
    from softpinn.symbolic import write_template
    from softpinn.symbolic.model._true_model import TrueModel

    _, named = write_template("a", 3)
    _, matrix = write_template("a", 3, actuation="tendons", angles=[0, 90, 180, 270])
    assert named.actuation == "tendon" and isinstance(matrix.actuation, tuple)
    q = np.random.default_rng(0).normal(0.0, 0.005, 9)
    A_named = np.asarray(TrueModel(named, compiled=False).A(q)).reshape(9, 12)
    A_matrix = np.asarray(TrueModel(matrix, compiled=False).A(q)).reshape(9, 12)
    np.testing.assert_allclose(A_matrix, A_named, atol=1e-6)
    _, torques = write_template("a", 2, actuation="torques")
    A = np.asarray(TrueModel(torques, compiled=False).A(np.zeros(6))).reshape(6, 4)
    d = torques.segments[0].actuator_radius
    np.testing.assert_allclose(A[[0, 1, 3, 4]], np.eye(4) / d)
    assert not A[[2, 5]].any()


# --------------------------------------------------------------------------------------------
# Defaults for a spec without [data]


def hanging_soft_arm(**changes):
    """The issue's example: one hanging segment, soft in stretch (m g / (2 k) = 1.47 m)."""
    seg = dict(length=0.2, mass=0.3, stiffness=[1.0, 1.0, 1.0], damping=[0.1, 0.1, 0.1])
    raw = dict(name="soft", kind="spatial-pcc", gravity=[0.0, 0.0, 9.81],
               actuation="generalized", segment=[seg])
    raw.update(changes)
    return spec_from_dict(raw, source="soft.toml")


def test_a_hanging_soft_arm_is_held_at_rest_and_trajectories_differ():
    spec = hanging_soft_arm()
    table, summary = physics_data_table(spec)
    assert table["offset_low"] == table["offset_high"]
    assert table["offset_low"][2] == pytest.approx(-0.3 * 9.81 / 2, rel=1e-3)  # holds dL = 0
    assert "held by the constant input" in summary
    d = make_dataset(spec, trajectories=2, duration=2.0, rate=50.0, compile=False)
    assert np.max(np.abs(d.q[:, 2])) < 0.25 * 0.2  # not metres
    assert not np.allclose(d.q[d.traj == 0], d.q[d.traj == 1])
    assert len({json_key(s) for s in d.meta["signals"]}) == 2


def json_key(d):
    import json

    return json.dumps(d, sort_keys=True)


def test_unactuated_specs_get_distinct_free_motions():
    spec = dataclasses.replace(load_spec("task2"), data={})
    plan = plan_dataset(spec)
    assert plan.data.signal == "zero" and plan.data.q0_low == (-0.3, -0.3)
    assert plan.data_defaults.startswith("task2: no [data] table")


@pytest.mark.parametrize(
    "spec,message",
    [
        (hanging_soft_arm(gravity=[0.0, 0.0, -9.81], actuation="none",
                          segment=[dict(length=0.2, mass=0.3, stiffness=[1e-3, 1e-3, 100.0])]),
         "soft.toml: no [data] table, and the arm is not stable at its rest state"),
        (hanging_soft_arm(actuation="none"),
         "soft.toml: no [data] table, and the arm has no usable rest state at zero input"),
        (hanging_soft_arm(parameterization="phi-theta"), "phi-theta is singular"),
    ],
)
def test_specs_whose_physics_give_no_defaults_are_refused(spec, message):
    with pytest.raises(DataError, match=message.replace("[", r"\[").replace("]", r"\]")):
        plan_dataset(spec)


def test_a_data_table_that_makes_identical_trajectories_is_refused(tmp_path, capsys):
    text = ('name = "same"\nkind = "mass-spring-damper"\nmasses = [1.0, 1.0]\n'
            "springs = [1.0, 1.0]\n[data]\nduration = 1.0\n")
    with pytest.raises(DataError, match=r"same.toml: \[data\] makes all 3 trajectories "
                       r"identical"):
        plan_dataset(spec_from_toml(text, source="same.toml"), trajectories=3)
    plan_dataset(spec_from_toml(text, source="same.toml"), trajectories=1)  # one is fine


def test_reproduce_runs_a_spec_file_of_ones_own(tmp_path, capsys, monkeypatch):
    """`softpinn reproduce arm.toml`: a spec of one's own (no [data], no [training]) runs as a
    task, its data drawn from its physics; the report has our errors in Table III's columns and
    names the command; the arm's physics is part of the data's key, so an edited arm makes new
    data (and so new models) in the same folder."""
    from softpinn.bridge.tasks.pipeline import _data_settings
    from softpinn.bridge.tasks.plan import ReproduceConfig, make_plan, task_spec

    monkeypatch.chdir(tmp_path)
    assert run(capsys, "init", "arm", "--segments", 1, "--planar", "--out", "arm.toml")[0] == 0
    status, out, err = run(capsys, "reproduce", "arm.toml", "--quick", "--epochs", 2,
                           "--lbfgs-steps", 0, "--out", "runs", "--quiet")
    assert status == 0, err
    report = (tmp_path / "runs" / "report.md").read_text()
    assert "`softpinn reproduce arm.toml --quick`" in report
    assert "## Errors" in report and "Table III (" not in report and "paper" not in report
    assert "arm: errors in Table III's columns (Lagrangian physics model)" in report
    assert "configurations sampled in the data's range" in report
    done = json.loads((tmp_path / "runs" / "data" / "done.json").read_text())
    config = ReproduceConfig("arm.toml", quick=True)
    spec = task_spec("arm.toml")
    assert done["settings"]["physics"] == spec.physics_dict()
    mass = spec.segments[0].mass
    text = (tmp_path / "arm.toml").read_text()
    (tmp_path / "arm.toml").write_text(text.replace(f"mass = {mass:g}", f"mass = {2 * mass:g}"))
    edited = task_spec("arm.toml")
    assert edited.segments[0].mass == 2 * mass
    assert (_data_settings(make_plan(edited, config), edited)
            != _data_settings(make_plan(spec, config), spec))


def test_reproduce_refuses_a_missing_spec_file(tmp_path, capsys):
    status, _, err = run(capsys, "reproduce", tmp_path / "nope.toml", "--quick", "--out",
                         tmp_path / "runs")
    assert status == 2 and err.count("\n") == 1 and "nope.toml" in err, err
    assert not (tmp_path / "runs").exists()
    status, _, err = run(capsys, "reproduce", "task9", "--out", tmp_path / "runs")
    # the studies after the presets (experiment, challenges, cosserat, ...) are the registry's
    assert status == 2 and err.startswith("softpinn: error: task: expected one of task1, task2, "
                                          "task3, task4, task5, experiment, challenges"), err
    assert err.endswith(" or a spec file (.toml), got 'task9'\n") and err.count("\n") == 1, err


def test_a_full_run_of_ones_own_arm_takes_about_50000_steps(tmp_path):
    """Without epochs in the recipe, a full run's networks get about DEFAULT_STEPS optimizer
    steps on the data's training pairs (not 1,000 epochs of whatever the data hold)."""
    from softpinn.bridge.tasks.plan import DEFAULT_STEPS, ReproduceConfig, make_plan, task_spec

    path = tmp_path / "arm.toml"
    assert main(["init", "arm", "--segments", "1", "--planar", "--out", str(path)]) == 0
    spec = task_spec(str(path))
    plan = make_plan(spec, ReproduceConfig(str(path)))
    d = spec.data  # the physics defaults: 8 training trajectories of 10 s at 500 Hz
    pairs = d["train_trajectories"] * (round(d["duration"] * d["rate"]) - 1)
    steps = -(-pairs // plan.batch_size)
    for kind in ("lagrangian", "blackbox"):
        assert plan.models[kind].epochs == round(DEFAULT_STEPS / steps) == 80
    # a recipe's own epochs win; so does --epochs
    text = path.read_text() + "\n[training.full.lagrangian]\nepochs = 7\n"
    path.write_text(text)
    plan = make_plan(task_spec(str(path)), ReproduceConfig(str(path)))
    assert plan.models["lagrangian"].epochs == 7 and plan.models["blackbox"].epochs == 80
    plan = make_plan(task_spec(str(path)), ReproduceConfig(str(path), epochs=3))
    assert plan.models["lagrangian"].epochs == plan.models["blackbox"].epochs == 3
