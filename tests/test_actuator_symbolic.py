"""A spec's ``[actuator]`` table (issue 43, item 2) on the symbolic side: parsed and refused in
one line naming the file and field, simulated exactly (lag states in the integrator, the dead
time inside the signal) with u recorded as the commands, and written to a dataset's
``meta["actuator"]`` by simulate and import."""

from __future__ import annotations

import numpy as np
import pytest

from softpinn.actuator import Actuator
from softpinn.symbolic.model._functions import functions
from softpinn.symbolic.recorded._import import import_recordings
from softpinn.symbolic.recorded._template import write_template
from softpinn.symbolic.simulation._datasets import make_dataset
from softpinn.symbolic.simulation._signals import Sinusoid, Step, signal_from_dict
from softpinn.symbolic.simulation._sim_config import SimulationConfig
from softpinn.symbolic.simulation._simulate import simulate
from softpinn.symbolic.spec._model_spec import SpecError
from softpinn.symbolic.spec._spec import spec_from_dict, spec_from_toml

K, C = 4.0, 0.5  # the test arm: q'' = u - K q - C q' (a unit mass on a spring)


def msd(actuator=None, inputs: int = 1):
    raw = {"name": "msd", "kind": "mass-spring-damper", "masses": [1.0] * inputs,
           "springs": [K] * inputs, "dampers": [C] * inputs, "actuation": "generalized"}
    if actuator is not None:
        raw["actuator"] = actuator
    return spec_from_dict(raw, source="arm.toml")


@pytest.fixture(scope="module")
def fns():
    return functions(msd())


def cvodes(duration=3.0, rate=100.0):
    return SimulationConfig(integrator="cvodes", duration=duration, rate=rate, rtol=1e-11,
                            atol=1e-11)


# --------------------------------------------------------------------------------------------
# The spec


def test_a_table_is_read_per_input_and_kept_out_of_the_physics():
    spec = msd({"time_constant": 0.2, "delay": [0.1, 0.15]}, inputs=2)
    assert spec.actuator_dynamics == Actuator((0.2,), (0.1, 0.15))
    assert spec.actuator_meta() == {"time_constant": [0.2, 0.2], "delay": [0.1, 0.15]}
    assert spec.to_dict()["actuator"] == {"time_constant": 0.2, "delay": [0.1, 0.15]}
    assert "actuator" not in spec.physics_dict()
    assert spec == msd(inputs=2)  # the same arm: the actuator is not compared
    plain = msd()
    assert plain.actuator_dynamics is None and plain.actuator_meta() is None
    assert "actuator" not in plain.to_dict()
    only_delay = msd({"delay": 0.3})
    assert only_delay.actuator_meta() == {"time_constant": [0.0], "delay": [0.3]}


@pytest.mark.parametrize("table,message", [
    ({"time_constant": [0.1, 0.2, 0.3]}, r"arm.toml: field 'actuator.time_constant': expected "
     r"one value for every input or 2 \(one per input\), got 3"),
    ({"delay": -0.1}, r"arm.toml: field 'actuator.delay': must not be negative, got -0.1"),
    ({"time_constant": [0.1, -1.0]}, r"field 'actuator.time_constant\[1\]': must not be "
     r"negative, got -1.0"),
    ({"time_constant": "0.2"}, r"field 'actuator.time_constant': expected a number, got '0.2'"),
    ({"time_constant": []}, r"field 'actuator.time_constant': expected at least one entry"),
    ({"delay": 200.0}, r"field 'actuator.delay': 200 s is longer than 60 s"),
    ({"lag": 0.2}, r"arm.toml: field 'actuator.lag': unknown key \(allowed: delay, "
     r"time_constant\)"),
])
def test_bad_tables_are_refused_naming_the_field(table, message):
    with pytest.raises(SpecError, match=message):
        msd(table, inputs=2)


def test_an_actuator_needs_inputs_and_a_table():
    with pytest.raises(SpecError, match=r"field 'actuator': the spec has no inputs"):
        spec_from_dict({"kind": "mass-spring-damper", "masses": [1.0], "springs": [1.0],
                        "actuator": {"delay": 0.1}}, source="arm.toml")
    with pytest.raises(SpecError, match=r"field 'actuator': expected a table"):
        msd(0.2)


def test_the_init_template_documents_the_table_and_its_example_loads():
    text, spec = write_template("arm", 1)
    assert spec.actuator == {}
    assert "# [actuator]" in text and "COMMANDS" in text and "MEASURED" in text
    uncommented = text.replace("\n# [actuator]\n", "\n[actuator]\n").replace(
        "# time_constant = 0.2", "time_constant = 0.2").replace("# delay = 0.1", "delay = 0.1")
    with_table = spec_from_toml(uncommented, source="arm.toml")
    assert with_table.actuator_meta() == {"time_constant": [0.2] * spec.m,
                                          "delay": [0.1] * spec.m}


# --------------------------------------------------------------------------------------------
# Simulation


@pytest.mark.parametrize("integrator", ["cvodes", "rk4"])
def test_the_identity_actuator_is_the_plain_simulation(fns, integrator):
    sig = [Sinusoid([1.0], [0.7], [0.3], [0.2])]
    cfg = SimulationConfig(integrator=integrator, duration=2.0, rate=50.0,
                           dt=1e-3 if integrator == "rk4" else None)
    x0 = np.array([[0.1, -0.2]])
    plain = simulate(fns, x0, sig, cfg)
    ident = simulate(fns, x0, sig, cfg, actuator=Actuator((0.0,), (0.0,)))
    for key in ("x", "u", "qdd", "p"):
        np.testing.assert_allclose(getattr(ident, key), getattr(plain, key), rtol=0, atol=1e-12)


def test_a_dead_time_moves_the_arm_only_after_the_delayed_step(fns):
    d = 0.25
    cmd = [Step([1.0], [[0.0], [1.0]])]
    x0 = np.zeros((1, 2))
    res = simulate(fns, x0, cmd, cvodes(), actuator=Actuator((0.0,), (d,)))
    late = simulate(fns, x0, [Step([1.0 + d], [[0.0], [1.0]])], cvodes())
    t = res.t
    assert np.all(res.x[0, t < 1.0 + d] == 0.0) and np.abs(res.x[0, t > 1.3, 0]).min() > 0
    np.testing.assert_allclose(res.x, late.x, rtol=0, atol=1e-7)
    np.testing.assert_allclose(res.qdd, late.qdd, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(res.u, cmd[0](t)[None])  # u: the commands, not delayed


@pytest.mark.parametrize("integrator", ["cvodes", "rk4"])
def test_a_lag_matches_the_actuator_applied_to_the_commands(fns, integrator):
    """The arm behind tau = 0.3 s after 0.2 s: q̈ from the integrator's lag state equals the
    arm's equation under Actuator.apply of the recorded commands (two approximations of one
    y(t): the integrator's exact one, apply's linear between samples)."""
    act = Actuator((0.3,), (0.2,))
    sigs = [Sinusoid([1.0], [0.7], [0.3], [0.2]), Sinusoid([0.5], [1.5], [-1.0], [-0.1])]
    x0 = np.array([[0.1, 0.0], [0.0, 0.3]])
    cfg = SimulationConfig(integrator=integrator, duration=3.0, rate=200.0,
                           dt=1e-3 if integrator == "rk4" else None, rtol=1e-10, atol=1e-10)
    res = simulate(fns, x0, sigs, cfg, actuator=act)
    plain = simulate(fns, x0, sigs, cfg)
    assert res.x.shape == plain.x.shape and res.qdd.shape == plain.qdd.shape
    np.testing.assert_array_equal(res.u, plain.u)
    for k in range(2):
        y = act.apply(res.t, res.u[k])[:, 0]
        q, qd = res.x[k, :, 0], res.x[k, :, 1]
        np.testing.assert_allclose(res.qdd[k, :, 0], y - K * q - C * qd, rtol=0, atol=2e-4)
    assert np.abs(res.x - plain.x).max() > 0.05  # the actuator matters here


def test_lag_only_on_some_inputs(tmp_path):
    """Two inputs: the first lagged (an extra state), the second only delayed (a chain of two
    masses: the arm's equation from the model's forward function)."""
    spec = msd({"time_constant": [0.2, 0.0], "delay": [0.0, 0.1]}, inputs=2)
    fns2 = functions(spec)
    sig = [Step([0.5], [[0.0, 0.0], [1.0, -1.0]])]
    res = simulate(fns2, np.zeros((1, 4)), sig, cvodes(duration=1.5),
                   actuator=spec.actuator_dynamics)
    t = res.t
    y = spec.actuator_dynamics.apply(t, res.u[0])  # a step: a ramp over one sample here
    q, qd = res.x[0, :, :2], res.x[0, :, 2:]
    want = np.array(fns2["forward"].map(len(t))(q.T, qd.T, y.T)).T
    np.testing.assert_allclose(res.qdd[0], want, rtol=0, atol=0.05)
    early = t < 0.6
    np.testing.assert_allclose(res.qdd[0, early, 1], want[early, 1], rtol=0, atol=1e-9)
    assert np.abs(res.x[0, t < 0.5]).max() == 0.0 and np.all(res.x[0, t > 0.52, 0] > 0)


# --------------------------------------------------------------------------------------------
# Datasets


def test_simulate_and_import_record_the_actuator(tmp_path):
    table = {"time_constant": [0.3], "delay": [0.1]}
    spec = msd(table)
    data = make_dataset(spec, trajectories=2, duration=1.0, rate=50.0, compile=False)
    assert data.meta["actuator"] == {"time_constant": [0.3], "delay": [0.1]}
    assert data.meta["spec"]["actuator"] == table
    first = data.traj == 0  # u: the commands
    command = signal_from_dict(data.meta["signals"][0])
    np.testing.assert_allclose(data.u[first], command(data.t[first]), rtol=0, atol=1e-12)
    plain = make_dataset(msd(), trajectories=2, duration=1.0, rate=50.0, compile=False)
    assert "actuator" not in plain.meta
    np.testing.assert_array_equal(data.u, plain.u)

    toml = tmp_path / "arm.toml"
    toml.write_text('name = "arm"\nkind = "mass-spring-damper"\nmasses = [1.0, 1.0]\n'
                    'springs = [4.0, 4.0]\nactuation = "generalized"\n\n[actuator]\n'
                    'time_constant = 0.3\ndelay = [0.1, 0.2]\n')
    t = np.arange(0.0, 1.0, 0.02)
    csv = tmp_path / "rec.csv"
    np.savetxt(csv, np.stack([t, np.sin(t), np.cos(t), 0.1 * np.sin(t), 0.1 * np.cos(t)], 1),
               delimiter=",", header="t,u0,u1,q0,q1", comments="")
    imported = import_recordings([csv], toml).data
    assert imported.meta["actuator"] == {"time_constant": [0.3, 0.3], "delay": [0.1, 0.2]}
    toml.write_text(toml.read_text().split("[actuator]")[0])
    assert "actuator" not in import_recordings([csv], toml).data.meta


def test_an_integrator_without_the_actuator_is_refused():
    spec = msd({"time_constant": 0.3})

    def plain_simulator(x0, signals, config, progress=None):
        raise AssertionError("not reached")

    with pytest.raises(Exception, match=r"arm.toml: \[actuator\]: this integrator does not "
                       r"model the actuator"):
        make_dataset(spec, trajectories=1, duration=0.5, rate=50.0,
                     simulator=plain_simulator)
