"""Model specs: presets load, and every bad input is refused naming the file and the field."""

from __future__ import annotations

import pytest

from softpinn.errors import UserError
from softpinn.symbolic.spec._spec import (
    ModelSpec,
    SpecError,
    list_presets,
    load_spec,
    spec_from_toml,
)

GOOD = """
name = "arm"
kind = "spatial-pcc"
parameterization = "delta"
gravity = [0.0, 0.0, -9.81]
actuators_per_segment = 4
actuation = "generalized"

[[segment]]
length = 0.2
mass = 0.1
radius = 0.02
actuator_radius = 0.015
stiffness = [1.0, 1.0, 50.0]
damping = [0.1, 0.1, 0.1]
"""


def write(tmp_path, text, name="spec.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_presets_load():
    assert list_presets() == ["experiment", "task1", "task2", "task3", "task4", "task5"]
    sizes = {name: (load_spec(name).n, load_spec(name).m) for name in list_presets()}
    assert sizes == {"experiment": (3, 4), "task1": (2, 0), "task2": (2, 0), "task3": (2, 1),
                     "task4": (3, 3), "task5": (6, 6)}
    spec = load_spec("task4")
    assert load_spec(spec) is spec
    assert spec.segments[0].mass == 0.3 and spec.gravity == (0.0, 0.0, 9.81)
    assert hash(spec) == hash(load_spec("task4"))  # usable as a cache key
    assert spec.data["rate"] == 200.0 and "lagrangian" in spec.training


def test_good_file(tmp_path):
    spec = load_spec(write(tmp_path, GOOD))
    assert isinstance(spec, ModelSpec)
    assert spec.n == 3 and spec.m == 3
    assert spec.segments[0].stiffness == (1.0, 1.0, 50.0)
    assert spec.coordinate_names == ("dx1", "dy1", "dL1")


BAD = [
    # (replace this, with this, message pattern)
    ('name = "arm"', 'name = "arm"\ncolour = "red"', r"field 'colour': unknown key"),
    ("length = 0.2", "length = 0.2\nwidth = 1.0", r"field 'segment\[0\].width': unknown key"),
    ("stiffness = [1.0, 1.0, 50.0]", "stiffness = [1.0, 50.0]",
     r"field 'segment\[0\].stiffness': expected 3 entries, got 2"),
    ("gravity = [0.0, 0.0, -9.81]", "gravity = [0.0, -9.81]",
     r"field 'gravity': expected 3 entries, got 2"),
    ("mass = 0.1", "mass = 0.0", r"field 'segment\[0\].mass': must be positive, got 0.0"),
    ("mass = 0.1", "mass = -1.0", r"field 'segment\[0\].mass': must be positive"),
    ("length = 0.2", "length = 0", r"field 'segment\[0\].length': must be positive"),
    ("radius = 0.02", "radius = -0.02",
     r"field 'segment\[0\].radius': must not be negative, got -0.02"),
    ("stiffness = [1.0, 1.0, 50.0]", "stiffness = [1.0, -1.0, 50.0]",
     r"field 'segment\[0\].stiffness\[1\]': must not be negative"),
    ("damping = [0.1, 0.1, 0.1]", "damping = [0.1, 0.1, -0.1]",
     r"field 'segment\[0\].damping\[2\]': must not be negative"),
    ("mass = 0.1", 'mass = "heavy"', r"field 'segment\[0\].mass': expected a number"),
    ('kind = "spatial-pcc"', 'kind = "tentacle"', r"field 'kind': expected one of"),
    ('parameterization = "delta"', 'parameterization = "euler"',
     r"field 'parameterization': expected one of delta, phi-theta"),
    ('actuation = "generalized"', 'actuation = "magic"', r"field 'actuation': expected one of"),
    ('actuation = "generalized"', "actuation = [[1.0, 0.0], [0.0, 1.0]]",
     r"field 'actuation': a constant matrix must be a list of 3 rows"),
    ('actuation = "generalized"', "actuation = [[1.0], [0.0, 1.0], [1.0]]",
     r"field 'actuation': every row of the matrix must have the same"),
    ('actuation = "generalized"', 'actuation = [[1.0], ["x"], [1.0]]',
     r"field 'actuation\[1\]\[0\]': expected a number"),
    ("actuators_per_segment = 4", "actuators_per_segment = 0",
     r"field 'actuators_per_segment': must be at least 1"),
]


@pytest.mark.parametrize("old, new, message", BAD)
def test_bad_spec_names_file_and_field(tmp_path, old, new, message):
    assert old in GOOD
    path = write(tmp_path, GOOD.replace(old, new, 1))
    with pytest.raises(SpecError, match=message) as info:
        load_spec(path)
    assert str(path) in str(info.value)
    assert "\n" not in str(info.value)


def test_missing_segments(tmp_path):
    text = GOOD.split("[[segment]]")[0]
    with pytest.raises(SpecError, match="field 'segment': missing"):
        load_spec(write(tmp_path, text))


def test_other_kinds_refuse_bad_values(tmp_path):
    msd = 'kind = "mass-spring-damper"\nmasses = [1.0, 0.0]\nsprings = [1.0, 1.0]\n'
    with pytest.raises(SpecError, match=r"field 'masses\[1\]': must be positive"):
        load_spec(write(tmp_path, msd))
    msd = 'kind = "mass-spring-damper"\nmasses = [1.0, 2.0]\nsprings = [1.0]\n'
    with pytest.raises(SpecError, match=r"field 'springs': expected 2 entries, got 1"):
        load_spec(write(tmp_path, msd))
    pend = 'kind = "double-pendulum"\nmasses = [1.0, 1.0]\nlengths = [1.0, -1.0]\n'
    with pytest.raises(SpecError, match=r"field 'lengths\[1\]': must be positive"):
        load_spec(write(tmp_path, pend))
    planar = ('kind = "planar-pcc"\nactuation = "tendon"\n[[segment]]\nlength = 1.0\n'
              "mass = 1.0\nstiffness = [1.0, 1.0]\n")
    with pytest.raises(SpecError, match="field 'actuation'"):
        load_spec(write(tmp_path, planar))
    planar = planar.replace('actuation = "tendon"', "")
    planar = planar.replace("mass = 1.0", "mass = 1.0\nradius = 1.0")
    with pytest.raises(SpecError, match=r"field 'segment\[0\].radius': unknown key"):
        load_spec(write(tmp_path, planar))


def test_unknown_preset_and_missing_file(tmp_path):
    with pytest.raises(UserError, match="unknown model 'task9': not a preset"):
        load_spec("task9")
    with pytest.raises(SpecError, match="no such spec file"):
        load_spec(tmp_path / "absent.toml")
    # a data set given as the model
    import numpy as np

    np.savez(tmp_path / "d.npz", t=np.zeros(2))
    with pytest.raises(UserError, match=r"d.npz: is a data set, not a model; MODEL is a preset"):
        load_spec(tmp_path / "d.npz")
    # a spec file named without its .toml: the message points at it
    (tmp_path / "arm2.toml").write_text("name = 'arm2'")
    with pytest.raises(UserError, match=r"no such file; did you mean .*arm2\.toml\?"):
        load_spec(tmp_path / "arm2")


def test_not_toml(tmp_path):
    path = write(tmp_path, '{"kind": "spatial-pcc"}', name="spec.json")
    with pytest.raises(SpecError, match=r"spec.json: not valid TOML"):
        load_spec(path)
    with pytest.raises(SpecError, match=r"<string>: not valid TOML"):
        spec_from_toml("kind = ")
