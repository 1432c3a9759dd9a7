"""learn._losses: eqs. 8-10 against hand computations, rollout loss (and its out-of-range
count), gradients, no retracing."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from softpinn.errors import UserError
from softpinn.learn._integrate import rollout, step
from softpinn.learn._losses import (
    Pairs,
    Windows,
    accel_loss,
    outside_range,
    pair_errors,
    pair_loss,
    rollout_errors,
    rollout_loss,
    rollout_loss_and_range,
    rollout_predictions,
)
from softpinn.learn._models import ModelConfig, make_model

SMALL = dict(mass=(8, 1), potential=(8, 1), damping=(4, 1), input=(4, 1), hidden=(8, 1))


def _model(key, kind="lagrangian", n=2, m=1):
    return make_model(ModelConfig(kind=kind, n=n, m=m, **SMALL), key=key)


def _pairs(key, B=6, n=2, m=1, xdot=True):
    k = jax.random.split(key, 6)
    return Pairs(
        x0=jax.random.normal(k[0], (B, 2 * n)),
        u0=jax.random.normal(k[1], (B, m)),
        u1=jax.random.normal(k[2], (B, m)),
        dt=jax.random.uniform(k[3], (B,), minval=0.01, maxval=0.05),
        x1=jax.random.normal(k[4], (B, 2 * n)),
        xdot0=jax.random.normal(k[5], (B, 2 * n)) if xdot else None,
    )


@pytest.mark.parametrize("kind", ["lagrangian", "hamiltonian", "blackbox"])
def test_pair_loss_is_eq8_or_eq9(getkey, kind):
    model, pairs, lam = _model(getkey(), kind), _pairs(getkey()), 0.3
    errs, loss = jax.jit(
        lambda p: (
            pair_errors(model, p, weight=lam, input_hold="linear"),
            pair_loss(model, p, weight=lam, input_hold="linear"),
        )
    )(pairs)
    one = jax.jit(lambda x, a, b, dt: step(model, x, a, b, dt, input_hold="linear"))
    manual = []
    for k in range(pairs.x0.shape[0]):
        x1 = one(pairs.x0[k], pairs.u0[k], pairs.u1[k], pairs.dt[k])
        d = np.asarray(pairs.x1[k] - x1)
        manual.append(np.sum(d[:2] ** 2) + lam * np.sum(d[2:] ** 2))  # q, then q̇ or p
    np.testing.assert_allclose(errs, manual, rtol=1e-12)
    np.testing.assert_allclose(loss, np.mean(manual), rtol=1e-12)


def test_accel_loss_is_eq10(getkey):
    model, pairs = _model(getkey()), _pairs(getkey())
    f = jax.jit(jax.vmap(model.vector_field))(pairs.x0, pairs.u0)
    # a Lagrangian model's first half of ẋ is q̇ itself, so only q̈ contributes (eq. 10)
    exact = pairs._replace(xdot0=pairs.xdot0.at[:, 2:].set(f[:, 2:]).at[:, :2].set(pairs.x0[:, 2:]))
    loss = jax.jit(lambda p: accel_loss(model, p))
    assert float(loss(exact)) < 1e-28
    expected = np.mean(np.sum((np.asarray(pairs.xdot0) - np.asarray(f)) ** 2, axis=1))
    np.testing.assert_allclose(loss(pairs), expected, rtol=1e-12)
    with pytest.raises(UserError, match="needs pairs.xdot0"):
        accel_loss(model, pairs._replace(xdot0=None))


def test_rollout_loss_over_windows(getkey):
    model = _model(getkey(), "blackbox")  # the windowing logic is model-independent
    B, h, n = 3, 3, 2
    k = jax.random.split(getkey(), 3)
    t = jnp.cumsum(jax.random.uniform(k[0], (B, h + 2), minval=0.01, maxval=0.03), axis=1)
    win = Windows(
        jax.random.normal(k[1], (B, h + 2, 2 * n)), jax.random.normal(k[2], (B, h + 2, 1)), t
    )
    # horizon 1 is the pair loss on the first pair of each window
    pairs = Pairs(win.x[:, 0], win.u[:, 0], win.u[:, 1], t[:, 1] - t[:, 0], win.x[:, 1])
    both = jax.jit(
        lambda w, p: (
            rollout_loss(model, w, horizon=1, weight=0.5),
            pair_loss(model, p, weight=0.5),
        )
    )
    np.testing.assert_allclose(*both(win, pairs), rtol=1e-12)
    errs = jax.jit(lambda w: rollout_errors(model, w, horizon=h))(win)
    run = jax.jit(lambda x0, u, t: rollout(model, x0, u, t))
    manual = []
    for b in range(B):
        xs = run(win.x[b, 0], win.u[b, : h + 1], t[b, : h + 1])
        d = np.asarray(win.x[b, 1 : h + 1] - xs[1:])
        manual.append(np.mean(np.sum(d**2, axis=1)))
    np.testing.assert_allclose(errs, manual, rtol=1e-12)
    with pytest.raises(UserError, match="horizon must be an integer >= 1"):
        rollout_loss(model, win, horizon=0)
    with pytest.raises(UserError, match="windows.x must have shape"):
        rollout_loss(model, win, horizon=h + 2)


@pytest.mark.parametrize("kind", ["lagrangian", "hamiltonian", "blackbox"])
def test_rollout_loss_and_range_for_every_kind(getkey, kind):
    """Issue 43: the rollout loss and its out-of-range count work for every model kind (a
    Hamiltonian network on (q, q̇) is stepped through its momenta) and have gradients."""
    model = _model(getkey(), kind)
    if kind == "hamiltonian":  # on velocities too: the windows hold (q, q̇)
        model = make_model(ModelConfig(kind=kind, n=2, m=1, state_kind="velocity", **SMALL),
                           key=getkey())
    B, h = 4, 3
    k = jax.random.split(getkey(), 3)
    t = jnp.cumsum(jnp.full((B, h + 1), 0.02), axis=1)
    win = Windows(0.1 * jax.random.normal(k[1], (B, h + 1, 4)),
                  jax.random.normal(k[2], (B, h + 1, 1)), t)
    wide = (jnp.full(2, -1e3), jnp.full(2, 1e3))
    loss, frac = jax.jit(lambda w: rollout_loss_and_range(model, w, wide, horizon=h))(win)
    np.testing.assert_allclose(loss, rollout_loss(model, win, horizon=h), rtol=1e-12)
    assert float(frac) == 0.0
    tight = (jnp.full(2, -1e-9), jnp.full(2, 1e-9))  # every rollout leaves it
    assert float(rollout_loss_and_range(model, win, tight, horizon=h)[1]) == 1.0
    params, static = eqx.partition(model, eqx.is_array)
    g = jax.grad(lambda p: rollout_loss_and_range(eqx.combine(p, static), win, wide,
                                                  horizon=h)[0])(params)
    assert all(np.all(np.isfinite(x)) for x in jax.tree.leaves(g))
    assert rollout_predictions(model, win, horizon=2).shape == (B, 3, 4)


def test_outside_range_counts_leaving_and_non_finite_windows():
    n, low, high = 1, jnp.array([-1.0]), jnp.array([1.0])
    inside = jnp.zeros((3, 2))
    xhat = jnp.stack([inside, inside.at[1, 0].set(1.5), inside.at[2, 1].set(jnp.nan),
                      inside.at[0, 1].set(50.0)])  # v may be anything: q alone is boxed
    np.testing.assert_array_equal(outside_range(xhat, n, low, high), [False, True, True, False])


def test_shape_mistakes_are_user_errors(getkey):
    model, pairs = _model(getkey()), _pairs(getkey())
    with pytest.raises(UserError, match=r"pairs.u0 must have shape \(6, 1\), got \(6, 2\)"):
        pair_loss(model, pairs._replace(u0=jnp.zeros((6, 2))))
    with pytest.raises(UserError, match=r"pairs.x1 must have shape \(6, 4\)"):
        pair_loss(model, pairs._replace(x1=jnp.zeros((6, 3))))


def test_loss_gradient_matches_finite_differences(getkey):
    """Reverse-mode gradient of eq. 8 through the structured model (second order) vs FD."""
    model, pairs = _model(getkey()), _pairs(getkey())
    params, static = eqx.partition(model, eqx.is_array)
    direction = jax.tree_util.tree_map(lambda a: jax.random.normal(getkey(), a.shape), params)

    def loss_along(s):
        p = jax.tree_util.tree_map(lambda a, d: a + s * d, params, direction)
        return pair_loss(eqx.combine(p, static), pairs, weight=0.7)

    h = 1e-5
    grad0, plus, minus = jax.jit(
        lambda: (jax.grad(loss_along)(0.0), loss_along(h), loss_along(-h))
    )()
    np.testing.assert_allclose(grad0, (plus - minus) / (2 * h), rtol=1e-6)


def test_adamw_training_step_compiles_once_and_learns(getkey):
    model, pairs = _model(getkey()), _pairs(getkey())
    opt = optax.adamw(1e-2)
    state = opt.init(eqx.filter(model, eqx.is_array))

    @eqx.filter_jit
    @eqx.debug.assert_max_traces(max_traces=1)
    def train_step(model, state, pairs):
        loss, grads = eqx.filter_value_and_grad(pair_loss)(model, pairs)
        updates, state = opt.update(grads, state, eqx.filter(model, eqx.is_array))
        return eqx.apply_updates(model, updates), state, loss

    losses = []
    for _ in range(15):
        model, state, loss = train_step(model, state, pairs)
        losses.append(float(loss))
    assert losses[-1] < 0.9 * losses[0]
