"""Eq. 6 / eq. 7 of a trained network, computed symbolically in CasADi from its weights.

:func:`member_expressions` turns the parameters of one model (:mod:`.params`) into SX
expressions of shared symbols; :func:`export_functions` averages members (an ensemble's mean
model) and wraps everything into named ``casadi.Function`` objects:

* Lagrangian network (eq. 6), M = L Lᵀ from the Cholesky network (Fig. 2):
  M q̈ = A u - Ṁ q̇ + ½ ∂(q̇ᵀ M q̇)/∂q - ∂V/∂q - D q̇, where Ṁ q̇ - ½ ∂(q̇ᵀ M q̇)/∂q = C q̇ comes
  from the symbolic derivative of M (``jtimes``, ``gradient``), and q̈ from two triangular
  solves with L (no inverse). The reference kind "lagrangian-hessian" has the same L, V, D, A
  and, as ∂²L/∂q̇² = M exactly, the same eq. 6: it exports the same expressions.
* Hamiltonian network (eq. 7), M⁻¹ = L Lᵀ: q̇ = M⁻¹ p, ṗ = -∂H/∂q - D q̇ + A u with
  H = ½ pᵀ M⁻¹ p + V; q̈ at a velocity state through p = M q̇ and q̈ = ∂(M⁻¹ p)/∂q q̇ + M⁻¹ ṗ.
* Black box: ẋ = MLP([x, u]) and, on a velocity state, q̈ = its last n entries.
* A linear prior (``learn/_prior.py``) adds its fixed force F₀ = B₀ u + c₀ - K₀ q - D₀ q̇ to the
  right-hand side of eq. 6 and to ṗ of eq. 7 (and (q̇, F₀) to a black box's ẋ); the matrices
  are the totals, G + K₀ q - c₀, D + D₀ and A + B₀, as the JAX model's ``matrices``.

The ensemble mean is the mean of the members' vector fields (and of their q̈, M, M⁻¹, G, D, A);
its ``step`` integrates the mean field.
"""

from __future__ import annotations

import casadi as ca

from softpinn.bridge.export.layers import cho_solve, field_expression, lower_inverse, mlp
from softpinn.errors import UserError

__all__ = ["member_expressions", "export_functions", "step_function", "MATRIX_NAMES"]

#: The matrix functions of a physics model, each a Function of q alone.
MATRIX_NAMES = ("M", "M_inv", "G", "D", "A")


def _damping(field: dict, q):
    """D(q) = L Lᵀ for a Cholesky damping field (eps = 0, Fig. 3), zeros for "zero"."""
    value = field_expression(field, q)
    if field["kind"] in ("cholesky", "constant-cholesky"):
        return ca.mtimes(value, value.T)
    return value


def _prior(params: dict, q, qd, u):
    """F₀(q, q̇, u) and the prior's shares (G₀, D₀, A₀) of a model with a linear prior, else
    None."""
    p = params.get("prior")
    if p is None:
        return None
    K, D, B, c = (ca.DM(p[k]) for k in ("K", "D", "B", "c"))
    G0 = ca.mtimes(K, q) - c
    return ca.mtimes(B, u) - G0 - ca.mtimes(D, qd), G0, D, B


def _physics_parts(params: dict, q):
    L = field_expression(params["mass"], q)
    V = field_expression(params["potential"], q)
    D = _damping(params["damping"], q)
    A = field_expression(params["input_map"], q)
    return L, V, D, A


def _lagrangian(params: dict, q, qd, u) -> dict:
    """Eq. 6 for M = L Lᵀ."""
    L, V, D, A = _physics_parts(params, q)
    M = ca.mtimes(L, L.T)
    Mqd = ca.mtimes(M, qd)
    mdot_qd = ca.jtimes(Mqd, q, qd)  # Ṁ q̇ = ∂(M q̇)/∂q · q̇
    dT_dq = ca.gradient(0.5 * ca.dot(qd, Mqd), q)
    G = ca.gradient(V, q)
    rhs = ca.mtimes(A, u) - mdot_qd + dT_dq - G - ca.mtimes(D, qd)
    prior = _prior(params, q, qd, u)
    if prior is not None:
        F0, G0, D0, A0 = prior
        rhs, G, D, A = rhs + F0, G + G0, D + D0, A + A0
    qdd = cho_solve(L, rhs)
    return {"qdd": qdd, "M": M, "M_inv": lower_inverse(L), "G": G, "D": D, "A": A}


def _hamiltonian(params: dict, q, qd, p, u) -> dict:
    """Eq. 7 for M⁻¹ = L Lᵀ: the (q, p) field, and q̈ at a velocity state."""
    L, V, D, A = _physics_parts(params, q)
    Minv = ca.mtimes(L, L.T)
    w = ca.mtimes(L.T, p)
    H = 0.5 * ca.dot(w, w) + V
    qdot = ca.mtimes(L, w)
    pdot = -ca.gradient(H, q) - ca.mtimes(D, qdot) + ca.mtimes(A, u)
    G = ca.gradient(V, q)
    prior = _prior(params, q, qdot, u)
    if prior is not None:
        F0, G0, D0, A0 = prior
        pdot, G, D, A = pdot + F0, G + G0, D + D0, A + A0
    # q̈ = d/dt (M⁻¹(q) p) along (q̇, ṗ), then p = M q̇ (two triangular solves with L)
    acc = ca.jtimes(qdot, ca.vertcat(q, p), ca.vertcat(qd, pdot))
    qdd = ca.substitute(acc, p, cho_solve(L, qd))
    return {
        "field_qp": ca.vertcat(qdot, pdot),
        "qdd": qdd,
        "M": lower_inverse(L),
        "M_inv": Minv,
        "G": G,
        "D": D,
        "A": A,
    }


def member_expressions(params: dict, sym: dict) -> dict:
    """SX expressions of one model in the symbols ``sym`` (``q``, ``qd``, ``p``, ``x``, ``u``).

    Returns ``field`` (ẋ in the model's own state, a function of ``x`` and ``u``), ``qdd``
    (of ``q``, ``qd``, ``u``; absent for a black box on (q, p)) and, for physics models, the
    matrices of :data:`MATRIX_NAMES` (of ``q``).
    """
    n = params["n"]
    q, qd, p, x, u = (sym[k] for k in ("q", "qd", "p", "x", "u"))
    kind = params["kind"]
    if kind == "blackbox":
        field = mlp(params["mlp"], ca.vertcat(x, u))
        prior = _prior(params, x[:n], x[n:], u)
        if prior is not None:  # on (q, q̇) only (ModelConfig refuses a prior on momenta)
            field = field + ca.vertcat(x[n:], prior[0])
        out = {"field": field}
        if params["state_kind"] == "velocity":
            out["qdd"] = ca.substitute(field[n:], x, ca.vertcat(q, qd))
        return out
    if kind in ("lagrangian", "lagrangian-hessian"):
        out = _lagrangian(params, q, qd, u)
        acc = ca.substitute(out["qdd"], ca.vertcat(q, qd), x)
        out["field"] = ca.vertcat(x[n:], acc)
        return out
    if kind == "hamiltonian":
        out = _hamiltonian(params, q, qd, p, u)
        out["field"] = ca.substitute(out.pop("field_qp"), ca.vertcat(q, p), x)
        return out
    raise UserError(f"model kind {kind!r} cannot be exported")


def step_function(field: ca.Function, n: int, m: int, *, substeps: int, input_hold: str):
    """``step(x, u0, u1, dt) -> x_next``: ``substeps`` RK4 steps of dt / substeps of ``field``,
    the input held at u0 ("constant") or interpolated from u0 to u1 ("linear"), exactly as
    :func:`softpinn.learn._integrate.step`. An MX function that calls ``field``."""
    x = ca.MX.sym("x", 2 * n)
    u0, u1 = ca.MX.sym("u0", m), ca.MX.sym("u1", m)
    dt = ca.MX.sym("dt")
    h = dt / substeps
    if input_hold == "constant":
        def u_at(s):
            return u0
    elif input_hold == "linear":
        def u_at(s):
            return u0 + (u1 - u0) * (s * (1.0 / dt))
    else:
        raise UserError(f"input_hold must be 'constant' or 'linear', got {input_hold!r}")
    y = x
    for i in range(substeps):
        t = i * h
        half = 0.5 * h
        k1 = field(y, u_at(t))
        k2 = field(y + half * k1, u_at(t + half))
        k3 = field(y + half * k2, u_at(t + half))
        k4 = field(y + h * k3, u_at(t + h))
        y = y + (h / 6.0) * (k1 + 2.0 * (k2 + k3) + k4)
    return ca.Function("step", [x, u0, u1, dt], [y], ["x", "u0", "u1", "dt"], ["x_next"])


def export_functions(members: list[dict], *, substeps: int, input_hold: str) -> dict:
    """Named Functions of one model or of the mean of several (same kind, n, m).

    Keys and names: ``qdd`` (q, qd, u), ``field`` (x, u), ``step`` (x, u0, u1, dt) and, for
    physics models, ``M``, ``M_inv``, ``G``, ``D``, ``A`` (q). A black box on (q, p) has no q̈
    and is refused (there is no mass matrix to turn p into q̇).
    """
    first = members[0]
    n, m, kind = first["n"], first["m"], first["kind"]
    if kind == "blackbox" and first["state_kind"] != "velocity":
        raise UserError(
            "a black-box model on the momentum state (q, p) has no q̈(q, q̇, u) to export (no mass "
            "matrix maps p to q̇); export a black box trained on the velocity state"
        )
    sym = {
        "q": ca.SX.sym("q", n),
        "qd": ca.SX.sym("qd", n),
        "p": ca.SX.sym("p", n),
        "x": ca.SX.sym("x", 2 * n),
        "u": ca.SX.sym("u", m),
    }
    exprs = [member_expressions(p, sym) for p in members]
    k = float(len(exprs))

    def mean(key):
        total = exprs[0][key]
        for e in exprs[1:]:
            total = total + e[key]
        return total if len(exprs) == 1 else total / k

    q, qd, x, u = sym["q"], sym["qd"], sym["x"], sym["u"]
    fns = {
        "qdd": ca.Function("qdd", [q, qd, u], [mean("qdd")], ["q", "qd", "u"], ["qdd"]),
        "field": ca.Function("field", [x, u], [mean("field")], ["x", "u"], ["xdot"]),
    }
    fns["step"] = step_function(fns["field"], n, m, substeps=substeps, input_hold=input_hold)
    if kind != "blackbox":
        for name in MATRIX_NAMES:
            fns[name] = ca.Function(name, [q], [mean(name)], ["q"], [name])
    return fns
