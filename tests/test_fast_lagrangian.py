"""Issue 18 part 1 (fast Lagrangian training): the fused pass of the structured Lagrangian
network (eq. 6) equals the separate sub-network passes, values and gradients, and the
polynomial log1p inside softplus matches log(1 + eˣ) in float32 and float64."""

from __future__ import annotations

import json

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from softpinn.learn._known_input import known_input_text
from softpinn.learn._losses import pair_loss
from softpinn.learn._models import LagrangianNet, ModelConfig, make_model
from softpinn.learn._nets import ZeroMatrix, _log1p_unit, softplus

jax.config.update("jax_enable_x64", True)

CONFIGS = [
    # (n, m, damping_form, input_form, sizes)
    (3, 3, "network", "network", {}),
    (2, 1, "constant", "constant", {}),
    (4, 2, "none", "network", {"mass": (8, 1), "potential": (8, 2), "input": (5, 1)}),
    (3, 2, "network", "known", {"damping": (5, 3)}),
    (2, 0, "none", "network", {}),  # no inputs: A is a ZeroMatrix
]


def _model(n, m, damping, inp, sizes, seed=0):
    extra = {}
    if inp == "known":
        extra["known_input"] = known_input_text(np.arange(n * m, dtype=float).reshape(n, m) / 7)
    cfg = ModelConfig(kind="lagrangian", n=n, m=m, damping_form=damping, input_form=inp,
                      dtype="float64", **sizes, **extra)
    model = make_model(cfg, key=jax.random.PRNGKey(seed))
    assert isinstance(model, LagrangianNet)
    return model


def _inputs(n, m, seed=1, batch=7):
    k = jax.random.split(jax.random.PRNGKey(seed), 3)
    return (jax.random.normal(k[0], (batch, n)), jax.random.normal(k[1], (batch, n)),
            jax.random.normal(k[2], (batch, m)))


@pytest.mark.parametrize("config", CONFIGS, ids=lambda c: f"n{c[0]}m{c[1]}-{c[2]}-{c[3]}")
def test_fused_qdd_equals_separate(config):
    model = _model(*config)
    n, m = config[:2]
    if m == 0:
        assert isinstance(model.input_map, ZeroMatrix)
    assert model._fusable()
    q, qd, u = _inputs(n, m)
    fused = jax.jit(jax.vmap(model._fused_qdd))(q, qd, u)
    separate = jax.jit(jax.vmap(model._separate_qdd))(q, qd, u)
    assert fused.dtype == jnp.float64
    np.testing.assert_allclose(fused, separate, rtol=1e-12, atol=1e-12 * float(
        jnp.max(jnp.abs(separate))))
    # qdd() takes the fused path
    np.testing.assert_array_equal(jax.jit(jax.vmap(model.qdd))(q, qd, u), fused)


@pytest.mark.parametrize("config", CONFIGS[:4], ids=lambda c: f"n{c[0]}m{c[1]}-{c[2]}-{c[3]}")
def test_fused_gradients_equal_separate(config):
    """d(loss)/d(parameters) and d(qdd)/d(q, qd, u) through the fused pass = the separate one."""
    model = _model(*config)
    n, m = config[:2]
    q, qd, u = _inputs(n, m, seed=2, batch=5)

    def loss(model, which):
        f = model._fused_qdd if which == "fused" else model._separate_qdd
        return jnp.sum(jnp.sin(jax.vmap(f)(q, qd, u)))

    gf = eqx.filter_jit(eqx.filter_grad(lambda mdl: loss(mdl, "fused")))(model)
    gs = eqx.filter_jit(eqx.filter_grad(lambda mdl: loss(mdl, "separate")))(model)
    leaves_f = jax.tree_util.tree_leaves(gf)
    leaves_s = jax.tree_util.tree_leaves(gs)
    assert len(leaves_f) == len(leaves_s) > 0
    for a, b in zip(leaves_f, leaves_s, strict=True):
        scale = max(float(jnp.max(jnp.abs(b))), 1.0)
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12 * scale)
    @eqx.filter_jit
    def jac(model, which):
        f = model._fused_qdd if which == "fused" else model._separate_qdd
        return jax.jacfwd(f, argnums=(0, 1, 2))(q[0], qd[0], u[0])

    for jf, js in zip(jac(model, "fused"), jac(model, "separate"), strict=True):
        np.testing.assert_allclose(jf, js, rtol=1e-11, atol=1e-11 * float(jnp.max(jnp.abs(js))))


def test_fused_and_separate_pair_loss_gradient():
    """The training step's gradient (pair loss, eq. 8, through one RK4 step) is the same."""
    from softpinn.learn._losses import Pairs

    model = _model(3, 3, "network", "network", {})
    k = jax.random.split(jax.random.PRNGKey(3), 4)
    b = 6
    pairs = Pairs(x0=0.5 * jax.random.normal(k[0], (b, 6)), u0=jax.random.normal(k[1], (b, 3)),
                  u1=jax.random.normal(k[2], (b, 3)), dt=jnp.full((b,), 0.01),
                  x1=0.5 * jax.random.normal(k[3], (b, 6)))

    class Separate(LagrangianNet):
        def _fusable(self):
            return False

    sep = Separate(config=model.config, mass=model.mass, potential=model.potential,
                   damping=model.damping, input_map=model.input_map)
    step = eqx.filter_jit(eqx.filter_value_and_grad(pair_loss))
    lf, gf = step(model, pairs)
    ls, gs = step(sep, pairs)
    np.testing.assert_allclose(lf, ls, rtol=1e-12)
    for a, c in zip(jax.tree_util.tree_leaves(gf), jax.tree_util.tree_leaves(gs), strict=True):
        np.testing.assert_allclose(a, c, rtol=1e-10, atol=1e-12 * float(jnp.max(jnp.abs(c))))


def _reference_softplus(x):
    x = np.asarray(x, dtype=np.float64)
    return np.logaddexp(0.0, x)  # log(1 + eˣ) without overflow


@pytest.mark.parametrize("dtype, rtol", [("float64", 2e-15), ("float32", 4e-7)])
def test_softplus_series_matches_log1p_exp(dtype, rtol):
    x = np.concatenate([np.linspace(-40, 40, 20001), np.geomspace(1e-12, 1e3, 400),
                        -np.geomspace(1e-12, 700 if dtype == "float64" else 80, 400),
                        [0.0, 1e30, 1e300 if dtype == "float64" else 1e38]]).astype(dtype)
    got = np.asarray(jax.jit(softplus)(jnp.asarray(x)), dtype=np.float64)
    assert got.dtype == np.float64 and jnp.asarray(x).dtype == jnp.dtype(dtype)
    ref = _reference_softplus(x.astype(np.float64))
    assert np.all(np.isfinite(got))
    np.testing.assert_allclose(got, ref, rtol=rtol, atol=0)
    # and the polynomial alone against numpy's log1p over its whole domain [0, 1]
    e = np.linspace(0, 1, 10001).astype(dtype)
    np.testing.assert_allclose(np.asarray(_log1p_unit(jnp.asarray(e)), dtype=np.float64),
                               np.log1p(e.astype(np.float64)), rtol=rtol, atol=0)


@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_softplus_derivative_is_logistic(dtype):
    x = jnp.asarray(np.linspace(-50, 50, 1001), dtype=dtype)
    d = jax.vmap(jax.grad(softplus))(x)
    assert d.dtype == jnp.dtype(dtype)
    tol = 1e-15 if dtype == "float64" else 1e-7
    np.testing.assert_allclose(d, jax.nn.sigmoid(x), rtol=10 * tol, atol=tol)
    # second derivative σ(1 - σ) through the custom JVP
    d2 = jax.vmap(jax.grad(jax.grad(softplus)))(x)
    s = jax.nn.sigmoid(x)
    np.testing.assert_allclose(d2, s * (1 - s), rtol=100 * tol, atol=tol)


def test_train_init_warm_start(tmp_path, capsys):
    """``TrainConfig.init`` / ``softpinn train --init RUN``: an acceleration-loss run (eq. 10)
    warm-starts a pair-loss run (eq. 8), which starts from its best model, not a fresh one."""
    from datagen import make_dataset, tiny_model_config

    from softpinn.bridge.cli import main
    from softpinn.errors import UserError
    from softpinn.learn._rundir import load_run
    from softpinn.learn._train import TrainConfig, train

    data = make_dataset(tmp_path / "msd.npz", trajectories=3, duration=2.0, rate=20.0)
    model = tiny_model_config("lagrangian")
    warm = TrainConfig(model=model, epochs=3, batch_size=32, lr=1e-2, loss="accel",
                       accel_labels="differences", test_trajectories=(2,), checkpoint_every=100)
    train(data, warm, tmp_path / "warm", force=True)
    start = load_run(tmp_path / "warm").model
    fresh = make_model(model, key=jax.random.PRNGKey(0))
    # the pair-loss run with a vanishing learning rate ends where it started
    assert main(["train", str(data), "--model", "lagrangian", "--out", str(tmp_path / "pair"),
                 "--mass", "16", "1", "--potential", "16", "1", "--damping", "8", "1",
                 "--input", "8", "1", "--init", str(tmp_path / "warm"),
                 "--epochs", "1", "--batch-size", "32", "--lr", "1e-14",
                 "--test-trajectories", "2", "--quiet"]) == 0, capsys.readouterr().err
    stored = json.loads((tmp_path / "pair" / "config.json").read_text())["train"]
    assert stored["init"] == str(tmp_path / "warm") and stored["loss"] == "pair"
    after = load_run(tmp_path / "pair").model
    a, s, f = (jax.tree_util.tree_leaves(eqx.filter(x, eqx.is_array))
               for x in (after, start, fresh))
    for x, y in zip(a, s, strict=True):
        np.testing.assert_allclose(x, y, rtol=1e-9, atol=1e-9)
    assert max(float(jnp.max(jnp.abs(x - y))) for x, y in zip(s, f, strict=True)) > 1e-3
    # another network is refused
    other = TrainConfig(model=tiny_model_config("lagrangian", mass=(8, 1)), epochs=1,
                        test_trajectories=(2,), init=str(tmp_path / "warm"))
    with pytest.raises(UserError, match="another network"):
        train(data, other, tmp_path / "other", force=True)
    with pytest.raises(UserError, match="init"):
        TrainConfig(model=model, init="")
