"""``softpinn init``: a commented template spec for an arm of one's own (``docs/import.md``).

:func:`spec_template` writes a PCC arm of K segments, spatial (``delta``, tendon-driven by
default, as the paper's platform) or planar, standing up or hanging. The numbers are a plausible
small soft arm (0.2 m, 0.1 kg segments; bending stiffness about 1 N m/rad per segment it
carries, enough to stand up) for the user to replace by their own. The ``[data]`` table is left
commented out: without it ``softpinn simulate`` takes defaults from the physics
(:mod:`symbolic.simulation._defaults`), which follow edits of the physics; the template shows their
values for the physics it was written with.

The actuation kinds users have (``docs/spec.md``, "Actuation of an arm of one's own"):
``tendon`` (named: evenly spaced tendons, A(q) = -(d l_tendon / dq)^T, eq. 4), tendons at given
angles, pneumatic ``chambers`` at given angles, and direct bending ``torques``. The last three are
written as the constant input matrix A a spec accepts: in the ``delta`` form a tendon's or a
chamber's length is linear in q (l = L0 + dL - (r/d)(dx cos a + dy sin a), as
:func:`symbolic.derivation._kinematics.tendon_lengths`), so its column of A is exact and constant.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence

from softpinn.errors import UserError
from softpinn.symbolic.simulation._defaults import physics_data_table
from softpinn.symbolic.spec._model_spec import ModelSpec
from softpinn.symbolic.spec._spec import spec_from_toml

SPATIAL_ACTUATIONS = ("tendon", "generalized", "tip-wrench", "none", "chambers", "torques")
PLANAR_ACTUATIONS = ("generalized", "torques", "none")
#: other spellings ``init`` accepts
ALIASES = {"tendons": "tendon", "chamber": "chambers", "torque": "torques"}
#: inputs per segment when ``inputs`` is not given
DEFAULT_INPUTS = {"tendon": 4, "chambers": 3}
LENGTH, MASS, RADIUS, TENDON_RADIUS = 0.2, 0.1, 0.03, 0.02
CHAMBER_AREA = math.pi * 0.006**2  # m^2: a 12 mm bore
KPA = 1000.0  # Pa per kPa: chamber pressures are written in kPa
BEND_K = 1.2  # N m / rad per segment carried (the base carries all K)
BEND_C = 0.012  # N m s / rad per segment carried
STRETCH_K, STRETCH_C = 500.0, 2.0  # N/m, N s/m


def _num(x: float) -> str:
    return repr(float(f"{x:.6g}"))


def _line(code: str, comment: str) -> str:
    """``code`` with its comment aligned at column 35."""
    return f"{code:<33} # {comment}"


def spec_template(name: str, segments: int, *, planar: bool = False, hanging: bool = False,
                  actuation: str | None = None, file: str | None = None,
                  inputs: int | None = None, angles: Sequence[float] | None = None) -> str:
    """The TOML text of a commented template spec (see the module docstring); ``file`` is the
    name its comments use for it (default ``NAME.toml``). ``inputs``: tendons or chambers per
    segment; ``angles``: their angles [deg] in each segment's frame (tendons at given angles
    and chambers are written as a constant matrix, see :func:`actuation_matrix`)."""
    if not re.fullmatch(r"[A-Za-z0-9_.-]+", name or ""):
        raise _error(f"name: use letters, digits, '_', '-' or '.', got {name!r}")
    if isinstance(segments, bool) or not isinstance(segments, int) or segments < 1:
        raise _error(f"segments: must be a whole number >= 1, got {segments!r}")
    options = PLANAR_ACTUATIONS if planar else SPATIAL_ACTUATIONS
    actuation = ALIASES.get(actuation, actuation) or options[0]
    if actuation not in options:
        raise _error(f"actuation: a {'planar' if planar else 'spatial'} arm takes one of "
                     f"{', '.join(options)}, got {actuation!r}")
    angles = _angles(actuation, inputs, angles)
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
        ]
        if actuation == "torques":
            out += _matrix_lines(actuation, segments, None, planar=True)
        else:
            out.append(_line(f'actuation = "{actuation}"', '"generalized": u = [torque on '
                             'theta, force on dL] per segment | "none" | a matrix [[...], ...] '
                             '(n rows)'))
    else:
        g = "9.81" if hanging else "-9.81"
        out += [
            _line('parameterization = "delta"', "q per segment [dx, dy, dL]: (dx, dy) = d theta "
                  "(cos phi, sin phi) [m], dL the stretch [m]; smooth at the straight arm"),
            _line(f"gravity = [0.0, 0.0, {g}]", "[m/s^2] in the base frame; the straight arm "
                  f"points along +z, so this one {'hangs' if hanging else 'stands up'} (flip the "
                  "sign for the other way)"),
        ]
        if angles is None and actuation not in ("chambers", "torques"):
            count = inputs or DEFAULT_INPUTS["tendon"]
            out += [
                _line(f"actuators_per_segment = {count}", "tendons per segment (a_dof), evenly "
                      "around the centre line"),
                _line(f'actuation = "{actuation}"', '"tendon": u = tendon tensions [N] (a '
                      'negative one pulls the opposite tendon), a_dof per segment | '
                      '"generalized": u = forces on q | "tip-wrench": tip torques and tangent '
                      'force | "none"'),
            ]
        elif actuation == "torques":
            out.append(_line("actuators_per_segment = 4", "a_dof: turns each segment's frame by "
                             "180/a_dof deg about z (eq. 14); no tendons here"))
            out += _matrix_lines(actuation, segments, None, planar=False)
        else:
            what = "tendons" if actuation == "tendon" else "chambers"
            out.append(_line(f"actuators_per_segment = {len(angles)}",
                             f"{what} per segment (a_dof); segment i's frame is the base frame "
                             f"turned by i*180/{len(angles)} deg about z (eq. 14)"))
            out += _matrix_lines(actuation, segments, angles, planar=False)
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
                _line(f"actuator_radius = {_num(TENDON_RADIUS)}", _radius_comment(actuation)),
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
        "# [actuator]: the lag and dead time between the u you record and the arm [s], one",
        "# number for every input or a list with one per input. Give it when u holds COMMANDS",
        "# (valve or pressure-regulator set points, motor set points): a pneumatic chamber fills",
        "# with a lag of 0.1-1 s after a transport delay of 0.1-0.5 s. Leave it out when u holds",
        "# MEASURED actuator signals (chamber pressures, tendon tensions): their lag is in them.",
        "# `softpinn simulate` simulates the arm behind it, `softpinn import` records it and",
        "# `softpinn train` applies it; without the table, `train --actuator auto` identifies one",
        "# from imported recordings (docs/import.md, \"Actuator dynamics\").",
        "# [actuator]",
        "# time_constant = 0.2",
        "# delay = 0.1",
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


def _radius_comment(actuation: str) -> str:
    """The comment on ``actuator_radius``: what d is for the arm's actuation."""
    if actuation == "chambers":
        return "d: the chambers' centres' distance from the centre line [m]"
    if actuation == "torques":
        return "d: sets the delta form's units, dx = d theta cos phi [m]"
    return "d: the tendons' distance from the centre line [m]"


def _angles(actuation: str, inputs, angles) -> tuple[float, ...] | None:
    """The actuators' angles [deg] per segment: given ones, evenly spaced chambers, or None
    (the named actuation, evenly spaced tendons included); checks ``inputs`` and ``angles``."""
    if inputs is not None:
        if actuation not in DEFAULT_INPUTS:
            raise _error(f"inputs: only --actuation tendons or chambers take a number of "
                         f"inputs per segment; {actuation} has a fixed number")
        if isinstance(inputs, bool) or not isinstance(inputs, int) or inputs < 1:
            raise _error(f"inputs: must be a whole number >= 1, got {inputs!r}")
    if angles is None:
        if actuation == "chambers":
            count = inputs or DEFAULT_INPUTS["chambers"]
            return tuple(360.0 * j / count for j in range(count))
        return None
    if actuation not in DEFAULT_INPUTS:
        raise _error(f"angles: only --actuation tendons or chambers are placed at angles; "
                     f"{actuation} has none")
    angles = tuple(float(a) for a in angles)
    if not angles:
        raise _error("angles: give at least one angle [deg]")
    if not all(math.isfinite(a) for a in angles):
        raise _error(f"angles: must be finite numbers of degrees, got {list(angles)}")
    if inputs is not None and inputs != len(angles):
        raise _error(f"inputs: {inputs} inputs per segment but {len(angles)} angles; give as "
                     "many angles as inputs")
    wrapped = [round(a % 360.0, 9) % 360.0 for a in angles]
    if len(set(wrapped)) != len(wrapped):
        raise _error(f"angles: two actuators at the same angle (mod 360), got {list(angles)}")
    return angles


def actuation_matrix(actuation: str, segments: int, angles: Sequence[float] | None, *,
                     planar: bool = False, radius: float = TENDON_RADIUS,
                     area: float = CHAMBER_AREA) -> list[list[float]]:
    """The constant input matrix A (n rows, m columns) of tendons or chambers at ``angles``
    [deg, in each segment's own frame] or of direct ``torques``, for a template arm whose
    segments all have actuator radius d = ``radius`` (the ``delta`` form; ``docs/spec.md``).

    * tendons: tendon j of segment i runs from the base to segment i's tip at angle a_j of
      segment i's frame, through segment k <= i at a_j + (i - k) 180/a_dof deg (as
      :func:`symbolic.derivation._kinematics.tendon_lengths`); A = -(d l / dq)^T: on
      (dx_k, dy_k, dL_k) the entries (cos b, sin b, -1), u the tensions [N];
    * chambers: chamber j of segment i (area S, centre at r = d) lengthens segment i only,
      l = L0 + dL - (r/d)(dx cos a_j + dy sin a_j); a gauge pressure p [kPa] does the work
      1000 p S dl, so A = 1000 S (d l / dq)^T: (-cos a_j, -sin a_j, 1) 1000 S [N/kPa] on
      (dx_i, dy_i, dL_i): it bends the segment away from the chamber with the moment 1000 p S r
      [N m] and stretches it with the force 1000 p S [N];
    * torques: u = [tau_x, tau_y] per segment [N m], the generalized forces conjugate to the
      bending angle's components (dx, dy) / d: A = I / d on (dx_i, dy_i), 0 on dL_i; planar:
      u = the torque on theta_i [N m], A = I on theta_i.
    """
    if actuation == "torques":
        per, n = (2, 2 * segments) if planar else (3, 3 * segments)
        cols = per - 1
        A = [[0.0] * (cols * segments) for _ in range(n)]
        for i in range(segments):
            for c in range(cols):
                A[per * i + c][cols * i + c] = 1.0 if planar else 1.0 / radius
        return A
    a = len(angles)
    A = [[0.0] * (a * segments) for _ in range(3 * segments)]
    for i in range(segments):
        for j, deg in enumerate(angles):
            col = a * i + j
            if actuation == "chambers":
                rad = math.radians(deg)
                entries = {3 * i: -math.cos(rad), 3 * i + 1: -math.sin(rad), 3 * i + 2: 1.0}
                for row, v in entries.items():
                    A[row][col] = KPA * area * v
                continue
            for k in range(i + 1):
                rad = math.radians(deg + (i - k) * 180.0 / a)
                A[3 * k][col] = math.cos(rad)
                A[3 * k + 1][col] = math.sin(rad)
                A[3 * k + 2][col] = -1.0
    top = max(abs(v) for row in A for v in row)
    return [[0.0 if abs(v) < 1e-12 * top else v for v in row] for row in A]  # cos 90 deg


def _matrix_lines(actuation: str, segments: int, angles, *, planar: bool) -> list[str]:
    """The commented ``actuation = [[...], ...]`` block of a constant input matrix."""
    A = actuation_matrix(actuation, segments, angles, planar=planar)
    m = len(A[0])
    names = ([f"{c}{i + 1}" for i in range(segments) for c in ("theta", "dL")] if planar
             else [f"{c}{i + 1}" for i in range(segments) for c in ("dx", "dy", "dL")])
    per = m // segments
    if actuation == "torques" and planar:
        head = [
            "# Direct torques: u = the torque on every segment's theta [N m], one per segment;",
            "# the constant input matrix A (one row per coordinate, one column per input) is the",
            "# identity on the bending coordinates theta_i and 0 on the stretch dL_i.",
        ]
        inputs = [f"tau{i + 1}" for i in range(segments)]
    elif actuation == "torques":
        head = [
            "# Direct bending torques: u = [tau_x, tau_y] per segment [N m], the generalized",
            "# forces conjugate to the bending angle's components theta_x = dx/d, theta_y = dy/d",
            "# (moments that bend segment i toward +x, +y of its frame). As the constant input",
            "# matrix A (one row per coordinate, one column per input): 1/d on (dx_i, dy_i), 0 on",
            f"# dL_i (the stretch is not driven). 1/d = {_num(1 / TENDON_RADIUS)} 1/m for d = "
            f"{_num(TENDON_RADIUS)} m: change them",
            "# with actuator_radius. (A = I instead makes u the forces on dx, dy [N].)",
        ]
        inputs = [f"tau{c}{i + 1}" for i in range(segments) for c in ("x", "y")]
    elif actuation == "chambers":
        listed = ", ".join(f"{float(a):g}" for a in angles)
        head = [
            f"# Pneumatic chambers: {per} per segment at {listed} deg in the segment's frame",
            "# (from +x toward +y), u = their gauge pressures [kPa], segment by segment. Chamber j",
            "# of segment i (cross-section S, centre at r from the centre line) has the length",
            "# l = L0 + dL - (r/d)(dx cos a_j + dy sin a_j) (constant curvature); a pressure p",
            "# does the work p S dl, so its column of the constant input matrix A (one row per",
            "# coordinate) is 1000 S (-(r/d) cos a_j, -(r/d) sin a_j, 1) [N/kPa] on (dx_i, dy_i,",
            "# dL_i) and 0 elsewhere, exact in the delta form: p bends segment i away from the",
            "# chamber (toward a_j + 180 deg) with the moment 1000 p S r [N m] and stretches it",
            f"# with 1000 p S [N]. Here S = {_num(CHAMBER_AREA)} m^2 (a 12 mm bore) and r = d:",
            f"# 1000 S = {_num(KPA * CHAMBER_AREA)} N/kPa. Pressures in Pa: divide every entry by "
            "1000; bar:",
            "# multiply by 100; psi: by 6.895. A chamber only pushes (p >= 0): the [data] defaults",
            "# swing each input about 0; give offset_low/high >= amplitude_high for a real arm's.",
        ]
        inputs = [f"p{i + 1}.{j + 1}" for i in range(segments) for j in range(per)]
    else:
        listed = ", ".join(f"{float(a):g}" for a in angles)
        head = [
            f"# Tendons: {per} per segment at {listed} deg in the segment's frame (from +x toward",
            "# +y), u = their tensions [N] (a negative one pushes), segment by segment. Tendon j",
            "# of segment i runs from the base to segment i's tip, at distance d from the centre",
            "# line, through segment k <= i at a_j + (i - k) 180/a_dof deg; its length is",
            "# sum_k L0_k + dL_k - (dx_k cos b + dy_k sin b), so its column of the constant input",
            "# matrix A = -(d l / dq)^T (one row per coordinate) is (cos b, sin b, -1) on (dx_k,",
            "# dy_k, dL_k) [N/N], as actuation = \"tendon\" gives for evenly spaced tendons",
            "# (segments of different d: scale segment k's dx, dy entries of tendon j of segment",
            "# i by d_i / d_k).",
        ]
        inputs = [f"T{i + 1}.{j + 1}" for i in range(segments) for j in range(per)]
    width = max(len(_num(v)) for row in A for v in row)
    out = head + [_line("actuation = [", f"A: {len(A)} x {m}; columns {', '.join(inputs)}")]
    for name, row in zip(names, A, strict=True):
        cells = ", ".join(f"{_num(v):>{width}}" for v in row)
        out.append(_line(f"  [{cells}],", name))
    out.append("]")
    return out


def _error(message: str):
    return UserError(message)
