"""References for the tip (or q) to follow, and the equilibria they start from.

Every reference is the output y(q(t)) of a path q(t) in the arm's own coordinates, so its shape
is one the arm can take:

* :func:`circle_reference`: q(t) goes round a circle of radius ``radius`` in the first two
  coordinates around ``q_center``. For a spatial PCC arm in the delta parameterization
  (q = [dx, dy, dL, ...]) the tip then draws a closed, horizontal curve around the tip at
  ``q_center`` (a circle seen from below), with the bend angle constant;
* :func:`step_reference`: a sequence of targets, each an equilibrium (:func:`equilibrium`: the
  rest state nearest a desired q that some constant input holds, so an under-actuated system
  gets targets it can reach), held ``hold`` seconds each.

:func:`default_center` and :func:`default_radius` take the middle and 15 % of the range of the
initial coordinates in the spec's ``[data]`` table, :func:`default_input_bounds` the range of
its input signals: the region the models were trained on.
"""

from __future__ import annotations

import logging

import casadi as ca
import numpy as np

from softpinn.errors import UserError
from softpinn.symbolic import data_config, draw_trajectories, plan_dataset

__all__ = ["circle_reference", "circle_start", "step_reference", "equilibrium", "step_targets",
           "default_center", "default_radius", "default_input_bounds", "check_lengths",
           "reachable_radius", "fitted_radius"]

#: the share of the input box's width on each side that a default reference's holding inputs
#: keep clear of (room for the transients between them)
INPUT_MARGIN = 0.1


def check_lengths(spec, center, radius: float) -> None:
    """Refuse (one line naming ``center`` or ``radius`` and the segment) a centre, or a
    reference around it (± ``radius`` in q's first two coordinates), where a PCC segment's
    length L + dL is not positive: such a q describes no arm (issue 44)."""
    if spec.kind not in ("spatial-pcc", "planar-pcc"):
        return
    c = np.asarray(center, float).ravel()
    for k, name in enumerate(spec.coordinate_names):
        if not (name.startswith("dL") and name[2:].isdigit()):
            continue
        i = int(name[2:])
        L = float(spec.segments[i - 1].length)
        if c[k] <= -L:
            raise UserError(f"center: {name} = {c[k]:g} makes segment {i}'s length "
                            f"L + {name} = {L + c[k]:g} m, not > 0 (L = {L:g} m); give "
                            f"{name} > {-L:g}")
        if k < 2 and c[k] - radius <= -L:
            raise UserError(f"radius: {radius:g} takes {name} to {c[k] - radius:g} around the "
                            f"centre's {c[k]:g}, where segment {i}'s length L + {name} is not "
                            f"> 0 (L = {L:g} m); give a radius < {c[k] + L:g}")


_last_plan: dict = {}


def _quiet_plan(spec):
    """``plan_dataset(spec)`` without its note on the physics defaults (``simulate``'s to say);
    the last spec's is kept (the centre, the radius and the bounds each ask it, and its physics
    defaults take seconds for a 3-segment arm)."""
    key = repr(spec)
    if key in _last_plan:
        return _last_plan[key]
    quiet = logging.getLogger("softpinn.symbolic")
    level = quiet.level
    quiet.setLevel(logging.ERROR)
    try:
        plan = plan_dataset(spec)
    finally:
        quiet.setLevel(level)
    _last_plan.clear()
    _last_plan[key] = plan
    return plan


def _data_range(spec):
    """(q0_low, q0_high) of the data ``softpinn simulate`` makes for ``spec``: its ``[data]``
    table's, or for a PCC arm without one the defaults it computes from the physics (issue 46:
    a spec from ``softpinn init`` has none, and a fixed radius of 0.1 in q took a tendon arm's
    circle to a bend of 5 rad, a rest state 100 times beyond the input bounds); None where
    neither gives one (other models without a table keep zeros and 0.1)."""
    physics = not spec.data and spec.kind in ("spatial-pcc", "planar-pcc")
    try:
        cfg = _quiet_plan(spec).data if physics else data_config(spec)
    except Exception:  # noqa: BLE001 - a spec without a usable [data] table: no range
        return None
    if cfg.q0_low is None or cfg.q0_high is None:
        return None
    lo, hi = np.asarray(cfg.q0_low, float), np.asarray(cfg.q0_high, float)
    if lo.size != spec.n or hi.size != spec.n:
        return None
    return lo, hi


def default_center(spec) -> np.ndarray:
    """The middle of the initial coordinates of the spec's data (its ``[data]`` table, or a PCC
    arm's physics defaults without one; zeros without a range)."""
    r = _data_range(spec)
    return np.zeros(spec.n) if r is None else 0.5 * (r[0] + r[1])


def default_radius(spec) -> float:
    """15 % of the smaller range of the first two initial coordinates of the spec's data (its
    ``[data]`` table, or a PCC arm's physics defaults without one; 0.1 without a range)."""
    r = _data_range(spec)
    if r is None or spec.n < 2:
        return 0.1
    return float(0.15 * np.min(r[1][:2] - r[0][:2]))


def default_input_bounds(spec) -> tuple[np.ndarray, np.ndarray] | None:
    """(u_min, u_max): the range of the inputs ``softpinn simulate SPEC`` draws (every
    trajectory's signal from the spec's ``[data]`` table, or the physics defaults without one,
    sampled at the data's rate, together with offset ± amplitude where the table gives those
    ranges), widened by a quarter of its width on each side: inputs near those the models were
    trained on. The signals themselves are measured, so a multisine's summed components count.
    An input the data hold constant is left unbounded (-inf, inf); None when no input moves
    (or m = 0)."""

    if not spec.m:
        return None
    plan = _quiet_plan(spec)
    sim = plan.sim
    _, signals = draw_trajectories(plan.data, spec.n, spec.m, range(plan.trajectories),
                                   kind=plan.signal, duration=sim.duration + plan.settle,
                                   seed=plan.seed)
    t = np.arange(int(np.floor((sim.duration + plan.settle) * sim.rate)) + 1) / sim.rate
    u = np.concatenate([np.asarray(sig(t), float).reshape(len(t), spec.m) for sig in signals])
    lo, hi = u.min(axis=0), u.max(axis=0)
    envelope = _signal_envelope(plan.data.ranges, spec.m)
    if envelope is not None:  # offset ± amplitude: what one sinusoid of the ranges can reach
        lo, hi = np.minimum(lo, envelope[0]), np.maximum(hi, envelope[1])
    moves = np.isfinite(lo) & np.isfinite(hi) & (hi > lo)
    if not moves.any():
        return None
    pad = 0.25 * (hi - lo)
    # an input the data hold constant gets no bound: its one value would leave no control
    return (np.where(moves, np.round(lo - pad, 12), -np.inf),
            np.where(moves, np.round(hi + pad, 12), np.inf))


def _signal_envelope(ranges, m: int) -> tuple[np.ndarray, np.ndarray] | None:
    """offset_low - amplitude_high .. offset_high + amplitude_high per input (a missing offset
    is 0, one number stands for every input), or None without an amplitude range."""
    if "amplitude_high" not in ranges:
        return None
    try:
        amp = np.broadcast_to(np.asarray(ranges["amplitude_high"], float), (m,))
        off_lo = np.broadcast_to(np.asarray(ranges.get("offset_low", 0.0), float), (m,))
        off_hi = np.broadcast_to(np.asarray(ranges.get("offset_high", 0.0), float), (m,))
    except ValueError:  # sizes the [data] table's checks let through for another use
        return None
    return off_lo - np.abs(amp), off_hi + np.abs(amp)


def _circle_q(q_center, radius, period, t):
    q = np.array(q_center, float)
    q[0] += radius * np.cos(2 * np.pi * t / period)
    if q.size > 1:
        q[1] += radius * np.sin(2 * np.pi * t / period)
    return q


def circle_reference(output: ca.Function, q_center, radius: float, period: float,
                     times: np.ndarray) -> np.ndarray:
    """Outputs y(q(t)) (len(times), ny) for q(t) going round a circle in q's first two
    coordinates (q_center + radius (cos ωt, sin ωt, 0 ...), ω = 2π / period)."""
    if not (np.isfinite(period) and period > 0):
        raise UserError(f"period: expected a number of seconds > 0, got {period!r}")
    return np.array([np.asarray(output(_circle_q(q_center, radius, period, t))).ravel()
                     for t in np.asarray(times, float)])


def circle_start(q_center, radius: float) -> np.ndarray:
    """q at t = 0 on the circle of :func:`circle_reference`."""
    return _circle_q(q_center, radius, 1.0, 0.0)


def equilibrium(true_model, q_desired, *, weight_u: float = 1e-12
                ) -> tuple[np.ndarray, np.ndarray]:
    """(q*, u*): the rest state nearest ``q_desired`` that a constant input u* holds
    (A(q*) u* = G(q*), the static part of eq. 4), from a small NLP (IPOPT). For a fully
    actuated arm q* = q_desired."""
    n, m = true_model.n, true_model.m
    qd = np.asarray(q_desired, float).ravel()
    if qd.size != n:
        raise UserError(f"equilibrium: expected {n} coordinates, got {qd.size}")
    inverse = true_model.functions["inverse"]
    A = true_model.functions["A"]
    tau0 = np.asarray(inverse(qd, np.zeros(n), np.zeros(n))).ravel()
    A0 = np.asarray(A(qd)).reshape(n, m)
    u0 = np.linalg.lstsq(A0, tau0, rcond=None)[0] if m else np.zeros(0)
    if np.linalg.norm(A0 @ u0 - tau0) <= 1e-12 * (1.0 + np.linalg.norm(tau0)):
        return qd, u0  # q_desired is a rest state already (a fully actuated arm)
    q, u = ca.SX.sym("q", n), ca.SX.sym("u", m)
    z = ca.SX.zeros(n)
    tau = inverse(q, z, z)
    res = tau - ca.mtimes(A(q), u) if m else tau
    f = 0.5 * ca.sumsqr(q - qd) + 0.5 * weight_u * ca.sumsqr(u)
    nlp = {"x": ca.vertcat(q, u), "f": f, "g": res}
    solver = ca.nlpsol("equilibrium", "ipopt", nlp,
                       {"print_time": False, "error_on_fail": False,
                        "ipopt": {"print_level": 0, "sb": "yes", "tol": 1e-12,
                                  "max_iter": 200}})
    sol = solver(x0=np.concatenate([qd, u0]), lbg=0, ubg=0)
    w = np.asarray(sol["x"]).ravel()
    viol = np.max(np.abs(np.asarray(sol["g"]))) if n else 0.0
    if not (solver.stats()["success"] and np.all(np.isfinite(w)) and viol < 1e-8):
        raise UserError(f"equilibrium: no rest state found near q = {qd.tolist()} "
                        f"({solver.stats()['return_status']})")
    return w[:n], w[n:]


def _reference_points(q_center, radius: float) -> list[np.ndarray]:
    """The desired q the references ask around ``q_center``: the step targets and eight points
    of the circle."""
    circle = [_circle_q(q_center, radius, 8.0, t) for t in range(8)]
    return step_targets(q_center, radius) + circle


def reachable_radius(true_model, q_center, radius: float, u_min, u_max, *,
                     margin: float = INPUT_MARGIN) -> float:
    """``radius``, shrunk (halved until it is) so that the input holding each rest state the
    references ask (:func:`equilibrium` at the step targets and along the circle) lies inside
    [u_min, u_max] less ``margin`` of the box's width on each side: a reference the arm can
    follow with the inputs it is allowed. Issue 46: a 3-segment tendon arm's default circle
    needed 16 N where the bounds allow ±3.9 N, and every controller saturated (0.46 m RMS,
    failed solves). Unbounded inputs keep ``radius``; 0 when even the centre's input is
    outside."""
    lb, ub = (np.asarray(v, float).ravel() for v in (u_min, u_max))
    finite = np.isfinite(lb) & np.isfinite(ub)
    with np.errstate(invalid="ignore"):  # inf - inf where a bound is missing
        width = np.where(finite, ub - lb, 0.0)
    lo, hi = lb + margin * width, ub - margin * width

    def inside(r):
        for q in ([np.asarray(q_center, float)] if r == 0 else _reference_points(q_center, r)):
            try:
                u = equilibrium(true_model, q)[1]
            except UserError:
                return False
            if np.any(u < lo) or np.any(u > hi):
                return False
        return True

    r = float(radius)
    for _ in range(40):  # 2^-40: nothing is left of any radius
        if inside(r):
            break
        r *= 0.5
    else:
        return 0.0
    if r == radius:
        return r
    good, bad = r, 2.0 * r
    for _ in range(4):  # then within 1/16 of the largest radius that fits
        mid = 0.5 * (good + bad)
        good, bad = (mid, bad) if inside(mid) else (good, mid)
    return good


def fitted_radius(true_model, q_center, radius: float, u_min, u_max, *, given: bool,
                  say=None) -> float:
    """The radius ``softpinn control`` uses on a PCC arm: the default one shrunk by
    :func:`reachable_radius`; a ``given`` one kept, with a note (``say``) where it does not
    fit. Other models keep theirs."""
    if true_model.spec.kind not in ("spatial-pcc", "planar-pcc"):
        return radius
    say = say or (lambda line: None)
    fits = reachable_radius(true_model, q_center, radius, u_min, u_max)
    if fits < radius and not given:
        say(f"note: the default radius {radius:.4g} asks rest states whose inputs leave the "
            f"bounds; using {fits:.4g} (every holding input inside the bounds, "
            f"{INPUT_MARGIN:.0%} of their width clear)")
        return fits
    if fits < radius:
        say(f"note: --radius {radius:g} asks rest states the arm cannot hold within the "
            f"input bounds; {fits:.4g} would fit")
    return radius


def step_targets(q_center, radius: float) -> list[np.ndarray]:
    """Desired q of a step reference: the centre moved by ± radius along q's first two
    coordinates, in the order +e₀, +e₁, -e₀, -e₁."""
    c = np.asarray(q_center, float)
    out = []
    for sign, axis in ((1, 0), (1, 1), (-1, 0), (-1, 1)):
        if axis < c.size:
            q = c.copy()
            q[axis] += sign * radius
            out.append(q)
    return out


def step_reference(output: ca.Function, q_targets, hold: float, times: np.ndarray) -> np.ndarray:
    """Outputs y(q_i) held ``hold`` seconds each, cycling through ``q_targets``: the row for
    time t is target ⌈t / hold⌉ - 1 (mod the number of targets), so target 0 holds on
    (0, hold], target 1 on (hold, 2 hold], ..."""
    if not (np.isfinite(hold) and hold > 0):
        raise UserError(f"hold: expected a number of seconds > 0, got {hold!r}")
    targets = [np.asarray(output(np.asarray(q, float))).ravel() for q in q_targets]
    idx = np.maximum(np.ceil(np.asarray(times, float) / hold - 1e-9).astype(int) - 1, 0)
    idx = idx % len(targets)
    return np.array([targets[i] for i in idx])
