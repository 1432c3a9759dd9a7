"""The linear prior inside the networks (learn/_prior.py, issue 43): every model kind starts as
the least-squares linear model, training can only leave it for something better on the
validation trajectories, runs record and resume it, and the exporter writes the same force."""

from __future__ import annotations

import json
import shutil

import casadi as ca
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from datagen import make_dataset, simulate, tiny_model_config, write

from softpinn.bridge import cli
from softpinn.bridge.export import export_run, load_exported
from softpinn.bridge.export.dynamics import member_expressions
from softpinn.bridge.export.params import model_params
from softpinn.errors import UserError
from softpinn.learn import ModelConfig, TrainConfig, load_run, make_model, train
from softpinn.learn._baselines import fit_linear_second_order
from softpinn.learn._data import load_dataset
from softpinn.learn._output_error import fit_linear_rollout, window_error
from softpinn.learn._prior import prior_text, resolve_prior

N, M = 3, 2
QUIET_D = 0.03 ** 2  # the quiet damping network's D = (softplus(b) = 0.03)² I


def _random_prior(seed=0):
    rng = np.random.default_rng(seed)
    mats = {"K": rng.normal(size=(N, N)), "D": rng.normal(size=(N, N)),
            "B": rng.normal(size=(N, M)), "c": rng.normal(size=N)}
    return mats, prior_text(mats)


@pytest.mark.parametrize("kind", ["lagrangian", "lagrangian-hessian", "hamiltonian", "blackbox"])
@pytest.mark.parametrize("damping_form", ["network", "constant"])
def test_every_kind_starts_as_its_prior(kind, damping_form):
    mats, text = _random_prior()
    state = {"state_kind": "velocity"} if kind == "hamiltonian" else {}
    cfg = ModelConfig(kind=kind, n=N, m=M, prior=text, damping_form=damping_form, **state)
    model = make_model(cfg, key=jax.random.PRNGKey(3))
    rng = np.random.default_rng(1)
    for _ in range(3):
        q, qd, u = rng.normal(size=N), rng.normal(size=N), rng.normal(size=M)
        f0 = mats["B"] @ u + mats["c"] - mats["K"] @ q - mats["D"] @ qd
        want = f0 if kind == "blackbox" else f0 - QUIET_D * qd
        got = np.asarray(model.vector_field(jnp.concatenate([q, qd]), u))
        np.testing.assert_allclose(got[:N], qd, rtol=0, atol=1e-14)
        np.testing.assert_allclose(got[N:], want, rtol=1e-12, atol=1e-12)
        if kind != "blackbox":  # the matrices a report shows are the totals
            mat = model.matrices(q)
            np.testing.assert_allclose(mat["M"], np.eye(N), atol=1e-14)
            np.testing.assert_allclose(mat["G"], mats["K"] @ q - mats["c"], atol=1e-12)
            np.testing.assert_allclose(mat["A"], mats["B"], atol=1e-14)
            np.testing.assert_allclose(mat["D"], mats["D"] + QUIET_D * np.eye(N), atol=1e-12)


def test_the_prior_has_no_trainable_parameter():
    _, text = _random_prior()
    plain = make_model(ModelConfig(kind="lagrangian", n=N, m=M), key=jax.random.PRNGKey(0))
    with_prior = make_model(ModelConfig(kind="lagrangian", n=N, m=M, prior=text),
                            key=jax.random.PRNGKey(0))
    count = lambda mdl: sum(x.size for x in jax.tree_util.tree_leaves(mdl)
                            if isinstance(x, jax.Array))
    assert count(plain) == count(with_prior) > 0


@pytest.mark.parametrize("change, message", [
    ({"prior": "{"}, "prior must be JSON text"),
    ({"prior": json.dumps({"kind": "cubic"})}, "expected {'kind': 'linear'"),
    ({"prior": json.dumps({"kind": "linear", "K": [[1.0]], "D": [[0.0]], "B": [[1.0]],
                           "c": [0.0]})}, "'K' must be finite of shape (3, 3)"),
    ({"input_form": "known", "known_input": json.dumps({"kind": "constant",
                                                        "value": [[1.0] * M] * N})},
     "a linear prior and a known input matrix"),
    ({"kind": "blackbox", "state_kind": "momentum"}, "a linear prior needs a black box on"),
])
def test_bad_priors_are_refused_in_one_line(change, message):
    _, text = _random_prior()
    kw = {"kind": "lagrangian", "n": N, "m": M, "prior": text, **change}
    with pytest.raises(UserError, match=None) as err:
        ModelConfig(**kw)
    assert message in str(err.value) and "\n" not in str(err.value)


def test_a_prior_with_nan_is_refused():
    mats, _ = _random_prior()
    mats["K"][0, 0] = np.nan
    with pytest.raises(UserError, match="K.*NaN"):
        prior_text(mats)


def test_train_config_refuses_an_unknown_prior_setting():
    with pytest.raises(UserError, match="prior: expected one of"):
        TrainConfig(model=tiny_model_config("lagrangian"), prior="quadratic")


@pytest.fixture(scope="module")
def pendulum(tmp_path_factory):
    """A forced pendulum pair (nonlinear: a linear model cannot be exact), imported-looking."""
    arrays = simulate("pendulum", trajectories=5, duration=6.0, seed=2)
    meta = {"spec": {"name": "pend", "kind": "pendulum"}, "source": "import", "rate": 20.0}
    return write(tmp_path_factory.mktemp("pend") / "pend.npz", arrays, meta)


@pytest.fixture(scope="module")
def prior_run(pendulum, tmp_path_factory):
    n = load_dataset(pendulum).n
    cfg = TrainConfig(model=tiny_model_config("lagrangian", n=n), epochs=40, batch_size=16,
                      lr=1e-2, loss="accel", test_trajectories=(4,), validation=(3,),
                      checkpoint_every=1000, actuator="none")
    out = tmp_path_factory.mktemp("runs") / "lag"
    train(pendulum, cfg, out)  # prior "auto" on an imported file: linear
    return out


def test_auto_fits_the_prior_on_imports_only(pendulum, tmp_path):
    data = load_dataset(pendulum)
    text, note = resolve_prior("auto", data, np.array([0, 1]), np.array([2]))
    fits = [fit_linear_second_order(data, [0, 1]), fit_linear_rollout(data, [0, 1])]
    # the prior is the fit with the lower rollout error on the validation trajectory
    errors = [window_error(f, data, [2], horizon=fits[1].info["horizon"]) for f in fits]
    chosen = fits[int(np.argmin(errors))]
    assert json.loads(text)["K"] == (-chosen.A_q).tolist()
    assert "2 training trajectories" in note and "auto: imported recordings" in note
    assert f"least squares {errors[0]:.3g}, rollout fit {errors[1]:.3g}" in note
    assert "validation trajectories" in note
    simulated = make_dataset(tmp_path / "msd.npz", trajectories=2, duration=1.0)
    assert resolve_prior("auto", load_dataset(simulated), np.array([0])) == (None, None)
    assert resolve_prior("none", data, np.array([0])) == (None, None)
    assert resolve_prior("linear", load_dataset(simulated), np.array([0]))[0] is not None


def test_a_run_records_its_prior_and_never_ends_behind_it(prior_run):
    info = json.loads((prior_run / "config.json").read_text())
    assert info["train"]["prior"] == "linear"
    assert json.loads(info["model"]["prior"])["kind"] == "linear"
    assert "the networks learn the correction" in info["prior"]["note"]
    history = (prior_run / "history.csv").read_text().splitlines()
    header = history[0].split(",")
    rows = [dict(zip(header, line.split(","), strict=True)) for line in history[1:]]
    start = float(rows[0]["validation_loss"])  # epoch 0: the linear model itself
    picked = json.loads((prior_run / "metrics.json").read_text())["best_validation_loss"]
    assert picked <= start
    assert picked < 0.5 * start, "the networks learned nothing on top of the linear model"


def test_resume_keeps_the_prior(prior_run, pendulum, tmp_path):
    copy = tmp_path / "copy"
    shutil.copytree(prior_run, copy)
    stored = json.loads((copy / "config.json").read_text())
    cfg = TrainConfig.from_dict({**stored["train"], "epochs": 41, "prior": "auto",
                                 "model": {**stored["train"]["model"], "prior": None}})
    train(pendulum, cfg, copy, resume=True)
    again = json.loads((copy / "config.json").read_text())
    assert again["model"]["prior"] == stored["model"]["prior"]
    assert again["train"]["epochs"] == 41


@pytest.mark.usefixtures("session_cache")
def test_export_writes_the_same_force(prior_run, tmp_path):
    run = load_run(prior_run)
    export_run(prior_run, tmp_path / "x", compile=False)
    fns = load_exported(tmp_path / "x")
    model, n, m = run.model, run.model.config.n, run.model.config.m
    rng = np.random.default_rng(4)
    for _ in range(4):
        q, qd, u = rng.uniform(-1, 1, n), rng.uniform(-1, 1, n), rng.uniform(-1, 1, m)
        np.testing.assert_allclose(np.asarray(fns["qdd"](q, qd, u)).ravel(),
                                   np.asarray(model.qdd(q, qd, u)), rtol=1e-10, atol=1e-12)
        mats = model.matrices(q)
        for name in ("G", "D", "A"):
            np.testing.assert_allclose(np.asarray(fns[name](q)).reshape(mats[name].shape),
                                       np.asarray(mats[name]), rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("kind", ["hamiltonian", "blackbox"])
def test_export_of_other_kinds_with_a_prior(kind, tmp_path):
    _, text = _random_prior(5)
    state = {"state_kind": "velocity"} if kind == "blackbox" else {}
    model = make_model(tiny_model_config(kind, n=N, m=M, prior=text, **state),
                       key=jax.random.PRNGKey(2))
    sym = {k: ca.SX.sym(k, N) for k in ("q", "qd", "p")}
    sym |= {"x": ca.SX.sym("x", 2 * N), "u": ca.SX.sym("u", M)}
    expr = member_expressions(model_params(model), sym)
    field = ca.Function("f", [sym["x"], sym["u"]], [expr["field"]])
    rng = np.random.default_rng(6)
    x, u = rng.uniform(-1, 1, 2 * N), rng.uniform(-1, 1, M)
    np.testing.assert_allclose(np.asarray(field(x, u)).ravel(),
                               np.asarray(model.vector_field(jnp.asarray(x), jnp.asarray(u))),
                               rtol=1e-10, atol=1e-12)


def test_cli_prints_the_prior_and_refuses_a_bad_setting(pendulum, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["train", str(pendulum), "--prior", "cubic", "--out", str(tmp_path / "r")])
    assert exc.value.code == 2
    assert "invalid choice: 'cubic'" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()


def test_reproduce_takes_the_prior_for_the_experiment_and_cosserat_only():
    from softpinn.bridge.tasks import ReproduceConfig
    from softpinn.bridge.tasks.experiment import make_experiment_plan
    from softpinn.symbolic import load_spec

    with pytest.raises(UserError, match="--prior: only the experiment and cosserat"):
        ReproduceConfig("task1", prior="linear")
    with pytest.raises(UserError, match="--prior: expected one of"):
        ReproduceConfig("experiment", prior="cubic")
    spec = load_spec("experiment")
    plain = make_experiment_plan(spec, ReproduceConfig("experiment", quick=True))
    assert plain.prior == "none" and "prior" not in plain.to_dict()  # plan.json as before
    plan = make_experiment_plan(spec, ReproduceConfig("experiment", quick=True, prior="linear"))
    assert plan.to_dict()["prior"] == "linear"


def test_init_from_a_run_with_another_prior_says_how_to_match_it(prior_run, pendulum, tmp_path):
    stored = json.loads((prior_run / "config.json").read_text())
    cfg = TrainConfig.from_dict({**stored["train"], "prior": "none", "init": str(prior_run),
                                 "model": {**stored["train"]["model"], "prior": None}})
    with pytest.raises(UserError,
                       match=r"differs in prior\); the linear prior \(--prior\) is fitted"):
        train(pendulum, cfg, tmp_path / "again")
    assert not (tmp_path / "again").exists() or not any((tmp_path / "again").iterdir())
