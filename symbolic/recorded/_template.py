"""``softpinn init``: a commented template spec for an arm of one's own (``docs/import.md``).

:func:`spec_template` writes a PCC arm of K segments, spatial (``delta``, tendon-driven by
default, as the paper's platform) or planar, standing up or hanging. The numbers are a plausible
small soft arm (0.2 m, 0.1 kg segments; bending stiffness about 1 N m/rad per segment it
carries, enough to stand up) for the user to replace by their own. The ``[data]`` table is left
commented out: without it ``softpinn simulate`` takes defaults from the physics
(:mod:`symbolic.simulation._defaults`), which follow edits of the physics; the template shows their
values for the physics it was written with.
"""

from __future__ import annotations

import re

from softpinn.errors import UserError
from softpinn.symbolic.simulation._defaults import physics_data_table
from softpinn.symbolic.spec._model_spec import ModelSpec
from softpinn.symbolic.spec._spec import spec_from_toml

SPATIAL_ACTUATIONS = ("tendon", "generalized", "tip-wrench", "none")
PLANAR_ACTUATIONS = ("generalized", "none")
LENGTH, MASS, RADIUS, TENDON_RADIUS = 0.2, 0.1, 0.03, 0.02
BEND_K = 1.2  # N m / rad per segment carried (the base carries all K)
BEND_C = 0.012  # N m s / rad per segment carried
STRETCH_K, STRETCH_C = 500.0, 2.0  # N/m, N s/m


def _num(x: float) -> str:
    return repr(float(f"{x:.6g}"))


def _line(code: str, comment: str) -> str:
    """``code`` with its comment aligned at column 35."""
    return f"{code:<33} # {comment}"


def spec_template(name: str, segments: int, *, planar: bool = False, hanging: bool = False,
                  actuation: str | None = None, file: str | None = None) -> str:
    """The TOML text of a commented template spec (see the module docstring); ``file`` is the
    name its comments use for it (default ``NAME.toml``)."""
    if not re.fullmatch(r"[A-Za-z0-9_.-]+", name or ""):
        raise _error(f"name: use letters, digits, '_', '-' or '.', got {name!r}")
    if isinstance(segments, bool) or not isinstance(segments, int) or segments < 1:
        raise _error(f"segments: must be a whole number >= 1, got {segments!r}")
    options = PLANAR_ACTUATIONS if planar else SPATIAL_ACTUATIONS
    actuation = actuation or options[0]
    if actuation not in options:
        raise _error(f"actuation: a {'planar' if planar else 'spatial'} arm takes one of "
                     f"{', '.join(options)}, got {actuation!r}")
    kind = "planar-pcc" if planar else "spatial-pcc"
    file = file or f"{name}.toml"
    out = [
        f"# {name}: a {segments}-segment {'planar' if planar else 'spatial'} PCC arm, written by "
        "`softpinn init` as a starting point.",
        "# Replace the numbers by your arm's; every field is described in docs/spec.md.",
        f"#   softpinn matrices {file} --q {' '.join(['0'] * (2 if planar else 3) * segments)}"
        "   # M, G, D, A at the straight arm",
        f"#   softpinn simulate {file} --out {name}.npz   # simulated data",
        f"#   softpinn import REC.csv --model {file} --out {name}.npz   # or your recordings "
        "(docs/import.md)",
        f"#   softpinn train {name}.npz --model lagrangian --out runs/{name}-lnn",
        "",
        f'name = "{name}"',
        f'description = "{"Planar" if planar else "Spatial"} PCC arm, {segments} segment'
        f'{"s" if segments > 1 else ""}, {"hanging" if hanging else "standing up"}."',
        f'kind = "{kind}"',
    ]
    if planar:
        g = "9.81" if hanging else "-9.81"
        out += [
            _line(f"gravity = [0.0, {g}]", "[m/s^2] in the base frame; the straight arm points "
                  f"along +y, so this one {'hangs' if hanging else 'stands up'} (flip the sign "
                  "for the other way)"),
            _line(f'actuation = "{actuation}"', '"generalized": u = [torque on theta, force on '
                  'dL] per segment | "none" | a matrix [[...], ...] (n rows)'),
        ]
    else:
        g = "9.81" if hanging else "-9.81"
        out += [
            _line('parameterization = "delta"', "q per segment [dx, dy, dL]: (dx, dy) = d theta "
                  "(cos phi, sin phi) [m], dL the stretch [m]; smooth at the straight arm"),
            _line(f"gravity = [0.0, 0.0, {g}]", "[m/s^2] in the base frame; the straight arm "
                  f"points along +z, so this one {'hangs' if hanging else 'stands up'} (flip the "
                  "sign for the other way)"),
            _line("actuators_per_segment = 4", "tendons per segment (a_dof), evenly around the "
                  "centre line"),
            _line(f'actuation = "{actuation}"', '"tendon": u = tendon tensions [N] (a negative '
                  'one pulls the opposite tendon), a_dof per segment | "generalized": u = forces '
                  'on q | "tip-wrench": tip torques and tangent force | "none"'),
        ]
    for i in range(segments):
        carried = segments - i
        kb = BEND_K * carried
        cb = BEND_C * carried
        where = " (base)" if i == 0 else (" (tip)" if i == segments - 1 else "")
        first = ("; one table per segment, base to tip (errors name them so)"
                 if i == 0 else "")
        out += ["", _line("[[segment]]", f"segment[{i}]{where}{first}")]
        out += [
            _line(f"length = {_num(LENGTH)}", "rest length L0 [m]"),
            _line(f"mass = {_num(MASS)}", "[kg]"),
        ]
        if planar:
            out += [
                _line(f"stiffness = [{_num(kb)}, {_num(STRETCH_K)}]",
                      f"[theta: N m/rad, dL: N/m]; it carries {carried} segment(s)"),
                _line(f"damping = [{_num(cb)}, {_num(STRETCH_C)}]", "[N m s/rad, N s/m]"),
            ]
        else:
            d2 = TENDON_RADIUS**2
            out += [
                _line(f"radius = {_num(RADIUS)}", "plate radius [m] (rotational inertia of the "
                      "plates); 0 for none"),
                _line(f"actuator_radius = {_num(TENDON_RADIUS)}", "d: the tendons' distance from "
                      "the centre line [m]"),
                _line(f"stiffness = [{_num(kb / d2)}, {_num(kb / d2)}, {_num(STRETCH_K)}]",
                      f"[dx, dy, dL] N/m: bending k d^2 = {_num(kb)} N m/rad, as it carries "
                      f"{carried} segment(s)"),
                _line(f"damping = [{_num(cb / d2)}, {_num(cb / d2)}, {_num(STRETCH_C)}]",
                      "[dx, dy, dL] N s/m"),
            ]
    return "\n".join(out) + "\n"


def data_comment(spec: ModelSpec) -> str:
    """The commented ``[data]`` block for a template: the physics defaults' values."""
    table, summary = physics_data_table(spec)
    lines = [
        "",
        "# [data]: how `softpinn simulate` makes data for this arm. Without the table it takes",
        "# defaults computed from the physics above (docs/spec.md), recomputed when you edit it;",
        "# for the physics as written they are the values below. To choose your own, uncomment",
        "# the whole table and edit it (a [data] table replaces every default).",
        "# [data]",
    ]
    for key, value in table.items():
        text = f'"{value}"' if isinstance(value, str) else (
            "[" + ", ".join(_num(v) for v in value) + "]" if isinstance(value, list)
            else _num(value) if isinstance(value, float) else str(value))
        lines.append(f"# {key} = {text}")
    lines += [
        "",
        "# [training]: a task recipe for `softpinn reproduce` (network sizes, epochs, losses):",
        "# see docs/recipes.md and the presets in symbolic/presets/.",
    ]
    return "\n".join(lines) + "\n"


def write_template(name: str, segments: int, **options) -> tuple[str, ModelSpec]:
    """The full template text (physics and the commented ``[data]`` block) and its spec,
    checked by the spec loader."""
    text = spec_template(name, segments, **options)
    source = options.get("file") or f"{name}.toml"
    spec = spec_from_toml(text, source=source)
    text += data_comment(spec)
    return text, spec_from_toml(text, source=source)


def _error(message: str):
    return UserError(message)
