"""Control of larger arms (issue 46): default references the arm can hold with its inputs (the
physics defaults of a spec without a [data] table, a radius shrunk until every holding input
lies inside the bounds), and a controller's Functions that share the model's Jacobian, so that
the generated C holds it once whatever the sensitivities."""

from __future__ import annotations

import numpy as np
import pytest

from softpinn.bridge.control import MPCConfig, equilibrium, from_true, tip_output
from softpinn.bridge.control.gauss_newton import sqp_functions
from softpinn.bridge.control.references import (
    INPUT_MARGIN,
    default_center,
    default_input_bounds,
    default_radius,
    fitted_radius,
    reachable_radius,
    step_targets,
)
from softpinn.symbolic import TrueModel, load_spec, write_template


@pytest.fixture(scope="module")
def arm(tmp_path_factory):
    """A one-segment tendon arm as `softpinn init` writes it: no [data] table."""
    text, _ = write_template("arm1", 1)
    path = tmp_path_factory.mktemp("spec") / "arm1.toml"
    path.write_text(text)
    spec = load_spec(str(path))
    assert not spec.data
    return spec, TrueModel(spec, compiled=False)


def test_defaults_come_from_the_physics_defaults(arm):
    """Without [data] the centre and radius are those of the data `simulate` would draw (its
    physics defaults, ±6 mm of bend here), not zeros and 0.1 (a 5 rad bend of this arm)."""
    from softpinn.symbolic import plan_dataset

    spec, _ = arm
    data = plan_dataset(spec).data
    lo, hi = np.asarray(data.q0_low), np.asarray(data.q0_high)
    assert np.allclose(default_center(spec), 0.5 * (lo + hi))
    assert default_radius(spec) == pytest.approx(0.15 * np.min((hi - lo)[:2]))
    assert default_radius(spec) < 0.01


def _holding_inputs(tm, center, radius):
    points = step_targets(center, radius) + [
        center + radius * np.r_[np.cos(a), np.sin(a), np.zeros(center.size - 2)]
        for a in np.linspace(0, 2 * np.pi, 8, endpoint=False)]
    return np.array([equilibrium(tm, q)[1] for q in points])


def test_reachable_radius_keeps_holding_inputs_inside_the_bounds(arm):
    """The default radius needs more input than the default bounds allow on this arm: it is
    shrunk until every holding input is inside the bounds less the margin, and not much
    further (twice the result does not fit)."""
    spec, tm = arm
    center, radius = default_center(spec), default_radius(spec)
    lb, ub = default_input_bounds(spec)
    width = ub - lb
    lo, hi = lb + INPUT_MARGIN * width, ub - INPUT_MARGIN * width
    u = _holding_inputs(tm, center, radius)
    assert np.any(u > hi) or np.any(u < lo)  # the case the shrinking is for
    r = reachable_radius(tm, center, radius, lb, ub)
    assert 0 < r < radius
    u = _holding_inputs(tm, center, r)
    assert np.all(u >= lo) and np.all(u <= hi)
    u = _holding_inputs(tm, center, 2 * r)
    assert np.any(u > hi) or np.any(u < lo)
    # unbounded inputs, or bounds wide enough, keep the radius
    assert reachable_radius(tm, center, radius, np.full(spec.m, -np.inf),
                            np.full(spec.m, np.inf)) == radius
    assert reachable_radius(tm, center, radius, 100 * lb, 100 * ub) == radius


def test_fitted_radius_shrinks_only_the_default(arm):
    """`softpinn control`'s radius: the default shrunk, a given one kept with a note."""
    spec, tm = arm
    center, radius = default_center(spec), default_radius(spec)
    bounds = default_input_bounds(spec)
    said = []
    fitted = fitted_radius(tm, center, radius, *bounds, given=False, say=said.append)
    assert fitted == reachable_radius(tm, center, radius, *bounds) < radius
    assert fitted_radius(tm, center, radius, *bounds, given=True, say=said.append) == radius
    assert len(said) == 2 and "default radius" in said[0] and "would fit" in said[1]


def test_task4_default_radius_is_kept():
    """Task 4's default references fit its bounds: nothing changes there."""
    spec = load_spec("task4")
    tm = TrueModel(spec, compiled=False)
    center, radius = default_center(spec), default_radius(spec)
    assert reachable_radius(tm, center, radius, *default_input_bounds(spec)) == radius


@pytest.mark.parametrize("sensitivities", ["frozen", "lifted"])
def test_generated_c_holds_the_jacobian_once(arm, tmp_path, sensitivities):
    """The frozen and lifted controllers' C is about the exact one's size: the Jacobian
    Function is shared by gn, gn_exact and gn_lifted (built per call, it was 1.7x and 2.5x)."""
    from softpinn.symbolic.codegen._codegen import write_c

    spec, tm = arm
    model = from_true(tm, tip_output(spec))
    sizes = {}
    for sens in ("exact", sensitivities):
        fns = sqp_functions(model, MPCConfig(horizon=5, sensitivities=sens), np.zeros(spec.m))
        sizes[sens] = write_c(fns, tmp_path, f"mpc_{sens}").stat().st_size
    assert sizes[sensitivities] < 1.25 * sizes["exact"]


def test_true_jacobian_is_the_odes(arm, tmp_path):
    """The true model's Jacobian through its inverse dynamics is CasADi's Jacobian of its ODE
    to rounding, at states away from the centre too, and is used where it is the smaller
    (two segments: fewer instructions; one segment: the ODE's own)."""
    import casadi as ca

    assert from_true(arm[1], tip_output(arm[0])).jacobian is None
    text, _ = write_template("arm2", 2)
    (tmp_path / "arm2.toml").write_text(text)
    spec = load_spec(str(tmp_path / "arm2.toml"))
    tm = TrueModel(spec, compiled=False)
    model = from_true(tm, tip_output(spec))
    assert model.jacobian is not None
    x, u = ca.SX.sym("x", 2 * spec.n), ca.SX.sym("u", spec.m)
    f = model.field(x, u)
    ref = ca.Function("ref", [x, u], [f, ca.jacobian(f, ca.vertcat(x, u))])
    assert model.jacobian.n_instructions() < 0.8 * ref.n_instructions()
    rng = np.random.default_rng(1)
    for _ in range(4):
        xs = np.concatenate([rng.uniform(-0.01, 0.01, spec.n), rng.uniform(-0.5, 0.5, spec.n)])
        us = rng.uniform(-3, 3, spec.m)
        (f0, J0), (f1, J1) = (tuple(np.asarray(v) for v in fn(xs, us))
                              for fn in (ref, model.jacobian))
        assert np.allclose(f1, f0, rtol=0, atol=1e-12 * np.max(np.abs(f0)))
        assert np.max(np.abs(J1 - J0)) <= 1e-10 * np.max(np.abs(J0))


def test_large_arms_default_to_a_short_horizon_and_lifted_sensitivities():
    """From three spatial segments on, softpinn control's defaults are horizon 10 and lifted
    sensitivities (measured at n = 9: 10-12 ms per solve against 125 ms, same tracking), said
    in a note; smaller arms and anything given keep theirs."""
    from softpinn.bridge.control import LARGE_ARM_N, arm_defaults

    assert arm_defaults(6, None, None) == (20, "exact", None)
    h, s, note = arm_defaults(LARGE_ARM_N, None, None)
    assert (h, s) == (10, "lifted")
    assert note.startswith("note: an arm of n = 9 coordinates: horizon 10 and lifted")
    h, s, note = arm_defaults(12, 30, None)
    assert (h, s) == (30, "lifted") and "horizon 10" not in note and "horizon 30" not in note
    assert "lifted sensitivities" in note
    assert arm_defaults(12, 20, "exact") == (20, "exact", None)


def test_the_cli_takes_the_large_arm_defaults_and_says_so(tmp_path, monkeypatch, capsys):
    """`softpinn control` on a 3-segment arm from `softpinn init`: horizon 10 and lifted, with
    one note; given flags win (the comparison itself, minutes of compiling, is not run)."""
    from softpinn.bridge import cli
    from softpinn.bridge.cli import _control_run

    text, _ = write_template("arm3", 3)
    spec = tmp_path / "arm3.toml"
    spec.write_text(text)
    seen = []

    class Stop(Exception):
        pass

    def stop(spec_, runs, out, config, **kw):
        seen.append(config.mpc)
        raise Stop

    monkeypatch.setattr(_control_run, "compare", stop)
    for extra in ([], ["--horizon", "15"]):
        with pytest.raises(Stop):
            cli.main(["control", str(spec), "--out", str(tmp_path / "o"), *extra])
    first, second = seen
    assert (first.horizon, first.sensitivities) == (10, "lifted")
    assert (second.horizon, second.sensitivities) == (15, "lifted")
    err = capsys.readouterr().err
    assert "note: an arm of n = 9 coordinates: horizon 10 and lifted sensitivities" in err
