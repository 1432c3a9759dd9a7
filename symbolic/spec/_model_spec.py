"""A validated model spec as a value: :class:`ModelSpec` (one of four kinds of system; read from
TOML and validated by :mod:`symbolic.spec._spec`), its PCC segments (:class:`Segment`), the
kinds, parameterizations and named actuations a spec may name, and :class:`SpecError`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from softpinn.actuator import Actuator
from softpinn.errors import UserError
from softpinn.symbolic.spec._recipe import Recipe, parse_recipe

KINDS = ("spatial-pcc", "planar-pcc", "mass-spring-damper", "double-pendulum")
PARAMETERIZATIONS = ("delta", "phi-theta")
NAMED_ACTUATIONS = ("generalized", "tip-wrench", "tendon", "none")

#: The most generalized coordinates a spec may have. Deriving the functions and their C grows
#: about as n^2.5 in time and memory, and compiling it faster still (measured on one core, spatial
#: PCC, derive + C generation / gcc -O1): 4 segments (n = 12) 1.4 s, 72 MB / 5.5 s, 0.3 GB;
#: 8 segments (n = 24) 9 s, 150 MB, 9 MB of C / 31 s, 0.8 GB; 12 segments (n = 36) 24 s,
#: 320 MB, 27 MB of C, minutes to compile; planar, 24 segments (n = 48): 60 s, 1.1 GB, 79 MB of
#: C; a chain of 100 masses: 47 s, 1.2 GB, 63 MB of C. 40 spatial segments ran for minutes past
#: 3 GB. n = 24 keeps a derive under a minute and a compile within the default timeout.
MAX_COORDINATES = 24


class SpecError(UserError):
    """A model spec that cannot be used; the message names the file and the field."""


@dataclass(frozen=True)
class Segment:
    """One PCC segment. Units: metres, kilograms, and the units of the coordinates."""

    length: float
    mass: float
    radius: float = 0.0
    actuator_radius: float = 1.0
    stiffness: tuple[float, ...] = ()
    damping: tuple[float, ...] = ()


@dataclass(frozen=True)
class ModelSpec:
    """A validated model spec (immutable; pass it around as a value).

    ``actuation`` is one of :data:`NAMED_ACTUATIONS` or a constant matrix (tuple of rows,
    n x m). For ``mass-spring-damper`` the chain couples mass i to mass i+1 through
    ``springs[i]`` and ``dampers[i]``, and the last mass to the ground through the last entries
    (eq. 25: springs [k1, k2], dampers [b, 0]). For ``double-pendulum`` angles are measured from
    the downward vertical and ``g`` is the scalar gravitational acceleration.
    """

    name: str
    kind: str
    source: str
    parameterization: str | None = None
    gravity: tuple[float, ...] = ()
    actuators_per_segment: int = 4
    actuation: str | tuple[tuple[float, ...], ...] = "generalized"
    segments: tuple[Segment, ...] = ()
    masses: tuple[float, ...] = ()
    springs: tuple[float, ...] = ()
    dampers: tuple[float, ...] = ()
    lengths: tuple[float, ...] = ()
    g: float = 9.8
    joint_damping: tuple[float, ...] = ()
    description: str = ""
    data: Mapping[str, Any] = field(default_factory=dict, compare=False, hash=False)
    training: Mapping[str, Any] = field(default_factory=dict, compare=False, hash=False)
    sensor: Mapping[str, Any] = field(default_factory=dict, compare=False, hash=False)
    actuator: Mapping[str, Any] = field(default_factory=dict, compare=False, hash=False)

    @property
    def n(self) -> int:
        """Number of generalized coordinates."""
        if self.kind == "spatial-pcc":
            return 3 * len(self.segments)
        if self.kind == "planar-pcc":
            return 2 * len(self.segments)
        if self.kind == "mass-spring-damper":
            return len(self.masses)
        return 2

    @property
    def m(self) -> int:
        """Number of inputs."""
        a = self.actuation
        if not isinstance(a, str):
            return len(a[0])
        if a == "none":
            return 0
        if a == "generalized":
            return self.n
        if a == "tip-wrench":
            return 3 * len(self.segments)
        if a == "tendon":
            return self.actuators_per_segment * len(self.segments)
        raise AssertionError(a)

    @property
    def coordinate_names(self) -> tuple[str, ...]:
        if self.kind == "spatial-pcc":
            delta = self.parameterization == "delta"
            names = ("dx", "dy", "dL") if delta else ("phi", "theta", "dL")
            return tuple(f"{c}{i + 1}" for i in range(len(self.segments)) for c in names)
        if self.kind == "planar-pcc":
            return tuple(f"{c}{i + 1}" for i in range(len(self.segments)) for c in ("theta", "dL"))
        return tuple(f"q{i + 1}" for i in range(self.n))

    @property
    def recipe(self) -> Recipe:
        """The ``[training]`` table as a typed :class:`symbolic.spec._recipe.Recipe` (validated when
        the spec was loaded)."""
        return parse_recipe(self.training, self.n)

    @property
    def actuator_dynamics(self) -> Actuator | None:
        """The ``[actuator]`` table (a lag and a dead time per input between the commands u
        and the arm) as an :class:`softpinn.actuator.Actuator`; None without one."""
        return Actuator.from_dict(self.actuator, self.m) if self.actuator else None

    def actuator_meta(self) -> dict[str, list[float]] | None:
        """A dataset's ``meta["actuator"]``: ``time_constant`` and ``delay``, one per input
        (None without an ``[actuator]`` table)."""
        act = self.actuator_dynamics
        if act is None:
            return None
        tau, delay = act.per_input(self.m)
        return {"time_constant": tau.tolist(), "delay": delay.tolist()}

    def physics_dict(self) -> dict[str, Any]:
        """The physical part of the spec as plain JSON-able data (what the EOM depend on)."""
        out: dict[str, Any] = {"name": self.name, "kind": self.kind}
        for f in dataclasses.fields(self):
            if f.name in ("name", "kind", "source", "data", "training", "sensor", "actuator",
                          "description"):
                continue
            value = getattr(self, f.name)
            if f.name == "segments":
                value = [dataclasses.asdict(s) for s in value]
            if value in ((), None):
                continue
            out[f.name] = _plain(value)
        return out

    def to_dict(self) -> dict[str, Any]:
        """Everything in the spec as plain JSON-able data (recorded in dataset ``meta``)."""
        out = self.physics_dict()
        out["source"] = self.source
        if self.description:
            out["description"] = self.description
        if self.data:
            out["data"] = _plain(self.data)
        if self.training:
            out["training"] = _plain(self.training)
        if self.sensor:
            out["sensor"] = _plain(self.sensor)
        if self.actuator:
            out["actuator"] = _plain(self.actuator)
        return out


def _plain(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value
