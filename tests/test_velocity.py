"""Hamiltonian networks trained on velocity data (learn/_velocity.py, issue 18 part 3): the map
p = M̂ q̇ -> RK4 step of eq. 7 -> q̇ = M̂⁻¹ p against the Lagrangian form of the same known system,
the scale the velocities cannot see, training on a file without momenta, and bad input."""

from __future__ import annotations

import json

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from datagen import make_dataset, simulate, tiny_model_config, write
from known_fields import Field, MassField

from softpinn.errors import UserError
from softpinn.learn._integrate import step as _step
from softpinn.learn._models import HamiltonianNet, LagrangianNet, ModelConfig
from softpinn.learn._velocity import (
    measured_momenta,
    momenta_from_velocities,
    resolve_momenta,
    velocities_from_momenta,
)

jax.config.update("jax_enable_x64", True)


def _mass(q):
    """A configuration-dependent SPD mass matrix (n = 2)."""
    c = jnp.cos(q[1])
    return jnp.array([[2.0 + c, 0.3 + 0.5 * c], [0.3 + 0.5 * c, 1.2]])


def _fields(scale=1.0):
    """M⁻¹ (for the Hamiltonian form) or M, V, D, A of one known system; ``scale`` c gives
    (c M⁻¹, V/c, D/c, A/c)."""
    pot = Field(lambda q: (1.5 * q[0] ** 2 + 0.8 * (1 - jnp.cos(q[1])) + 0.2 * q[0] * q[1])
                / scale)
    damp = Field(lambda q: jnp.array([[0.3, 0.05], [0.05, 0.2 + 0.1 * q[0] ** 2]]) / scale)
    inp = Field(lambda q: jnp.array([[1.0], [0.4 * jnp.sin(q[0])]]) / scale)
    return pot, damp, inp


def _hamiltonian(state, scale=1.0):
    cfg = ModelConfig(kind="hamiltonian", n=2, m=1, state_kind=state)
    pot, damp, inp = _fields(scale)
    return HamiltonianNet(config=cfg, mass=MassField(lambda q: scale * jnp.linalg.inv(_mass(q))),
                          potential=pot, damping=damp, input_map=inp)


def _lagrangian():
    pot, damp, inp = _fields()
    return LagrangianNet(config=ModelConfig(kind="lagrangian", n=2, m=1),
                         mass=MassField(_mass), potential=pot, damping=damp, input_map=inp)


step = eqx.filter_jit(_step)  # eager, a step dispatches hundreds of small ops
X = jnp.array([0.4, -0.7, 0.3, -0.5])
U0, U1 = jnp.array([0.6]), jnp.array([-0.2])


def test_velocity_map_and_step_are_exact_for_a_known_system():
    hv, hp, lag = _hamiltonian("velocity"), _hamiltonian("momentum"), _lagrangian()
    q, qd = X[:2], X[2:]
    # p = M q̇ and back
    y = momenta_from_velocities(hv, X)
    np.testing.assert_allclose(y[2:], _mass(q) @ qd, rtol=0, atol=1e-12)
    np.testing.assert_allclose(velocities_from_momenta(hv, y), X, rtol=0, atol=1e-12)
    # the vector field on (q, q̇): (q̇, q̈) of eq. 7 equals the Lagrangian form's (eq. 6)
    field = eqx.filter_jit(lambda model, x, u: model.vector_field(x, u))
    np.testing.assert_allclose(field(hv, X, U0), field(lag, X, U0), rtol=0, atol=1e-10)
    # one step: p₀ = M q̇₀, RK4 of eq. 7 in (q, p), q̇₁ = M⁻¹(q₁) p₁, with the analytic M
    kw = dict(input_hold="linear", substeps=2)
    y1 = step(hp, jnp.concatenate([q, _mass(q) @ qd]), U0, U1, 0.05, **kw)
    want = jnp.concatenate([y1[:2], jnp.linalg.solve(_mass(y1[:2]), y1[2:])])
    np.testing.assert_allclose(step(hv, X, U0, U1, 0.05, **kw), want, rtol=0, atol=1e-12)
    # and the Lagrangian form of the same system: RK4 in other coordinates, equal to O(dt^5)
    np.testing.assert_allclose(step(hv, X, U0, U1, 1e-3, **kw), step(lag, X, U0, U1, 1e-3, **kw),
                               rtol=0, atol=1e-10)
    assert float(jnp.max(jnp.abs(step(hv, X, U0, U1, 0.05, **kw) - X))) > 1e-3  # it moved


def test_velocities_do_not_see_the_scale_of_the_matrices():
    """(c M⁻¹, V/c, D/c, A/c) step (q, q̇) exactly as (M⁻¹, V, D, A): velocity data alone cannot
    pin the scale of M, D, G, A (only M⁻¹G, M⁻¹A u, ... are determined)."""
    a = step(_hamiltonian("velocity"), X, U0, U1, 0.05, input_hold="linear")
    b = step(_hamiltonian("velocity", scale=7.0), X, U0, U1, 0.05, input_hold="linear")
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)


def _no_momenta_file(path, **kw):
    arrays = simulate("msd", **kw)
    arrays.pop("p")
    return write(path, arrays, {"spec": {"name": "msd-no-p", "kind": "msd"}})


def test_momenta_choice_and_refusals(tmp_path):
    from softpinn.learn._data import load_dataset
    from softpinn.learn._train import TrainConfig

    with_p = load_dataset(make_dataset(tmp_path / "p.npz", trajectories=2, duration=1.0))
    no_p = load_dataset(_no_momenta_file(tmp_path / "nop.npz", trajectories=2, duration=1.0))
    assert no_p.p is None and measured_momenta(with_p) and not measured_momenta(no_p)
    imported = type(with_p)(**{**with_p.__dict__, "meta": {"source": "import"}})
    assert not measured_momenta(imported)
    ham = tiny_model_config("hamiltonian")
    auto = TrainConfig(model=ham, epochs=1)
    assert auto.momenta == "auto" and auto.model.state_kind == "momentum"
    got = resolve_momenta(auto, with_p)
    assert (got.momenta, got.model.state_kind) == ("data", "momentum")
    for data in (no_p, imported):
        got = resolve_momenta(auto, data)
        assert (got.momenta, got.model.state_kind) == ("velocity", "velocity")
    vel = TrainConfig(model=ham, epochs=1, momenta="velocity")
    assert vel.model.state_kind == "velocity"
    assert TrainConfig.from_dict(json.loads(json.dumps(vel.to_dict()))) == vel
    with pytest.raises(UserError, match=r"^momenta: 'data' needs momenta p .*--momenta velocity"):
        resolve_momenta(TrainConfig(model=ham, epochs=1, momenta="data"), no_p)
    with pytest.raises(UserError, match="momenta: 'velocity' is for Hamiltonian networks"):
        TrainConfig(model=tiny_model_config("lagrangian"), momenta="velocity")
    with pytest.raises(UserError, match="holds no momenta p"):
        no_p.state("momentum")


def test_cli_momenta_bad_input_is_one_line(tmp_path, capsys):
    from softpinn.bridge.cli import main

    path = _no_momenta_file(tmp_path / "nop.npz", trajectories=2, duration=1.0)
    base = ["train", str(path), "--out", str(tmp_path / "run"), "--epochs", "1", "--quiet"]
    cases = [(["--model", "hamiltonian", "--momenta", "data"], "momenta: 'data' needs momenta p"),
             (["--model", "lagrangian", "--momenta", "velocity"],
              "momenta: 'velocity' is for Hamiltonian networks"),
             (["--model", "hamiltonian", "--mass-init", "data"], "holds no momenta p")]
    for flags, message in cases:
        assert main(base + flags) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and message in err[0], err
    with pytest.raises(SystemExit) as exc:
        main(base + ["--model", "hamiltonian", "--momenta", "estimated"])
    assert exc.value.code == 2
    assert "--momenta: invalid choice" in capsys.readouterr().err


def test_velocity_trained_hamiltonian_on_a_file_without_momenta(tmp_path):
    """Task 1's two-mass chain (eq. 25, forced on mass 2) without momenta in the file: the
    Hamiltonian network trains on (q, q̇) by itself (auto -> velocity), predicts, resumes, and
    learns the accelerations, which velocity data determine (measured: test loss 4.3e-6, q̈
    6.7 % off on the test trajectory, rollout error 8e-5). Its M⁻¹ they do not: M̂⁻¹ is 56 %
    off the true one even after the best scale c (c = 2.1-2.2), and was 96 % off after 100
    epochs and 76 % after 200 more L-BFGS iterations (docs/velocity.md: the transforms P(q)
    velocity data leave)."""
    from softpinn.learn._data import load_dataset
    from softpinn.learn._predict import predict
    from softpinn.learn._train import TrainConfig, load_run, train

    path = _no_momenta_file(tmp_path / "msd.npz", trajectories=5, duration=6.0, rate=20.0)
    cfg = TrainConfig(model=tiny_model_config("hamiltonian", mass=(16, 1), potential=(16, 1),
                                              damping_form="constant", input_form="constant"),
                      epochs=400, batch_size=64, lr=1e-2, test_trajectories=(4,),
                      checkpoint_every=1000, eval_every=20)
    res = train(path, cfg, tmp_path / "run", warn=lambda m: None)
    stored = json.loads((tmp_path / "run" / "config.json").read_text())
    assert stored["train"]["momenta"] == "velocity"
    assert stored["model"]["state_kind"] == "velocity"
    assert res.metrics["best_test_loss"]["mean"] < 2e-5
    run = load_run(tmp_path / "run")
    assert run.model.state_kind == "velocity"
    data = load_dataset(path)
    rows = data.traj == 4
    qdd = eqx.filter_jit(lambda model, q, qd, u: jax.vmap(model.qdd)(q, qd, u))(
        run.model, data.q[rows], data.qd[rows], data.u[rows])
    err = np.linalg.norm(np.asarray(qdd) - data.qdd[rows]) / np.linalg.norm(data.qdd[rows])
    assert err < 0.15, err
    pr = predict(tmp_path / "run", path, horizon=2.0)
    assert pr.rollout_error_mean < 1e-3
    # resume with more epochs: the stored choice holds ("auto" given: as decided)
    more = train(path, TrainConfig(**{**cfg.__dict__, "epochs": 410}), tmp_path / "run",
                 resume=True, warn=lambda m: None)
    assert more.config.momenta == "velocity"
