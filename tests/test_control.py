"""Model-predictive control (bridge/control, `softpinn control`): the MPC with the true model
converges to reachable references and tracks a circle, the Gauss-Newton SQP finds IPOPT's
optimum, input bounds hold, a stiff model gets more RK4 sub-steps, learned models exported from
tiny runs close the loop with finite metrics and written results, and bad inputs give one-line
errors with exit status 2 and leave --out alone."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
from datagen import MSD_SPEC, MSD_SPEC_FULL, make_dataset, tiny_model_config

from softpinn.bridge import cli
from softpinn.bridge.control import (
    MPC,
    ControlConfig,
    MPCConfig,
    closed_loop,
    compare,
    equilibrium,
    from_run,
    from_true,
    metrics,
    plant,
    resolve_run,
    step_reference,
    tip_output,
)
from softpinn.bridge.control.models import PredictionModel
from softpinn.errors import UserError
from softpinn.symbolic import TrueModel

#: compiled libraries go to a cache of this test session (conftest.py)
pytestmark = pytest.mark.usefixtures("session_cache")


@pytest.fixture(scope="module")
def specs(tmp_path_factory):
    root = tmp_path_factory.mktemp("specs")
    (root / "forced.toml").write_text(MSD_SPEC)
    (root / "full.toml").write_text(MSD_SPEC_FULL)
    return {"forced": str(root / "forced.toml"), "full": str(root / "full.toml")}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """``get(kind, seeds=1)``: a tiny run on the forced chain's data, trained once per module."""
    from softpinn.learn import TrainConfig, train

    data = make_dataset(tmp_path_factory.mktemp("msd") / "msd.npz", trajectories=3,
                        duration=2.0)
    root = tmp_path_factory.mktemp("runs")
    cache = {}

    def get(kind, seeds=1):
        if (kind, seeds) not in cache:
            cfg = TrainConfig(model=tiny_model_config(kind), epochs=3, batch_size=64, lr=1e-2,
                              test_trajectories=(2,), seeds=seeds, checkpoint_every=1000)
            out = root / f"{kind}-{seeds}"
            train(data, cfg, out)
            cache[kind, seeds] = out
        return cache[kind, seeds]

    return get


def _loop(spec, q_target, *, steps, config, q0=None):
    tm = TrueModel(spec)
    out = tip_output(tm.spec)
    q_star, u_star = equilibrium(tm, q_target)
    mpc = MPC(from_true(tm, out), config)
    R = np.tile(np.asarray(out(q_star)).ravel(), (steps + config.horizon, 1))
    q0 = np.zeros(tm.n) if q0 is None else np.asarray(q0, float)
    res = closed_loop(mpc, plant(tm, config.dt), np.concatenate([q0, np.zeros(tm.n)]), R,
                      steps, u0=np.zeros(tm.m))
    return tm, q_star, u_star, res


def test_equilibria_are_reachable_targets(specs):
    """A fully actuated arm rests anywhere; the single-input chain only on K q = A u."""
    q, u = equilibrium(TrueModel(specs["full"]), [0.3, -0.2])
    np.testing.assert_allclose(q, [0.3, -0.2], atol=1e-7)
    tm = TrueModel(specs["forced"])
    q, u = equilibrium(tm, [0.3, 0.1])
    K = np.array([[2.1, -2.1], [-2.1, 6.7]])
    np.testing.assert_allclose(K @ q, [0.0, u[0]], atol=1e-8)
    assert q[0] == pytest.approx(q[1], abs=1e-8)  # force on mass 2: spring 1 unstretched


def test_true_model_converges_to_a_step(specs):
    """Compiled Gauss-Newton SQP, fully actuated chain: the target within 1e-6 in 2 s."""
    cfg = MPCConfig(horizon=10, dt=0.05, weight_y=1e2, weight_du=1e-3)
    _, q_star, u_star, res = _loop(specs["full"], [0.3, -0.2], steps=40, config=cfg)
    m = metrics(res)
    assert m["failures"] == 0 and not m["diverged"] and m["steps"] == 40
    assert m["error_final"] < 1e-6, m
    np.testing.assert_allclose(res["u"][-1], u_star, atol=1e-4)  # it holds the rest input
    assert m["solve_ms_mean"] > 0 and m["iterations_mean"] >= 1


def test_true_model_tracks_a_reachable_step_of_the_underactuated_chain(specs):
    """One force on the second mass: the equilibrium target is reached to a small error."""
    cfg = MPCConfig(horizon=30, dt=0.1, weight_y=1e2, codegen=False)
    _, q_star, _, res = _loop(specs["forced"], [0.3, 0.1], steps=100, config=cfg)
    e = np.linalg.norm(res["y"] - res["r"], axis=1)
    assert metrics(res)["failures"] == 0
    assert e[0] > 0.25 and e[-1] < 1e-3, e[::10]
    assert np.max(e[-20:]) < 1e-2


@pytest.mark.parametrize("solver", ["sqp", "ipopt"])
def test_offset_free_mpc_removes_a_wrong_models_offset(specs, tmp_path, solver):
    """A model with 30 % stiffer springs holds the chain off the target (it expects the
    springs to pull harder); the output-disturbance estimate measures that offset and removes
    it, and with the true model it stays ~0."""
    wrong = tmp_path / "stiff.toml"
    wrong.write_text(MSD_SPEC_FULL.replace("springs = [2.1, 4.6]", "springs = [2.73, 5.98]"))
    tm = TrueModel(specs["full"])
    out = tip_output(tm.spec)
    q_star, _ = equilibrium(tm, [0.3, -0.2])
    steps, errors, final_d = 60, {}, {}
    for name, spec, gain in (("plain", wrong, 0.0), ("offset-free", wrong, 0.5),
                             ("true", specs["full"], 0.5)):
        cfg = MPCConfig(horizon=10, dt=0.05, weight_y=1e2, weight_du=1e-3, solver=solver,
                        codegen=False, offset_free=gain)
        mpc = MPC(from_true(TrueModel(spec), out), cfg)
        R = np.tile(np.asarray(out(q_star)).ravel(), (steps + cfg.horizon, 1))
        res = closed_loop(mpc, plant(tm, cfg.dt), np.zeros(2 * tm.n), R, steps,
                          u0=np.zeros(tm.m))
        assert metrics(res)["failures"] == 0, name
        errors[name] = float(np.linalg.norm(res["y"][-1] - res["r"][-1]))
        final_d[name] = float(np.linalg.norm(mpc.disturbance))
    assert errors["plain"] > 2e-3, errors  # the wrong model's steady offset (3.7 mm)
    assert errors["offset-free"] < 1e-4 * errors["plain"], errors
    assert final_d["true"] < 1e-6 and final_d["offset-free"] > 1e-2, final_d


def test_the_disturbance_rate_follows_a_wrong_models_drifting_error(specs, tmp_path):
    """Along a moving reference (a sinusoid of the first mass) the 30 %-stiff model's error
    drifts; a constant estimate lags it, the alpha-beta filter (offset_free_rate) estimates its
    change per step too and tracks more than twice as close once both have settled."""
    wrong = tmp_path / "stiff.toml"
    wrong.write_text(MSD_SPEC_FULL.replace("springs = [2.1, 4.6]", "springs = [2.73, 5.98]"))
    tm = TrueModel(specs["full"])
    out = tip_output(tm.spec)
    steps, cfgs, late = 120, {}, {}
    t = np.arange(steps + 10 + 1)[1:] * 0.05
    R = np.stack([0.2 * np.sin(1.5 * t), -0.1 + 0.1 * np.cos(1.5 * t)], axis=1)
    for name, rate in (("constant", 0.0), ("rate", 0.053)):
        cfgs[name] = MPCConfig(horizon=10, dt=0.05, weight_y=1e2, weight_du=1e-3,
                               codegen=False, offset_free=0.3, offset_free_rate=rate)
        mpc = MPC(from_true(TrueModel(str(wrong)), out), cfgs[name])
        res = closed_loop(mpc, plant(tm, 0.05), np.zeros(2 * tm.n), R, steps,
                          u0=np.zeros(tm.m))
        assert metrics(res)["failures"] == 0, name
        e = np.linalg.norm(res["y"][1:] - res["r"][1:], axis=1)
        late[name] = float(np.sqrt(np.mean(e[60:] ** 2)))
        if rate:
            assert np.linalg.norm(mpc.disturbance_rate) > 0
        else:
            assert not np.any(mpc.disturbance_rate)
    assert late["rate"] < 0.5 * late["constant"], late  # 2.5x closer
    with pytest.raises(UserError, match=r"offset_free_rate: expected a gain in \[0, 1\]"):
        MPCConfig(offset_free=0.3, offset_free_rate=-0.1)
    with pytest.raises(UserError, match=r"needs the disturbance estimate on \(an offset-free"):
        MPCConfig(offset_free_rate=0.05)


def test_a_rest_start_gives_the_estimate_the_models_miss_at_once(specs, tmp_path):
    """Held at a target it rests on, the stiff model's controller moves the arm off it until
    the estimate has learnt the offset; started from the model's miss at that rest state
    (closed_loop sees the arm still: at_rest), the arm does not move at all."""
    wrong = tmp_path / "stiff.toml"
    wrong.write_text(MSD_SPEC_FULL.replace("springs = [2.1, 4.6]", "springs = [2.73, 5.98]"))
    tm = TrueModel(specs["full"])
    out = tip_output(tm.spec)
    q_star, u_star = equilibrium(tm, [0.3, -0.2])
    x0 = np.concatenate([q_star, np.zeros(tm.n)])
    cfg = MPCConfig(horizon=10, dt=0.05, weight_y=1e2, weight_du=1e-3, codegen=False,
                    offset_free=0.5)
    R = np.tile(np.asarray(out(q_star)).ravel(), (30 + cfg.horizon, 1))
    worst = {}
    for at_rest in (False, None):
        mpc = MPC(from_true(TrueModel(wrong), out), cfg)
        res = closed_loop(mpc, plant(tm, cfg.dt), x0, R, 30, u0=u_star, at_rest=at_rest)
        worst[at_rest] = metrics(res)["error_max"]
        assert res["at_rest"] is (at_rest is None)
    assert worst[False] > 1e-3, worst  # a few steps of the model's own equilibrium
    assert worst[None] < 1e-3 * worst[False], worst
    # not at rest (moving, or the plant not still under u0): the estimate starts at zero
    res = closed_loop(MPC(from_true(TrueModel(wrong), out), cfg), plant(tm, cfg.dt), x0, R, 2,
                      u0=np.zeros(tm.m))
    assert res["at_rest"] is False


def test_sqp_finds_the_ipopt_optimum(specs):
    """Both solvers minimise the same problem: the same first input to 1e-6."""
    tm = TrueModel(specs["forced"])
    out = tip_output(tm.spec)
    R = np.tile([0.3, 0.3], (10, 1))
    q, qd = np.array([0.1, -0.1]), np.array([0.2, 0.0])
    u = {}
    for solver in ("sqp", "ipopt"):
        cfg = MPCConfig(horizon=10, dt=0.05, solver=solver, codegen=False, tol=1e-10,
                        max_iter=100, u_min=(-3.0,), u_max=(3.0,))
        u[solver], info = MPC(from_true(tm, out), cfg).solve(q, qd, R, np.zeros(1))
        assert info["success"], info
    np.testing.assert_allclose(u["sqp"], u["ipopt"], atol=1e-6)


def _stage_sens(field, frozen, x, u, dt=0.05, substeps=3):
    from softpinn.bridge.control.rk4 import _stage_functions

    stage, roll = _stage_functions(field, dt, substeps, frozen=frozen)
    return [np.asarray(v) for v in stage(x, u)], np.asarray(roll(x, u))


def test_frozen_sensitivities_are_rk4s_own_on_a_linear_field(specs):
    """For a linear field the frozen Jacobian is the Jacobian: the closed form P^s,
    (I + ... + P^{s-1}) h Q B equals RK4's variational equations to rounding."""
    from softpinn.bridge.control import linearised

    tm = TrueModel(specs["full"])
    lin = linearised(tm, [0.2, -0.1, 0.0, 0.0], [0.5, -0.3], tip_output(tm.spec))
    x, u = np.array([0.3, -0.2, 0.4, 0.1]), np.array([0.7, -0.2])
    (y1, A1, B1), r1 = _stage_sens(lin.field, False, x, u)
    (y2, A2, B2), r2 = _stage_sens(lin.field, True, x, u)
    np.testing.assert_allclose(y2, y1, rtol=0, atol=1e-14)
    np.testing.assert_allclose(r2, r1, rtol=0, atol=1e-14)
    np.testing.assert_allclose(A2, A1, rtol=0, atol=1e-13)
    np.testing.assert_allclose(B2, B1, rtol=0, atol=1e-13)


def test_frozen_sensitivities_are_second_order_on_a_nonlinear_arm():
    """Task 4's spatial arm (nonlinear), near its hanging equilibrium and moving: the stage's
    state is the exact RK4 step; the frozen sensitivities (the Jacobian at the step's
    midpoint) differ from the exact ones by O(h²): halving the step quarters their error
    (2 % at 20 ms)."""
    from softpinn.bridge.control import default_center

    tm = TrueModel("task4")
    field = from_true(tm, tip_output(tm.spec)).field
    qc, uc = equilibrium(tm, default_center(tm.spec))
    rng = np.random.default_rng(3)
    x = np.concatenate([qc + rng.uniform(-0.05, 0.05, tm.n), rng.uniform(-0.5, 0.5, tm.n)])
    errors = []
    for dt in (0.02, 0.01):
        (y1, A1, B1), _ = _stage_sens(field, False, x, uc, dt=dt, substeps=2)
        (y2, A2, B2), r2 = _stage_sens(field, True, x, uc, dt=dt, substeps=2)
        np.testing.assert_array_equal(y2, r2)  # the stage's state is the roll's
        np.testing.assert_allclose(y2, y1, rtol=0, atol=1e-13)
        errors.append((np.linalg.norm(A2 - A1) / np.linalg.norm(A1 - np.eye(len(x))),
                       np.linalg.norm(B2 - B1) / np.linalg.norm(B1)))
    (a20, b20), (a10, b10) = errors
    assert 0 < a10 < 0.01 and 0 < b10 < 1e-3, errors
    assert 3.2 < a20 / a10 < 4.5 and 3.2 < b20 / b10 < 4.5, errors  # second order in h


@pytest.mark.parametrize("mode", ["frozen", "lifted"])
def test_approximate_sensitivities_converge_to_the_same_step(specs, mode):
    """An inexact-Jacobian SQP: the same closed-loop target, reached as closely."""
    cfg = MPCConfig(horizon=10, dt=0.05, weight_y=1e2, weight_du=1e-3,
                    sensitivities=mode, codegen=False)
    _, q_star, u_star, res = _loop(specs["full"], [0.3, -0.2], steps=40, config=cfg)
    m = metrics(res)
    assert m["failures"] == 0 and not m["diverged"]
    assert m["error_final"] < 1e-6, m
    if mode == "lifted":
        assert m["lifted_iterations"] >= 30, m  # all but the first and the transient's
    np.testing.assert_allclose(res["u"][-1], u_star, atol=1e-4)


def test_sensitivities_refused_where_they_do_not_apply():
    with pytest.raises(UserError, match="sensitivities: lifted is the SQP's"):
        MPCConfig(solver="ipopt", sensitivities="lifted")
    with pytest.raises(UserError, match="sensitivities: expected one of exact, frozen, lifted"):
        MPCConfig(sensitivities="approximate")


def test_the_lifted_step_about_the_exact_states_is_the_frozen_step():
    """Task 4's arm (nonlinear). Linearised about the plan's own predicted states (δ₀ = 0, no
    change of the disturbance), the lifted Gauss-Newton step is the frozen one: f, g, H to
    rounding. A measurement off the prediction, or a new disturbance estimate, moves f as the
    rollout does, to the frozen sensitivities' accuracy (the correction
    δ_{k+1} = A_k δ_k + Δd̂ uses them): under a hundredth of the change at either size."""
    from softpinn.bridge.control import default_center

    tm = TrueModel("task4")
    cfg = MPCConfig(horizon=6, dt=0.02, sensitivities="lifted", codegen=False)
    mpc = MPC(from_true(tm, tip_output(tm.spec)), cfg)
    qc, uc = equilibrium(tm, default_center(tm.spec))
    rng = np.random.default_rng(0)
    x0 = np.concatenate([qc + rng.uniform(-0.02, 0.02, 3), rng.uniform(-0.1, 0.1, 3)])
    U = uc[:, None] + rng.uniform(-0.2, 0.2, (3, 6))
    R = np.asarray(tip_output(tm.spec)(qc)).ravel()[:, None] + rng.uniform(-0.01, 0.01, (3, 6))
    up, d, nothing = uc, rng.uniform(-1e-4, 1e-4, 6), np.zeros(6)
    _, X = mpc._cost(x0, U, R, up, d)
    Xb = np.asarray(X)[:, :6]
    lifted = [np.asarray(v) for v in mpc._gn_lifted(x0, Xb, U, R, up, d, nothing)]
    frozen = [np.asarray(v) for v in mpc._gn(x0, U, R, up, d)]
    for a, b in zip(lifted, frozen, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-14)

    def f(fn, *args):
        return np.asarray(fn(*args)[0]).item()

    ratios = []
    for scale in (1e-3, 1e-4):
        dx = scale * np.array([1.0, -2.0, 1.5, 3.0, -1.0, 2.0])
        moved = f(mpc._gn_lifted, x0 + dx, Xb, U, R, up, d, nothing)
        true = f(mpc._gn, x0 + dx, U, R, up, d)
        ratios.append(abs(moved - true) / abs(true - frozen[0].item()))
        # a new disturbance estimate: the base was predicted with d, this plan adds d + Δ
        dd = 0.1 * dx
        moved = f(mpc._gn_lifted, x0, Xb, U, R, up, d + dd, dd)
        true = f(mpc._gn, x0, U, R, up, d + dd)
        ratios.append(abs(moved - true) / abs(true - frozen[0].item()))
    assert max(ratios) < 0.01, ratios


def test_a_frozen_step_that_fails_is_redone_with_exact_sensitivities(specs):
    """Where the frozen sensitivities give no descent (here: their gradient turned the wrong
    way, so the line search fails), the iteration is redone with the exact ones, counted."""
    tm = TrueModel(specs["full"])
    cfg = MPCConfig(horizon=8, dt=0.05, sensitivities="frozen", codegen=False)
    mpc = MPC(from_true(tm, tip_output(tm.spec)), cfg)
    good = mpc._gn

    def wrong(*args):
        f, g, H = good(*args)
        return f, -g, H

    mpc._gn = wrong
    R = np.tile([0.3, -0.2], (8, 1))
    u, info = mpc.solve(np.zeros(2), np.zeros(2), R, np.zeros(2))
    assert info["success"] and info["exact_iterations"] == 1, info
    exact = MPC(from_true(tm, tip_output(tm.spec)),
                MPCConfig(horizon=8, dt=0.05, codegen=False))
    u_exact, info_exact = exact.solve(np.zeros(2), np.zeros(2), R, np.zeros(2))
    np.testing.assert_allclose(u, u_exact, rtol=0, atol=1e-12)
    assert "exact_iterations" not in info_exact


def test_an_approximate_step_short_of_its_predicted_decrease_is_redone_exactly(specs):
    """Frozen sensitivities whose Gauss-Newton model is off (here: its Hessian a fifth of the
    true one, so the step is five times too long and the cost rises): the step is not
    shortened until the Armijo test passes, the iteration is redone with the exact
    sensitivities, and the input is the exact controller's."""
    tm = TrueModel(specs["full"])
    cfg = MPCConfig(horizon=8, dt=0.05, sensitivities="frozen", codegen=False)
    mpc = MPC(from_true(tm, tip_output(tm.spec)), cfg)
    good = mpc._gn
    mpc._gn = lambda *args: (lambda f, g, H: (f, g, 0.2 * H))(*good(*args))
    R = np.tile([0.3, -0.2], (8, 1))
    u, info = mpc.solve(np.zeros(2), np.zeros(2), R, np.zeros(2))
    assert info["success"] and info["exact_iterations"] == 1, info
    exact = MPC(from_true(tm, tip_output(tm.spec)),
                MPCConfig(horizon=8, dt=0.05, codegen=False))
    np.testing.assert_allclose(u, exact.solve(np.zeros(2), np.zeros(2), R, np.zeros(2))[0],
                               rtol=0, atol=1e-12)


def test_a_qp_answer_within_the_solvers_tolerance_of_the_box_is_kept(specs):
    """daqp stops within its feasibility tolerance: a step 1e-6 outside a bound is clipped
    and used; one a tenth of the box outside is a failed QP."""
    tm = TrueModel(specs["forced"])
    cfg = MPCConfig(horizon=3, dt=0.05, u_min=(-1.0,), u_max=(1.0,), codegen=False)
    mpc = MPC(from_true(tm, tip_output(tm.spec)), cfg)
    H, g, U = np.eye(3), np.array([-5.0, 0.0, 0.0]), np.zeros(3)
    for miss, kept in ((1e-6, True), (0.2, False)):
        mpc._qp = lambda miss=miss, **kw: {"x": np.array([1.0 + miss, 0.0, 0.0])}
        mpc._qp.stats = lambda: {"success": True}
        d, ok = mpc._qp_step(H, g, U)
        assert ok is kept, (miss, d)
        if kept:
            np.testing.assert_array_equal(d, [1.0, 0.0, 0.0])


def test_input_bounds_hold(specs):
    cfg = MPCConfig(horizon=10, dt=0.05, u_min=(-0.5,), u_max=(0.7,), codegen=False)
    _, _, _, res = _loop(specs["forced"], [0.3, 0.3], steps=20, config=cfg)
    assert metrics(res)["failures"] == 0
    assert res["u"].max() <= 0.7 + 1e-9 and res["u"].min() >= -0.5 - 1e-9
    assert res["u"].max() == pytest.approx(0.7)  # the bound is active at the start


def test_default_input_bounds_cover_the_inputs_simulate_draws(tmp_path):
    """The default bounds contain every input of the spec's data set, with a quarter of the
    range to spare: a multisine sums its components beyond one amplitude, a one-number
    amplitude stands for every input and a missing offset is 0 (they used to give no bounds)."""
    from softpinn.bridge.control import default_input_bounds
    from softpinn.symbolic import load_spec
    from softpinn.symbolic import make_dataset as simulate_data

    path = tmp_path / "arm.toml"
    path.write_text(MSD_SPEC_FULL + """
[data]
signal = "multisine"
components = 3
amplitude_low = 0.1
amplitude_high = 0.5
frequency_low = 0.2
frequency_high = 2.0
trajectories = 3
duration = 4.0
rate = 50.0
""")
    spec = load_spec(str(path))
    lo, hi = default_input_bounds(spec)
    u = simulate_data(spec, compile=False).u
    width = u.max(axis=0) - u.min(axis=0)
    assert np.all(width > 0.5)  # the components sum beyond one amplitude
    assert np.all(lo <= u.min(axis=0) - 0.2 * width) and np.all(hi >= u.max(axis=0) + 0.2 * width)
    # no input that moves: no bounds
    still = tmp_path / "still.toml"
    still.write_text(MSD_SPEC_FULL.replace("msd-full", "still") + '[data]\nsignal = "zero"\n'
                     'q0_low = [-0.1, -0.1]\nq0_high = [0.1, 0.1]\n')
    assert default_input_bounds(load_spec(str(still))) is None


def test_a_stiff_model_gets_more_substeps(specs):
    import casadi as ca

    tm = TrueModel(specs["forced"])
    x, u = ca.SX.sym("x", 4), ca.SX.sym("u", 1)
    stiff = ca.Function("field", [x, u], [ca.vertcat(x[2:], -500.0 * x[2:] + u)])
    model = PredictionModel("stiff", 2, 1, stiff, lambda q, qd: np.concatenate([q, qd]),
                            tip_output(tm.spec))
    cfg = MPCConfig(horizon=5, dt=0.02, substeps=1, codegen=False)
    point = (np.zeros(2), np.zeros(2), np.zeros(1))
    assert MPC(model, cfg, operating_point=point).substeps == 7  # 0.02 * 500 / 1.5
    assert MPC(model, cfg).substeps == 1


def test_circle_and_step_on_a_spatial_arm():
    """task 4 with the true model: the tip follows a horizontal circle to a tenth of a mm and
    settles on a step target (the reference holds it past the end: no step is anticipated)."""
    totals, steps = [], []
    config = ControlConfig(mpc=MPCConfig(horizon=10), references=("circle", "step"),
                           duration=0.4, include_linear=False)
    result = compare("task4", [], None, config, progress=lambda: steps.append(len(totals)),
                     progress_total=totals.append)
    assert totals == [40] and steps == [1] * 40  # the bar's total, told before the first step
    step = result["results"]["step"]["true"]
    assert step["error_max"] > 1e-3 and step["error_final"] < 1e-6, step
    m = result["results"]["circle"]["true"]
    assert m["failures"] == 0 and m["steps"] == 20
    assert m["error_max"] < 1e-4, m
    y = result["traces"]["circle"]["true"]["y"]
    assert y.shape == (21, 3)
    np.testing.assert_allclose(np.linalg.norm(y[:, :2], axis=1), np.linalg.norm(y[0, :2]),
                               rtol=1e-2)  # round the vertical axis


def test_step_reference_switches_after_each_hold():
    import casadi as ca

    q = ca.SX.sym("q", 1)
    out = ca.Function("output", [q], [q])
    R = step_reference(out, [[1.0], [2.0]], 0.5, np.arange(1, 9) * 0.25)
    assert R.ravel().tolist() == [1, 1, 2, 2, 1, 1, 2, 2]


def test_learned_models_close_the_loop(specs, runs, tmp_path):
    """Tiny Lagrangian and Hamiltonian runs, exported in-process, steer the chain; everything
    is written and every metric is a finite number."""
    out = tmp_path / "ctl"
    cfg = MPCConfig(horizon=8, dt=0.05, u_min=(-5.0,), u_max=(5.0,), codegen=False)
    result = compare(specs["forced"], [runs("lagrangian"), runs("hamiltonian")], out,
                     ControlConfig(mpc=cfg, duration=0.5))
    assert list(result["controllers"]) == ["true", "lagrangian", "hamiltonian", "linearised"]
    for rname in ("circle", "step"):
        for name, m in result["results"][rname].items():
            assert m["steps"] == 10 and not m["diverged"], (rname, name)
            for key in ("error_rms", "error_max", "effort_rms", "solve_ms_mean", "solve_ms_max"):
                assert np.isfinite(m[key]), (rname, name, key)
    saved = json.loads((out / "results.json").read_text())
    assert saved["format"] == "softpinn-control" and "traces" not in saved
    assert saved["controllers"]["hamiltonian"]["state_kind"] == "momentum"
    for f in ("report.md", "traces/circle.npz", "figures/paths_circle.png",
              "figures/tracking_step.png", "figures/solve_circle.png",
              "figures/inputs_step.png", "models/lagrangian/model.json"):
        assert (out / f).is_file(), f
    with np.load(out / "traces" / "step.npz") as traces:
        assert traces["lagrangian__u"].shape == (10, 1)
        assert traces["t"][-1] == pytest.approx(0.5)
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["command"] == "control" and "results.json" in manifest["files"]
    report = (out / "report.md").read_text()
    assert "| hamiltonian |" in report and "![paths_circle](figures/paths_circle.png)" in report


def test_leaving_the_training_data_is_found_and_reported(specs, runs, tmp_path):
    """outside_data counts the steps whose q leaves the range by more than the margin; the
    comparison checks every learned controller's loop against its training data's range and
    says so in the CLI line and the report."""
    from softpinn.bridge.control.compare import _line
    from softpinn.bridge.control.loop import outside_data
    from softpinn.bridge.control.report import _outside_lines

    rng = {"min": [0.0, -1.0], "max": [1.0, 1.0]}
    x = np.array([[0.5, 0.0, 9.0, 9.0],     # the start: not counted
                  [1.04, 0.0, 0.0, 0.0],    # within the 5 % margin
                  [1.06, 0.0, 0.0, 0.0],    # q1 out
                  [0.5, -1.2, 0.0, 0.0],    # q2 out
                  [0.5, 0.0, 0.0, 0.0]])
    got = outside_data(x, rng, 0.1, ["a", "b"])
    assert got == {"steps": 2, "first_s": pytest.approx(0.2), "coordinates": ["a", "b"],
                   "margin": 0.05}
    assert outside_data(x[:2], rng, 0.1)["first_s"] is None
    # a loop that leaves: in the CLI line and the report's sentence
    met = {"error_rms": 1e-3, "error_max": 2e-3, "solve_ms_mean": 1.0, "solve_ms_max": 2.0,
           "failures": 0, "diverged": False, "steps": 4, "outside_data": got}
    assert "left its training data's configurations at 0.20 s (2 of 4 steps: a, b)" in \
        _line("step", "hamiltonian", met, "m")
    assert "hamiltonian from 0.20 s, 2 steps (a, b)" in _outside_lines({"hamiltonian": met})[0]
    assert _outside_lines({"true": {}}) == []
    # the comparison: learned controllers are checked, the true model is not
    cfg = MPCConfig(horizon=8, dt=0.05, u_min=(-5.0,), u_max=(5.0,), codegen=False)
    result = compare(specs["forced"], [runs("lagrangian")], tmp_path / "c",
                     ControlConfig(mpc=cfg, duration=0.3, references=("step",),
                                   include_linear=False))
    per = result["results"]["step"]
    assert "outside_data" not in per["true"]
    away = per["lagrangian"]["outside_data"]
    assert away["steps"] >= 0 and set(away) == {"steps", "first_s", "coordinates", "margin"}
    report = (tmp_path / "c" / "report.md").read_text()
    assert ("stayed within its training data" in report) == (away["steps"] == 0)
    assert ("**Outside the training data**" in report) == (away["steps"] > 0)


def test_hamiltonian_state_is_momentum(specs, runs, tmp_path):
    from softpinn.learn import load_run

    tm = TrueModel(specs["forced"])
    model = from_run(runs("hamiltonian"), tip_output(tm.spec), export_dir=tmp_path / "x")
    q, qd = np.array([0.2, -0.1]), np.array([0.3, 0.4])
    M = np.asarray(load_run(runs("hamiltonian")).model.matrices(q)["M"])
    np.testing.assert_allclose(model.to_state(q, qd), np.concatenate([q, M @ qd]), atol=1e-10)
    # an export directory is a RUN too
    assert resolve_run(tmp_path / "x") == (tmp_path / "x", "export")


def test_black_box_is_rebuilt_in_mx(specs, runs, tmp_path):
    """A black box's field comes back as MX from its weights (its SX Jacobian would be huge),
    agrees with the exported SX field, and both solvers run with it."""
    from softpinn.bridge.export import load_exported

    tm = TrueModel(specs["forced"])
    model = from_run(runs("blackbox"), tip_output(tm.spec), export_dir=tmp_path / "bb")
    assert model.field.is_a("MXFunction") and model.info["field"].startswith("MX")
    sx = load_exported(tmp_path / "bb")["field"]
    x, u = np.array([0.3, -0.2, 0.1, 0.5]), np.array([0.7])
    np.testing.assert_allclose(np.asarray(model.field(x, u)), np.asarray(sx(x, u)), atol=1e-12)
    R = np.tile([0.2, 0.2], (5, 1))
    for solver in ("sqp", "ipopt"):
        mpc = MPC(model, MPCConfig(horizon=5, dt=0.05, solver=solver, codegen=solver == "sqp",
                                   u_min=(-2.0,), u_max=(2.0,)))
        u0, info = mpc.solve(np.zeros(2), np.zeros(2), R, np.zeros(1))
        assert np.all(np.isfinite(u0)) and info["iterations"] >= 1, (solver, info)


def _cli(capsys, *argv):
    status = cli.main(["control", *map(str, argv)])
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def test_cli_control(specs, runs, tmp_path, capsys):
    args = ("--reference", "step", "--duration", "0.2", "--horizon", "5", "--rate", "20",
            "--quiet")
    status, out, err = _cli(capsys, specs["forced"], "--runs", runs("lagrangian"), "--out",
                            tmp_path / "ok", *args)
    assert status == 0 and err == "", err
    assert "step:" in out and "lagrangian" in out and "wrote" in out
    assert (tmp_path / "ok" / "report.md").is_file()
    # a rerun into its own folder needs no --force
    status, out, _ = _cli(capsys, specs["forced"], "--out", tmp_path / "ok", "--json", *args)
    assert status == 0 and json.loads(out)["model"] == "test-msd"


def test_cli_bad_inputs(specs, runs, tmp_path, capsys):
    run = runs("lagrangian")

    def error(*argv):
        status, _, err = _cli(capsys, *argv)
        assert status == 2 and err.startswith("softpinn: error: ") and err.count("\n") == 1, err
        assert "Traceback" not in err
        return err

    a = tmp_path / "a"
    (tmp_path / "empty").mkdir()
    assert "not a softpinn run directory" in error(specs["forced"], "--runs", tmp_path / "empty",
                                                   "--out", a)
    assert "no such directory" in error(specs["forced"], "--runs", tmp_path / "nope", "--out", a)
    err = error(specs["forced"], "--runs", run, "--member", 5, "--out", a)
    assert "--member 5" in err and "single-model run" in err
    assert "has no inputs" in error("task1", "--out", a)
    # a run of another arm: named, with its size and data, before anything is exported
    err = error("task4", "--runs", run, "--out", a)
    assert f"runs: {run} models an arm of n = 2 coordinates (trained on test-msd data); the " \
        "plant has" in err
    assert "--center: expected 2" in error(specs["forced"], "--center", 0.1, "--out", a)
    assert "--u-min: expected 1 values" in error(specs["forced"], "--u-min", 1, 2, "--out", a)
    assert "--rate" in error(specs["forced"], "--rate", 0, "--out", a)
    assert "--horizon: expected an integer >= 1" in error(specs["forced"], "--horizon", 0,
                                                          "--out", a)
    assert "--stiffness: expected a finite number >= 0" in error(specs["forced"], "--stiffness",
                                                                 -1, "--out", a)
    err = error(specs["forced"], "--offset-free-rate", 0.05, "--out", a)
    assert err.startswith("softpinn: error: --offset-free-rate: needs") and "offset-free" in err
    (tmp_path / "file").write_text("x")
    assert "is a file" in error(specs["forced"], "--out", tmp_path / "file")
    assert "is a file" in error(specs["forced"], "--out", tmp_path / "file" / "sub")
    user = tmp_path / "user"
    user.mkdir()
    (user / "notes.txt").write_text("mine")
    err = error(specs["forced"], "--out", user, "--duration", "0.1")
    assert "--out" in err and "--force" in err
    assert not a.exists()  # nothing was written for a bad input
    if os.geteuid() != 0:  # root writes anywhere
        ro = tmp_path / "ro"
        ro.mkdir(mode=0o500)
        assert "cannot write there" in error(specs["forced"], "--out", ro / "sub")
    status, _, _ = _cli(capsys, specs["forced"], "--out", user, "--force", "--duration", "0.1",
                        "--quiet", "--reference", "step", "--no-linear")
    assert status == 0 and (user / "notes.txt").read_text() == "mine"


def test_library_errors_are_user_errors(specs):
    with pytest.raises(UserError, match="weight_y: must be > 0"):
        MPCConfig(weight_y=0)
    with pytest.raises(UserError, match="qpsol: expected one of"):
        MPCConfig(qpsol="nope")
    with pytest.raises(UserError, match=r"offset_free: expected a gain in \[0, 1\]"):
        MPCConfig(offset_free=1.5)
    with pytest.raises(UserError, match="reference: expected one of"):
        ControlConfig(references=("square",))
    for kw, expected in ((dict(references=()), "reference: give at least one reference"),
                         (dict(radius=-1.0), "radius: expected a finite number >= 0"),
                         (dict(period=0.0), "period: expected a number of seconds > 0"),
                         (dict(hold=float("nan")), "hold: expected a number of seconds > 0"),
                         (dict(duration=-2.0), "duration: expected a number of seconds > 0"),
                         (dict(mpc={"horizon": 4}), "mpc: expected an MPCConfig")):
        with pytest.raises(UserError, match=expected):
            ControlConfig(**kw)
    with pytest.raises(UserError, match="config: expected a ControlConfig"):
        compare(specs["forced"], [], None, MPCConfig())
    with pytest.raises(UserError, match="center: expected 2 finite coordinates"):
        compare(specs["forced"], [], None, ControlConfig(center=(0.1, 0.2, 0.3)))
    assert ControlConfig(references=["step", "circle", "step"], center=[0, 1]) == ControlConfig(
        references=("step", "circle"), center=(0.0, 1.0))
    tm = TrueModel(specs["forced"])
    mpc = MPC(from_true(tm, tip_output(tm.spec)), MPCConfig(horizon=4, codegen=False))
    with pytest.raises(UserError, match=r"reference: expected shape \(4, 2\)"):
        mpc.solve(np.zeros(2), np.zeros(2), np.zeros((3, 2)), np.zeros(1))


def test_controllers_are_named_for_their_model(tmp_path):
    """A run trained with a known input matrix, or a Hamiltonian network trained on velocities,
    is named for it (a table reading "hamiltonian" and "hamiltonian-2" would hide which is
    which); a run and its export get the same name."""
    from softpinn.bridge.control.compare import _run_kind

    cases = (("network", "data", "hamiltonian"), ("known", "data", "hamiltonian, A known"),
             ("known", "velocity", "hamiltonian from q̇, A known"),
             ("network", "velocity", "hamiltonian from q̇"))
    for i, (form, momenta, expected) in enumerate(cases):
        model = {"kind": "hamiltonian", "input_form": form}
        train = {"model": model, "momenta": momenta}
        run = tmp_path / f"run-{i}"
        run.mkdir()
        (run / "config.json").write_text(json.dumps({"model": model, "train": train}))
        export = tmp_path / f"export-{i}"
        export.mkdir()
        (export / "model.json").write_text(json.dumps(
            {"format": "softpinn-export", "kind": "hamiltonian",
             "training": {"model": model, "train": train}}))
        assert _run_kind(run) == _run_kind(export) == expected
