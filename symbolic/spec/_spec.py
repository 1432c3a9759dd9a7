"""Model specs: the TOML description of a robot (``docs/spec.md``).

A spec describes the physics of one of four kinds of system:

* ``spatial-pcc``: a chain of spatial piecewise-constant-curvature segments (Appendix A,
  eqs. 11-24), three coordinates per segment, in the ``delta`` or ``phi-theta`` parameterization;
* ``planar-pcc``: a chain of planar thin-rod PCC segments (eqs. 27-28), q_i = [theta_i, dL_i];
* ``mass-spring-damper``: a chain of masses (eq. 25);
* ``double-pendulum``: the point-mass double pendulum (eq. 26).

It may also carry a ``[data]`` table (how to generate data for it; validated by
:mod:`symbolic.simulation._datasets`), a ``[training]`` table (the task recipe, validated here
when the spec loads: :mod:`symbolic.spec._recipe`) and a ``[sensor]`` table (a simulated sensor
that records the arm, validated here: :mod:`symbolic.spec._sensor`) and an ``[actuator]`` table
(the lag and dead time between the recorded commands u and the arm, per input:
:class:`softpinn.actuator.Actuator`).

``load_spec`` accepts a preset name (``task1`` ... ``task5``) or a path to a ``.toml`` file, and
refuses a bad spec with a :class:`SpecError` naming the file and the field. This module reads and
validates; the value it returns, :class:`ModelSpec`, is :mod:`symbolic.spec._model_spec`'s.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from collections.abc import Mapping, Sequence
from importlib import resources
from pathlib import Path
from typing import Any

from softpinn.actuator import MAX_SECONDS, Actuator
from softpinn.symbolic.spec._model_spec import (
    KINDS,
    MAX_COORDINATES,
    PARAMETERIZATIONS,
    ModelSpec,
    Segment,
    SpecError,
)
from softpinn.symbolic.spec._recipe import RecipeError, parse_recipe
from softpinn.symbolic.spec._sensor import SensorError, parse_sensor

# --------------------------------------------------------------------------------------------
# Loading


def list_presets() -> list[str]:
    """Names of the presets shipped with the package (``task1`` ... ``task5``)."""
    files = resources.files("softpinn.symbolic.presets").iterdir()
    return sorted(f.name[:-5] for f in files if f.name.endswith(".toml"))


def preset_path(name: str) -> Path:
    return Path(str(resources.files("softpinn.symbolic.presets").joinpath(f"{name}.toml")))


def load_spec(model: str | Path | ModelSpec) -> ModelSpec:
    """Load a preset by name or a spec file by path; a :class:`ModelSpec` passes through."""
    if isinstance(model, ModelSpec):
        return model
    text = str(model)
    presets = list_presets()
    if text in presets:
        path = preset_path(text)
        return spec_from_toml(path.read_text(encoding="utf-8"), source=f"preset:{text}")
    path = Path(text)
    if path.suffix != ".toml" and not path.exists():
        toml = path.with_name(path.name + ".toml")
        hint = f"; did you mean {toml}?" if toml.is_file() else ""
        raise SpecError(
            f"unknown model {text!r}: not a preset ({', '.join(presets)}) and no such file{hint}"
        )
    if path.is_dir():
        raise SpecError(f"{text}: is a folder, not a spec file")
    if not path.is_file():
        raise SpecError(f"{text}: no such spec file")
    if path.suffix == ".npz" or _starts_with(path, b"PK\x03\x04"):
        raise SpecError(f"{text}: is a data set, not a model; MODEL is a preset name or a .toml "
                        "spec file")
    return spec_from_toml(_read_text(path), source=str(path))


def _starts_with(path: Path, magic: bytes) -> bool:
    try:
        with path.open("rb") as f:
            return f.read(len(magic)) == magic
    except OSError:
        return False


#: a spec file larger than this is refused before it is read (specs are a few kB)
MAX_SPEC_BYTES = 1 << 20


def _read_text(path: Path) -> str:
    """The text of a spec file; one-line errors for an unreadable, huge or non-UTF-8 file."""
    try:
        size = path.stat().st_size
        if size > MAX_SPEC_BYTES:
            raise SpecError(f"{path}: {size / 1e6:.1f} MB is too large for a spec file "
                            f"(at most {MAX_SPEC_BYTES // 1024} kB)")
        raw = path.read_bytes()
    except OSError as exc:
        raise SpecError(f"{path}: cannot read ({exc.strerror or type(exc).__name__})") from None
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise SpecError(
            f"{path}: not a UTF-8 text file (byte 0x{raw[exc.start]:02x} on line {line}); "
            "save it as UTF-8"
        ) from None


def spec_from_toml(text: str, *, source: str = "<string>") -> ModelSpec:
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(f"{source}: not valid TOML: {exc}") from None
    return spec_from_dict(raw, source=source)


def spec_from_dict(raw: Mapping[str, Any], *, source: str = "<dict>") -> ModelSpec:
    """Validate a parsed spec; every error names ``source`` and the field."""
    v = _Validator(source)
    raw = dict(raw)
    kind = v.choice(raw, "kind", KINDS)
    name = v.string(raw, "name", default=Path(source).stem if source.endswith(".toml") else kind)
    description = v.string(raw, "description", default="")
    data = v.table(raw, "data")
    training = v.table(raw, "training")
    sensor = v.table(raw, "sensor")
    actuator = v.table(raw, "actuator")
    common = dict(
        name=name, kind=kind, source=source, description=description, data=data, training=training,
        sensor=sensor, actuator=actuator,
    )

    if kind == "spatial-pcc":
        allowed = {"name", "kind", "description", "data", "training", "sensor", "actuator",
                   "parameterization",
                   "gravity", "actuators_per_segment", "actuation", "segment"}
        v.no_unknown(raw, allowed, "")
        param = v.choice(raw, "parameterization", PARAMETERIZATIONS, default="delta")
        gravity = v.floats(raw, "gravity", 3, default=(0.0, 0.0, -9.81))
        adof = v.integer(raw, "actuators_per_segment", default=4, minimum=1)
        segments = v.segments(raw, dims=3, spatial=True)
        spec = ModelSpec(parameterization=param, gravity=gravity, actuators_per_segment=adof,
                         segments=segments, actuation="generalized", **common)
        actuation = v.actuation(raw, spec.n, ("generalized", "tip-wrench", "tendon", "none"))
    elif kind == "planar-pcc":
        allowed = {"name", "kind", "description", "data", "training", "sensor", "actuator",
                   "gravity", "actuation",
                   "segment"}
        v.no_unknown(raw, allowed, "")
        gravity = v.floats(raw, "gravity", 2, default=(0.0, 9.81))
        segments = v.segments(raw, dims=2, spatial=False)
        spec = ModelSpec(gravity=gravity, segments=segments, actuation="generalized", **common)
        actuation = v.actuation(raw, spec.n, ("generalized", "none"))
    elif kind == "mass-spring-damper":
        allowed = {"name", "kind", "description", "data", "training", "sensor", "actuator",
                   "masses", "springs",
                   "dampers", "actuation"}
        v.no_unknown(raw, allowed, "")
        masses = v.floats(raw, "masses", None, positive=True)
        springs = v.floats(raw, "springs", len(masses), nonnegative=True)
        dampers = v.floats(raw, "dampers", len(masses), nonnegative=True,
                           default=(0.0,) * len(masses))
        spec = ModelSpec(masses=masses, springs=springs, dampers=dampers, actuation="none",
                         **common)
        actuation = v.actuation(raw, spec.n, ("generalized", "none"), default="none")
    else:  # double-pendulum
        allowed = {"name", "kind", "description", "data", "training", "sensor", "actuator",
                   "masses", "lengths", "g",
                   "damping", "actuation"}
        v.no_unknown(raw, allowed, "")
        masses = v.floats(raw, "masses", 2, positive=True)
        lengths = v.floats(raw, "lengths", 2, positive=True)
        g = v.number(raw, "g", default=9.8)
        damping = v.floats(raw, "damping", 2, nonnegative=True, default=(0.0, 0.0))
        spec = ModelSpec(masses=masses, lengths=lengths, g=g, joint_damping=damping,
                         actuation="none", **common)
        actuation = v.actuation(raw, spec.n, ("generalized", "none"), default="none")
    spec = dataclasses.replace(spec, actuation=actuation)
    if spec.n > MAX_COORDINATES:
        field_name = "segment" if kind in ("spatial-pcc", "planar-pcc") else "masses"
        count = (f"{len(spec.segments)} segments" if spec.segments
                 else f"{len(spec.masses)} masses")
        per = {"spatial-pcc": 3, "planar-pcc": 2}.get(kind, 1)
        v.fail(field_name, f"{count} give {spec.n} coordinates, more than the {MAX_COORDINATES} "
               f"supported (at most {MAX_COORDINATES // per} here): deriving and compiling the "
               "equations grow about as n^2.5 in time and memory (8 spatial segments: 9 s and "
               "0.15 GB to derive, 31 s and 0.8 GB to compile; 40 ran for minutes past 3 GB)")
    v.actuator(actuator, spec.m)
    try:
        parse_recipe(training, spec.n)
    except RecipeError as e:
        v.fail(e.where, e.message)
    try:
        parse_sensor(sensor, kind=kind, segments=len(spec.segments))
    except SensorError as e:
        v.fail(e.where, e.message)
    return spec


class _Validator:
    def __init__(self, source: str):
        self.source = source

    def fail(self, where: str, message: str):
        raise SpecError(f"{self.source}: field '{where}': {message}")

    def no_unknown(self, table: Mapping[str, Any], allowed: set[str], prefix: str):
        unknown = sorted(set(table) - allowed)
        if unknown:
            where = f"{prefix}{unknown[0]}"
            self.fail(where, f"unknown key (allowed: {', '.join(sorted(allowed))})")

    def string(self, raw, key, default=None):
        if key not in raw:
            if default is None:
                self.fail(key, "missing")
            return default
        if not isinstance(raw[key], str):
            self.fail(key, f"expected a string, got {raw[key]!r}")
        return raw[key]

    def choice(self, raw, key, options, default=None):
        value = self.string(raw, key, default)
        if value not in options:
            self.fail(key, f"expected one of {', '.join(options)}, got {value!r}")
        return value

    def table(self, raw, key):
        value = raw.get(key, {})
        if not isinstance(value, Mapping):
            self.fail(key, "expected a table")
        return dict(value)

    def number(self, raw, key, default=None, where=None, positive=False, nonnegative=False):
        where = where or key
        if key not in raw:
            if default is None:
                self.fail(where, "missing")
            return float(default)
        value = raw[key]
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.fail(where, f"expected a number, got {value!r}")
        value = float(value)
        if not math.isfinite(value):
            self.fail(where, f"must be finite, got {value}")
        if positive and value <= 0:
            self.fail(where, f"must be positive, got {value}")
        if nonnegative and value < 0:
            self.fail(where, f"must not be negative, got {value}")
        return value

    def integer(self, raw, key, default, minimum):
        value = raw.get(key, default)
        if isinstance(value, bool) or not isinstance(value, int):
            self.fail(key, f"expected an integer, got {value!r}")
        if value < minimum:
            self.fail(key, f"must be at least {minimum}, got {value}")
        return value

    def floats(self, raw, key, length, default=None, where=None, positive=False,
               nonnegative=False):
        where = where or key
        if key not in raw:
            if default is None:
                self.fail(where, "missing")
            return tuple(float(x) for x in default)
        value = raw[key]
        if not isinstance(value, Sequence) or isinstance(value, str):
            self.fail(where, f"expected a list of numbers, got {value!r}")
        if length is not None and len(value) != length:
            self.fail(where, f"expected {length} entries, got {len(value)}")
        if length is None and len(value) == 0:
            self.fail(where, "expected at least one entry")
        out = []
        for i, x in enumerate(value):
            out.append(self.number({key: x}, key, where=f"{where}[{i}]", positive=positive,
                                   nonnegative=nonnegative))
        return tuple(out)

    def segments(self, raw, dims: int, spatial: bool) -> tuple[Segment, ...]:
        segs = raw.get("segment")
        if segs is None:
            self.fail("segment", "missing: give at least one [[segment]] table")
        if not isinstance(segs, list) or not segs or not all(isinstance(s, Mapping) for s in segs):
            self.fail("segment", "expected one or more [[segment]] tables")
        allowed = {"length", "mass", "stiffness", "damping"}
        if spatial:
            allowed |= {"radius", "actuator_radius"}
        out = []
        for i, s in enumerate(segs):
            p = f"segment[{i}]."
            self.no_unknown(s, allowed, p)
            length = self.number(s, "length", where=p + "length", positive=True)
            mass = self.number(s, "mass", where=p + "mass", positive=True)
            radius = self.number(s, "radius", default=0.0, where=p + "radius", nonnegative=True)
            d = self.number(s, "actuator_radius", default=1.0, where=p + "actuator_radius",
                            positive=True)
            k = self.floats(s, "stiffness", dims, where=p + "stiffness", nonnegative=True)
            c = self.floats(s, "damping", dims, where=p + "damping", nonnegative=True,
                            default=(0.0,) * dims)
            out.append(Segment(length=length, mass=mass, radius=radius, actuator_radius=d,
                               stiffness=k, damping=c))
        return tuple(out)

    def actuator(self, table: Mapping[str, Any], m: int) -> None:
        """The ``[actuator]`` table: ``time_constant`` and ``delay`` [s], each one number for
        every input or a list with one per input."""
        if not table:
            return
        self.no_unknown(table, {"time_constant", "delay"}, "actuator.")
        if m == 0:
            self.fail("actuator", "the spec has no inputs (actuation = \"none\"); remove the "
                      "table or give the arm inputs")
        values = {}
        for key in ("time_constant", "delay"):
            if key not in table:
                continue
            where = f"actuator.{key}"
            raw = table[key]
            if isinstance(raw, Sequence) and not isinstance(raw, str):
                vals = self.floats(table, key, None, where=where, nonnegative=True)
                if len(vals) not in (1, m):
                    self.fail(where, f"expected one value for every input or {m} (one per "
                              f"input), got {len(vals)}")
            else:
                vals = (self.number(table, key, where=where, nonnegative=True),)
            too_long = [x for x in vals if x > MAX_SECONDS]
            if too_long:
                self.fail(where, f"{too_long[0]:g} s is longer than {MAX_SECONDS:g} s: give "
                          "seconds (not milliseconds)")
            values[key] = list(vals)
        Actuator.from_dict(values, m)  # the same rules: refuses nothing the checks above pass

    def actuation(self, raw, n, named, default="generalized"):
        value = raw.get("actuation", default)
        if isinstance(value, str):
            if value not in named:
                self.fail("actuation", f"expected one of {', '.join(named)} or a constant "
                          f"matrix, got {value!r}")
            return value
        if (not isinstance(value, list) or len(value) != n
                or not all(isinstance(r, list) for r in value)):
            self.fail("actuation", f"a constant matrix must be a list of {n} rows (one per "
                      "coordinate)")
        widths = {len(r) for r in value}
        if len(widths) != 1 or 0 in widths:
            self.fail("actuation", "every row of the matrix must have the same, non-zero length")
        rows = []
        for i, r in enumerate(value):
            rows.append(self.floats({"a": r}, "a", None, where=f"actuation[{i}]"))
        return tuple(rows)
