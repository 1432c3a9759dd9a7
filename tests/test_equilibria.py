"""Static equilibria as labels (issue 18, "additional labels"): the symbolic equilibria, the
optional arrays of the dataset file, the label loss and its settings."""

from __future__ import annotations

import json

import jax.numpy as jnp
import numpy as np
import pytest
from datagen import make_dataset, msd_matrices
from known_fields import Field, MassField

from softpinn.bridge.cli import main
from softpinn.errors import UserError
from softpinn.learn._config import RESUMABLE, TrainConfig
from softpinn.learn._data import load_dataset
from softpinn.learn._losses import Equilibria, label_loss
from softpinn.learn._models import HamiltonianNet, LagrangianNet, ModelConfig
from softpinn.symbolic.model._true_model import TrueModel
from softpinn.symbolic.simulation import _datafile as datafile
from softpinn.symbolic.simulation._datatable import DataError
from softpinn.symbolic.simulation._equilibria import attach, equilibria, input_box
from softpinn.symbolic.spec._spec import load_spec


@pytest.fixture(scope="module")
def task4_eq():
    spec = load_spec("task4")
    return spec, equilibria(spec, 6, seed=3)


def test_equilibria_balance_and_are_stable(task4_eq):
    spec, eq = task4_eq
    lo, hi = input_box(spec)
    assert eq.q.shape == (6, 3) and eq.u.shape == (6, 3) and eq.force.shape == (6, 3)
    assert np.all(eq.u >= lo) and np.all(eq.u <= hi)
    true = TrueModel(spec)
    G, A = true.G(eq.q), true.A(eq.q)
    Au = np.einsum("kij,kj->ki", A, eq.u)
    assert np.max(np.abs(G - Au)) <= 1e-10
    np.testing.assert_allclose(eq.force, G, rtol=0, atol=1e-12)
    # stable: the stiffness d(G - A u*)/dq at q* by central differences has eigenvalues > 0
    h = 1e-6
    for q, u in zip(eq.q, eq.u, strict=True):
        r = lambda x, u=u: true.G(x[None])[0] - true.A(x[None])[0] @ u
        K = np.stack([(r(q + h * e) - r(q - h * e)) / (2 * h) for e in np.eye(3)], axis=1)
        assert np.min(np.linalg.eigvals(K).real) > 0
    # distinct draws, seeded
    assert len({tuple(np.round(u, 12)) for u in eq.u}) == 6
    again = equilibria(spec, 2, seed=3)
    np.testing.assert_array_equal(again.u, eq.u[:2])


def test_unstable_or_unreachable_equilibria_are_refused():
    spec = load_spec("task4")
    # gravity pulls the hanging arm to dL = 1.47 m without the tangent force; with a large push
    # the other way Newton's point is no stable rest: refused with the count of skips
    with pytest.raises(DataError, match=r"found 0 of 3 stable equilibria .* 3 unstable"):
        equilibria(spec, 3, low=[0.0, 0.0, 40.0], high=[0.0, 0.0, 60.0], max_draws=3)
    with pytest.raises(DataError, match="input box"):
        equilibria(spec, 1, low=[0.0], high=[1.0])


def test_file_round_trip_and_old_files(tmp_path, task4_eq):
    _, eq = task4_eq
    T = 6
    arrays = dict(t=np.tile(np.arange(3.0), 2), q=np.zeros((T, 3)), qd=np.zeros((T, 3)),
                  qdd=np.zeros((T, 3)), p=np.zeros((T, 3)), u=np.zeros((T, 3)),
                  traj=np.repeat(np.arange(2), 3))
    old = datafile.DatasetArrays(meta={"rate": 1.0}, **arrays)
    new = attach(old, eq)
    assert new.meta["equilibria"]["count"] == 6
    datafile.write_dataset(tmp_path / "new.npz", new)
    datafile.write_dataset(tmp_path / "old.npz", old)
    back = datafile.read_dataset(tmp_path / "new.npz")
    np.testing.assert_array_equal(back.eq_q, eq.q)
    np.testing.assert_array_equal(back.eq_force, eq.force)
    # kept through selection, resampling and splitting
    for sub in (datafile.select_trajectories(back, [1]), datafile.resample(back, 1.0),
                datafile.take_samples(back, 4)):
        np.testing.assert_array_equal(sub.eq_u, eq.u)
    learned = load_dataset(tmp_path / "new.npz")
    assert learned.equilibria == 6
    np.testing.assert_array_equal(learned.eq_u, eq.u)
    assert datafile.read_dataset(tmp_path / "old.npz").eq_q is None
    assert load_dataset(tmp_path / "old.npz").equilibria == 0
    with np.load(tmp_path / "old.npz") as z:
        assert "eq_q" not in z.files
    # a file with part of the equilibria, or a wrong shape, is refused with one line
    with np.load(tmp_path / "new.npz") as z:
        d = {k: z[k] for k in z.files}
    np.savez(tmp_path / "part.npz", **{k: v for k, v in d.items() if k != "eq_force"})
    with pytest.raises(UserError, match="but not eq_force"):
        load_dataset(tmp_path / "part.npz")
    np.savez(tmp_path / "bad.npz", **dict(d, eq_u=d["eq_u"][:, :2]))
    with pytest.raises(UserError, match="'eq_u' must have shape"):
        load_dataset(tmp_path / "bad.npz")


def _msd_model(kind="lagrangian", *, scale_G=1.0, alpha=1.0):
    """The mass-spring-damper of tests/datagen.py with known fields (scale_G != 1: a wrong
    potential; alpha: M, D, G, A all scaled together, the same dynamics)."""
    M, K, B, A = msd_matrices()
    cfg = ModelConfig(kind=kind, n=2, m=1)
    cls = LagrangianNet if kind == "lagrangian" else HamiltonianNet
    mass = np.linalg.inv(M) / alpha if kind == "hamiltonian" else alpha * M
    return cls(
        config=cfg,
        mass=MassField(lambda q: jnp.asarray(mass) + 0.0 * q[0]),
        potential=Field(lambda q: 0.5 * alpha * scale_G * q @ jnp.asarray(K) @ q),
        damping=Field(lambda q: alpha * jnp.asarray(B) + 0.0 * q[0]),
        input_map=Field(lambda q: alpha * jnp.asarray(A) + 0.0 * q[0]),
    )


def _msd_labels(count=5, seed=0):
    M, K, B, A = msd_matrices()
    u = np.random.default_rng(seed).uniform(-1, 1, size=(count, 1))
    q = np.linalg.solve(K, (A @ u.T)).T  # K q* = A u*
    f = q @ K.T
    return Equilibria(jnp.asarray(q), jnp.asarray(u), jnp.asarray(f),
                      jnp.asarray(float(np.mean(np.sum(f * f, axis=1)))))


@pytest.mark.parametrize("kind", ["lagrangian", "hamiltonian"])
def test_label_loss_zero_for_the_true_fields(kind):
    eq = _msd_labels()
    both = dict(equilibrium_weight=1.0, force_weight=1.0)
    assert float(label_loss(_msd_model(kind), eq, **both)) < 1e-28
    # the balance is blind to a common scale of M, D, G, A (the same dynamics); the force is not
    scaled = _msd_model(kind, alpha=3.0)
    assert float(label_loss(scaled, eq, equilibrium_weight=1.0)) < 1e-28
    assert float(label_loss(scaled, eq, force_weight=1.0)) > 1.0
    wrong = _msd_model(kind, scale_G=1.3)
    bal = float(label_loss(wrong, eq, equilibrium_weight=1.0))
    assert bal > 0.01
    assert float(label_loss(wrong, eq, equilibrium_weight=2.0)) == pytest.approx(2 * bal)
    assert float(label_loss(wrong, eq, force_weight=1.0)) > 0.01


def test_settings_and_resume():
    model = ModelConfig(kind="lagrangian", n=2, m=1)
    assert TrainConfig(model=model, equilibrium_weight=0.5).group("loss")["equilibrium_weight"]
    assert "equilibrium_weight" not in RESUMABLE and "force_weight" not in RESUMABLE
    with pytest.raises(UserError, match="equilibrium_weight: expected a finite number >= 0"):
        TrainConfig(model=model, equilibrium_weight=-1.0)
    with pytest.raises(UserError, match="blackbox model has none"):
        TrainConfig(model=ModelConfig(kind="blackbox", n=2, m=1), force_weight=1.0)


@pytest.fixture(scope="module")
def msd_files(tmp_path_factory):
    """The forced mass-spring-damper data set, and the same with five equilibria."""
    root = tmp_path_factory.mktemp("eq")
    plain = make_dataset(root / "msd.npz", trajectories=4, duration=3.0)
    with np.load(plain) as z:
        d = {k: z[k] for k in z.files}
    eq = _msd_labels()
    np.savez(root / "msd-eq.npz", **d, eq_q=np.asarray(eq.q), eq_u=np.asarray(eq.u),
             eq_force=np.asarray(eq.force))
    return plain, root / "msd-eq.npz"


# a small, quick-to-compile Lagrangian network (eq. 10, constant D and A)
TRAIN = ["--model", "lagrangian", "--width", "4", "--depth", "1", "--epochs", "2",
         "--loss", "accel", "--damping-form", "constant", "--input-form", "constant",
         "--batch-size", "64", "--test-trajectories", "1", "--quiet"]


def _error_line(capsys):
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith("softpinn: error: ")
    return err[0]


def test_cli_refuses_labels_it_cannot_use(msd_files, tmp_path, capsys):
    plain, _ = msd_files
    out = tmp_path / "run"
    assert main(["train", str(plain), "--out", str(out), *TRAIN,
                 "--equilibrium-weight", "1"]) == 2
    assert "holds no static equilibria" in _error_line(capsys)
    assert not (out / "config.json").exists()
    assert main(["train", str(plain), "--out", str(tmp_path / "bb"), "--model", "blackbox",
                 "--epochs", "1", "--quiet", "--force-weight", "1"]) == 2
    assert "blackbox model has none" in _error_line(capsys)
    assert main(["train", str(plain), "--out", str(tmp_path / "neg"), *TRAIN,
                 "--equilibrium-weight", "-2"]) == 2
    _error_line(capsys)


def test_cli_trains_with_labels_and_resume_keeps_them(msd_files, tmp_path, capsys):
    _, labelled = msd_files
    out = tmp_path / "run"
    assert main(["train", str(labelled), "--out", str(out), *TRAIN,
                 "--equilibrium-weight", "0.5", "--force-weight", "0.1"]) == 0
    cfg = json.loads((out / "config.json").read_text())["train"]
    assert cfg["equilibrium_weight"] == 0.5 and cfg["force_weight"] == 0.1
    capsys.readouterr()
    # another weight is another run: refused on resume
    assert main(["train", str(labelled), "--out", str(out), *TRAIN, "--resume",
                 "--equilibrium-weight", "1"]) == 2
    assert "--equilibrium-weight" in _error_line(capsys)


def test_simulate_equilibria_flag(tmp_path, capsys):
    out = tmp_path / "t3.npz"
    assert main(["simulate", "task3", "--out", str(out), "--trajectories", "1", "--duration",
                 "0.2", "--no-compile", "--quiet", "--equilibria", "4"]) == 0
    data = load_dataset(out)
    assert data.equilibria == 4 and data.meta["equilibria"]["max_residual"] <= 1e-10
    true = TrueModel(load_spec("task3"))
    Au = np.einsum("kij,kj->ki", true.A(data.eq_q), data.eq_u)
    assert np.max(np.abs(true.G(data.eq_q) - Au)) <= 1e-10
    capsys.readouterr()
    assert main(["simulate", "task3", "--out", str(tmp_path / "x.npz"), "--equilibria",
                 "-1", "--quiet"]) == 2
    assert "--equilibria" in _error_line(capsys)


def test_labels_study_report(tmp_path):
    """The labels study's table, targets and figure from a results dict of its shape (a
    diverged rollout's inf included); its training runs are measured in RESULTS.md."""
    from softpinn.bridge.challenges import labels

    def run(kind, count, m, pred):
        mats = dict(M=m, D=2 * m, G=m / 2, A=m, M_inv=m, alpha=1.5, alpha_residual=m,
                    balance_at_pool=1.0, G_at_pool=2.0, samples=40)
        return {"kind": kind, "count": count, "weights": {}, "matrices": mats,
                "prediction_error": pred, "horizon_s": 5.0, "best_test_loss": 1e-3,
                "train_seconds": 3.0}

    runs = {"none": run("none", 0, 100.0, float("inf")),
            "balance-10": run("balance", 10, 80.0, 2.0),
            "force-10": run("force", 10, 1.0, 1e-3)}
    r = {"task": "task4", "mass_init": False, "variant": "main", "epochs": 5, "lbfgs_steps": 0,
         "samples": 100, "loss": "pair", "counts": {"balance": [10], "force": [10]},
         "equilibria": {"count": 10, "seconds": 0.1, "max_residual": 1e-12}, "runs": runs}
    targets = labels._targets({"task4": r})
    assert [t["met"] for t in targets] == [False, False, True, True]
    text = labels._markdown({"task4": r}, False, "labels/labels.png")
    assert "| force | 10 | 1.00 % | 2.00 % | 0.50 % | 1.00 % |" in text
    assert "| none | 0 |" in text and "inf (5 s)" in text
    labels._figure({"task4": r}, tmp_path / "labels.png")
    assert (tmp_path / "labels.png").stat().st_size > 10_000
