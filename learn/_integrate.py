"""Runge-Kutta-4 integration of a dynamics model (Section III-A: one RK4 step per pair).

``step`` advances one sample over one pair's own dt (variable-step data works), optionally with k
equal sub-steps and the input either held at u0 (zero-order hold) or interpolated linearly from
u0 to u1. ``rollout`` scans ``step`` over a whole trajectory, optionally re-setting the state to
the truth where a mask says so (Figs. 15, 17).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from softpinn.errors import UserError
from softpinn.learn._velocity import integration_coordinates

__all__ = ["rk4_step", "step", "rollout", "INPUT_HOLDS"]

INPUT_HOLDS = ("constant", "linear")


def rk4_step(f, t, y, args, dt):
    """One classic Runge-Kutta-4 step of y' = f(t, y, args) from t to t + dt (diffrax-like f)."""
    half = 0.5 * dt
    k1 = f(t, y, args)
    k2 = f(t + half, y + half * k1, args)
    k3 = f(t + half, y + half * k2, args)
    k4 = f(t + dt, y + dt * k3, args)
    return y + (dt / 6.0) * (k1 + 2.0 * (k2 + k3) + k4)


def _check_step_options(substeps, input_hold):
    if isinstance(substeps, bool) or not isinstance(substeps, int) or substeps < 1:
        raise UserError(f"substeps must be an integer >= 1, got {substeps!r}")
    if input_hold not in INPUT_HOLDS:
        raise UserError(f"input_hold must be one of {list(INPUT_HOLDS)}, got {input_hold!r}")


def step(model, x, u0, u1, dt, *, substeps: int = 1, input_hold: str = "constant"):
    """x_{k+1} from x_k = ``x`` (2n,) over ``dt`` with inputs u0 = u_k, u1 = u_{k+1} (m,).

    ``input_hold="constant"`` keeps u = u0 over the step; ``"linear"`` uses
    u(s) = u0 + (u1 - u0) s / dt. ``substeps`` RK4 steps of dt / substeps each.
    """
    _check_step_options(substeps, input_hold)
    coords = integration_coordinates(model)
    if coords is not None:  # stepped in other coordinates: a Hamiltonian net on (q, q̇), (q, p)
        encode, field, decode = coords
        inner = _SteppedField(field, model.dtype)
        x = encode(jnp.asarray(x, model.dtype))
        return decode(step(inner, x, u0, u1, dt, substeps=substeps, input_hold=input_hold))
    dtype = model.dtype
    x, u0, u1, dt = (jnp.asarray(a, dtype) for a in (x, u0, u1, dt))
    h = dt / substeps

    if input_hold == "constant":

        def f(s, y, args):
            return model.vector_field(y, u0)

    else:
        du = u1 - u0
        inv_dt = 1.0 / dt

        def f(s, y, args):
            return model.vector_field(y, u0 + du * (s * inv_dt))

    if substeps == 1:
        return rk4_step(f, jnp.zeros((), dtype), x, None, h)

    def body(y, i):
        return rk4_step(f, i * h, y, None, h), None

    y, _ = jax.lax.scan(body, x, jnp.arange(substeps, dtype=dtype))
    return y


class _SteppedField:
    """The vector field a model is stepped with in its integration coordinates
    (:func:`learn._velocity.integration_coordinates`), as :func:`step` needs it."""

    def __init__(self, field, dtype):
        self.vector_field, self.dtype = field, dtype


def rollout(model, x0, u, t, *, substeps: int = 1, input_hold: str = "constant", reset=None):
    """Simulate a trajectory from x0 (2n,) with inputs u (T, m) at times t (T,): x (T, 2n).

    x[0] = x0; x[k+1] = step(x[k], u[k], u[k+1], t[k+1] - t[k]) (variable dt allowed).
    ``reset``: optional ``(x_true (T, 2n), mask (T,) bool)``; where ``mask[k]`` (k >= 1) the
    state is set to ``x_true[k]`` before stepping on (re-set rollouts, Figs. 15, 17).
    """
    _check_step_options(substeps, input_hold)
    dtype = model.dtype
    x0 = jnp.asarray(x0, dtype)
    u = jnp.asarray(u, dtype)
    t = jnp.asarray(t, dtype)
    if u.ndim != 2 or t.ndim != 1 or u.shape[0] != t.shape[0]:
        raise UserError(f"rollout needs u (T, m) and t (T,), got u {u.shape} and t {t.shape}")
    if x0.shape != (2 * model.config.n,):
        raise UserError(f"rollout needs x0 of shape ({2 * model.config.n},), got {x0.shape}")
    dts = t[1:] - t[:-1]
    xs = (u[:-1], u[1:], dts)
    if reset is not None:
        x_true, mask = reset
        x_true = jnp.asarray(x_true, dtype)
        mask = jnp.asarray(mask, bool)
        if x_true.shape != (t.shape[0], x0.shape[0]) or mask.shape != t.shape:
            raise UserError(
                f"reset needs x_true {(t.shape[0], x0.shape[0])} and mask {t.shape}, "
                f"got {x_true.shape} and {mask.shape}"
            )
        xs = xs + (x_true[1:], mask[1:])

    def body(x, inp):
        x1 = step(model, x, inp[0], inp[1], inp[2], substeps=substeps, input_hold=input_hold)
        if reset is not None:
            x1 = jnp.where(inp[4], inp[3], x1)
        return x1, x1

    _, traj = jax.lax.scan(body, x0, xs)
    return jnp.concatenate([x0[None], traj], axis=0)
