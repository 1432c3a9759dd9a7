"""Time scales of the learned and the true dynamics: eigenvalues of ẋ = f(x, u) linearised.

A one-step loss can be low while the learned dynamics are wrong where the data are thin: data
that follow a slow manifold (Task 5's second segment relaxes at about -11 1/s and -288 1/s and
then follows the inputs) say little about the fast directions, and a network trained on them
may have no fast modes at all, or an unstable one, and drift in rollouts. The eigenvalues of
the Jacobian ∂f/∂x at a state at rest (q̇ = 0, p = 0) with a fixed input show that directly.
They are invariant to any constant linear change of coordinates, so a learned model that
equals the true one up to a constant transform (α I, or a constant P) has the true
eigenvalues; both Jacobians are taken in the model's own state form (eq. 4: x = (q, q̇);
eq. 7: x = (q, p)).
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np

from softpinn.bridge.analysis.floors import true_vector_field
from softpinn.errors import UserError

__all__ = ["format_modes", "learned_jacobian", "modes", "rest_state", "true_jacobian"]


def true_jacobian(true_model, x, u, *, state: str = "velocity", h: float = 1e-6) -> np.ndarray:
    """∂f/∂x (2n, 2n) of the true model at one state by central differences of step ``h``
    (relative to max(1, |x_i|))."""
    f = true_vector_field(true_model, state)
    x = np.asarray(x, float)
    u = np.asarray(u, float).reshape(1, -1)
    k = x.size
    steps = h * np.maximum(1.0, np.abs(x))
    plus = x + np.diag(steps)
    minus = x - np.diag(steps)
    both = f(np.concatenate([plus, minus]), np.repeat(u, 2 * k, axis=0))
    return ((both[:k] - both[k:]) / (2 * steps[:, None])).T


def learned_jacobian(model, x, u) -> np.ndarray:
    """∂f/∂x (2n, 2n) of a learned model (``learn._models``) at one state, by forward-mode AD."""
    import jax.numpy as jnp

    dtype = jnp.dtype(model.config.dtype)
    ux = jnp.asarray(np.asarray(u, float), dtype)
    return np.asarray(_jacobian()(model, jnp.asarray(np.asarray(x), dtype), ux), float)


@functools.cache
def _jacobian():
    """∂f/∂x of ``model.vector_field`` as one compiled program, the model an argument: models of
    one architecture share it (run eagerly, each primitive compiled on its own: 12 s for a task
    5 network on a 2-core machine)."""
    import equinox as eqx
    import jax

    return eqx.filter_jit(lambda model, x, u: jax.jacfwd(lambda xx: model.vector_field(xx, u))(x))


def _sorted_eigenvalues(jac: np.ndarray) -> np.ndarray:
    ev = np.linalg.eigvals(jac)
    order = np.lexsort((np.abs(ev.imag), ev.real))  # fastest decay first, then by frequency
    return ev[order]


def rest_state(q, qd=None) -> np.ndarray:
    """x = (q, 0): at rest, where velocity and momentum forms agree (p = M q̇ = 0)."""
    q = np.asarray(q, float).ravel()
    return np.concatenate([q, np.zeros_like(q)])


def modes(true_model, model, q, u, *, state: str | None = None) -> dict[str, Any]:
    """Eigenvalues of the true and the learned dynamics linearised at rest at ``q`` with input
    ``u``, sorted fastest decay first; JSON-ready (``true``/``learned`` as [re, im] pairs) with
    ``max_real`` of each (> 0: an unstable direction)."""
    n, m = true_model.n, true_model.m
    q = np.asarray(q, float).ravel()
    u = np.zeros(0) if u is None else np.asarray(u, float).ravel()
    if q.size != n:
        raise UserError(f"modes: q needs {n} values, got {q.size}")
    if u.size != m:
        raise UserError(f"modes: u needs {m} values, got {u.size}")
    state = state or model.config.state_kind
    x = rest_state(q)
    out: dict[str, Any] = {"q": q.tolist(), "u": u.tolist(), "state": state}
    for name, jac in (
        ("true", true_jacobian(true_model, x, u, state=state)),
        ("learned", learned_jacobian(model, x, u)),
    ):
        ev = _sorted_eigenvalues(jac)
        out[name] = [[float(e.real), float(e.imag)] for e in ev]
        out[f"{name}_max_real"] = float(np.max(ev.real))
    return out


def format_modes(pairs) -> str:
    """Eigenvalues as text, a conjugate pair once: ``-288, -1.32 ± 4.97i``."""
    parts, seen = [], set()
    values = [complex(re, im) for re, im in pairs]
    for i, e in enumerate(values):
        if i in seen:
            continue
        seen.add(i)
        if abs(e.imag) > 1e-9 * max(1.0, abs(e)):
            j = next((k for k in range(i + 1, len(values)) if k not in seen
                      and abs(values[k] - e.conjugate()) <= 1e-6 * max(1.0, abs(e))), None)
            # a real part at rounding level of the pair (an undamped mode) is shown as 0
            re = 0.0 if abs(e.real) <= 1e-9 * abs(e) else e.real
            if j is not None:
                seen.add(j)
                parts.append(f"± {abs(e.imag):.3g}i" if re == 0 else
                             f"{re:.3g} ± {abs(e.imag):.3g}i")
                continue
            parts.append(f"{re:.3g}{e.imag:+.3g}i")
        else:
            parts.append(f"{e.real:.3g}")
    return ", ".join(parts)
