"""Dynamics models: Lagrangian (eq. 6), Hamiltonian (eq. 7) and black-box networks (Figs. 6-7).

Every model is written for ONE sample: ``model.vector_field(x, u)`` takes a state x of shape
(2n,), ``concat(q, q̇)`` for ``state_kind == "velocity"`` or ``concat(q, p)`` for
``"momentum"``, and an input u of shape (m,), and returns ẋ of shape (2n,). Batch with
``jax.vmap`` (see :mod:`learn._losses`).

The physics models are built from the sub-networks of :mod:`learn._nets` held as plain fields
(``mass``, ``potential``, ``damping``, ``input_map``); any module that follows that small
protocol can be put in their place, e.g. analytic fields of a known system in the tests::

    LagrangianNet(config=cfg, mass=..., potential=..., damping=..., input_map=...)
"""

from __future__ import annotations

import abc
import math
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp

from softpinn.errors import UserError
from softpinn.learn._known_input import KnownMatrix
from softpinn.learn._linalg import cho_inverse, cho_solve, cholesky, mtv, mv
from softpinn.learn._model_config import KINDS, ModelConfig
from softpinn.learn._nets import (
    MLP,
    CholeskyField,
    ConstantCholesky,
    ConstantMatrix,
    MatrixField,
    ScalarField,
    ZeroMatrix,
    first_layers,
    first_layers_transpose,
    make_mlp,
    softplus_inverse,
)
from softpinn.learn._prior import LinearPrior, quiet_start, zero_last

__all__ = [
    "KINDS",
    "ModelConfig",
    "DynamicsModel",
    "LagrangianNet",
    "LagrangianHessianNet",
    "HamiltonianNet",
    "BlackBoxNet",
    "make_model",
]

def _mass_terms(mass, q, v, *, tangent=True):
    """(L, L̇ = dL/dq · v, ½ ∂‖L(q)ᵀ v‖²/∂q) for a mass-like field with factor(q) -> L.

    Uses the field's fused ``factor_derivatives`` when it has one (one network pass, see
    :meth:`learn._nets.CholeskyField.factor_derivatives`), else one ``jax.jvp`` and one
    ``jax.vjp`` (analytic fields injected by tests).
    """
    if hasattr(mass, "factor_derivatives"):
        return mass.factor_derivatives(q, v, tangent=tangent)
    if tangent:
        L, Ldot = jax.jvp(mass.factor, (q,), (v,))
    else:
        L, Ldot = mass.factor(q), None
    _, vjp = jax.vjp(lambda q: mtv(mass.factor(q), v), q)
    (g,) = vjp(mtv(L, v))
    return L, Ldot, g


def _apply(field, q, v):
    """field(q) v, through the field's ``matvec`` when it has one (no matrix formed)."""
    if hasattr(field, "matvec"):
        return field.matvec(q, v)
    return mv(field(q), v)


def _potential_grad(potential, q):
    """G(q) = ∂V/∂q."""
    if hasattr(potential, "grad"):
        return potential.grad(q)
    return jax.grad(potential)(q)


class DynamicsModel(eqx.Module):
    """A learned continuous-time dynamics model ẋ = f(x, u) for one sample."""

    config: ModelConfig = eqx.field(static=True)

    @property
    @abc.abstractmethod
    def state_kind(self) -> str:
        """ "velocity" (x = (q, q̇)) or "momentum" (x = (q, p))."""

    @abc.abstractmethod
    def vector_field(self, x, u):
        """ẋ for one state x (2n,) and input u (m,)."""

    @property
    def dtype(self):
        return jnp.dtype(self.config.dtype)

    def _cast(self, *arrays):
        return tuple(jnp.asarray(a, self.dtype) for a in arrays)

    def matrices(self, q) -> dict:
        raise UserError(f"a {self.config.kind} model has no physical matrices M, D, G, A")

    def qdd(self, q, qd, u):
        raise UserError(
            f"qdd is defined for Lagrangian (eq. 6) and Hamiltonian (eq. 7) models, not "
            f"{self.config.kind}"
        )


class _PhysicsModel(DynamicsModel):
    """Shared fields of the structured models: mass-like field, V, D and A."""

    mass: Any  # factor(q) -> L; M = L Lᵀ (Lagrangian) or M⁻¹ = L Lᵀ (Hamiltonian)
    potential: Any  # V(q) -> scalar
    damping: Any  # D(q) -> (n, n), positive semi-definite
    input_map: Any  # A(q) -> (n, m)
    prior: Any = None  # None, or a fixed linear force F₀(q, q̇, u) (learn/_prior.py)

    def _prior_force(self, q, qd, u):
        """F₀(q, q̇, u) of the linear prior, 0 without one (static: decided when traced)."""
        return 0.0 if self.prior is None else self.prior(q, qd, u)

    def _with_prior(self, mats: dict, q) -> dict:
        """The learned matrices with the prior's share added: G + K₀ q - c₀, D + D₀, A + B₀."""
        if self.prior is None:
            return mats
        p = self.prior.matrices(q)
        return {**mats, "G": mats["G"] + p["G"], "D": mats["D"] + p["D"],
                "A": mats["A"] + p["A"]}

    def energy(self, x):
        """Total energy T + V at state x (for tests and diagnostics)."""
        raise NotImplementedError


class _LagrangianBase(_PhysicsModel):
    @property
    def state_kind(self) -> str:
        return "velocity"

    def vector_field(self, x, u):
        """ẋ = (q̇, q̈) with q̈ from eq. 6."""
        (x, u) = self._cast(x, u)
        n = self.config.n
        q, qd = x[:n], x[n:]
        return jnp.concatenate([qd, self.qdd(q, qd, u)])

    def matrices(self, q) -> dict:
        """Learned {"M", "M_inv", "D", "G", "A"} at one q (G = dV/dq)."""
        (q,) = self._cast(q)
        L = self.mass.factor(q)
        return self._with_prior({
            "M": L @ L.T,
            "M_inv": cho_inverse(L),
            "D": self.damping(q),
            "G": _potential_grad(self.potential, q),
            "A": self.input_map(q),
        }, q)

    def energy(self, x):
        (x,) = self._cast(x)
        n = self.config.n
        q, qd = x[:n], x[n:]
        w = self.mass.factor(q).T @ qd
        return 0.5 * w @ w + self.potential(q)


class LagrangianNet(_LagrangianBase):
    """Structured Lagrangian network, eq. 6 without a Hessian of a black-box L.

    With L = T - V, T = ½ q̇ᵀ M(q) q̇, eq. 6 reads
        M q̈ = A u - Ṁ q̇ + ½ ∂(q̇ᵀ M q̇)/∂q - ∂V/∂q - D q̇.
    M = Lc Lcᵀ comes from the Cholesky network, so with w = Lcᵀ q̇:
        Ṁ q̇ = L̇c w + Lc (L̇cᵀ q̇),  L̇c one Jacobian-vector product of the factor along q̇;
        ½ ∂(q̇ᵀ M q̇)/∂q = ½ ∂‖Lc(q)ᵀ q̇‖²/∂q = Jᵀ(q̇ wᵀ), one vector-Jacobian product
        (both from one forward pass of the mass network, :func:`_mass_terms`);
    and q̈ by two triangular solves with Lc (no inverse, no factorisation).

    When M and V are the networks of :mod:`learn._nets` (and D, A are networks too, or not
    networks at all), the sub-networks share ONE product for their first layers, which all
    read q, and one for their first layers' transposes (∂T/∂q - ∂V/∂q together): the fused
    pass of :meth:`_fused_qdd`, equal to the separate passes to rounding (the tests hold it to
    1e-12) and fewer, larger products (see benchmarks/bench_lagrangian.py).
    """

    def qdd(self, q, qd, u):
        (q, qd, u) = self._cast(q, qd, u)
        if self._fusable():
            return self._fused_qdd(q, qd, u)
        return self._separate_qdd(q, qd, u)

    def _fusable(self) -> bool:
        """Whether M and V are the networks of :mod:`learn._nets` (static: decided when traced)."""
        return isinstance(self.mass, CholeskyField) and isinstance(self.potential, ScalarField)

    def _fused_qdd(self, q, qd, u):
        """Eq. 6 as :meth:`_separate_qdd`, with the first layers of M, V and of D and A where
        they are networks computed by one product (:func:`learn._nets.first_layers`), and
        ∂T/∂q - ∂V/∂q by one transposed product."""
        nets = [self.mass.mlp, self.potential.mlp]
        D_net = isinstance(self.damping, CholeskyField)
        A_net = isinstance(self.input_map, MatrixField)
        nets += [self.damping.mlp] if D_net else []
        nets += [self.input_map.mlp] if A_net else []
        z = first_layers(nets, q)
        M0 = self.mass.mlp.weights[0]
        Lc, Ldot, cM = self.mass.factor_derivatives_first(None, qd, first=(z[0], M0 @ qd))
        _, _, slopes = self.potential.mlp.linearize(None, first=(z[1], None))
        cV = self.potential.mlp.transpose_to_first(slopes, jnp.ones((1,), q.dtype))
        # ∂T/∂q - ∂V/∂q = W₀ᵀ_M cM - W₀ᵀ_V cV in one product
        dT_dq_minus_G = first_layers_transpose(nets[:2], [cM, -cV])
        w = mtv(Lc, qd)
        mdot_qd = mv(Ldot, w) + mv(Lc, mtv(Ldot, qd))
        if D_net:
            LD = self.damping.factor_from_first(z[2])
            Dqd = mv(LD, mtv(LD, qd))
        else:
            Dqd = _apply(self.damping, q, qd)
        if A_net:
            A = self.input_map.mlp.linearize(None, first=(z[-1], None))[0]
            Au = mv(A.reshape(self.input_map.shape), u)
        else:
            Au = _apply(self.input_map, q, u)
        rhs = Au - mdot_qd + dT_dq_minus_G - Dqd + self._prior_force(q, qd, u)
        return cho_solve(Lc, rhs)

    def _separate_qdd(self, q, qd, u):
        """Eq. 6 with each sub-network on its own (any fields that follow the protocol)."""
        Lc, Ldot, dT_dq = _mass_terms(self.mass, q, qd)
        w = mtv(Lc, qd)
        mdot_qd = mv(Ldot, w) + mv(Lc, mtv(Ldot, qd))
        G = _potential_grad(self.potential, q)
        rhs = (_apply(self.input_map, q, u) - mdot_qd + dT_dq - G - _apply(self.damping, q, qd)
               + self._prior_force(q, qd, u))
        return cho_solve(Lc, rhs)


class LagrangianHessianNet(_LagrangianBase):
    """Literal Hessian form of eq. 6, the reference implementation.

    L(q, q̇) = ½ q̇ᵀ M(q) q̇ - V(q) from the same sub-networks;
        q̈ = (∂²L/∂q̇²)⁻¹ (A u - (∂²L/∂q ∂q̇) q̇ + ∂L/∂q - D q̇)
    with the Hessians by ``jax.hessian``/``jax.jacfwd`` and the solve by a plain-jnp Cholesky
    factorisation of ∂²L/∂q̇² (which the network does not know equals M).
    """

    def lagrangian(self, q, qd):
        return 0.5 * qd @ self.mass(q) @ qd - self.potential(q)

    def qdd(self, q, qd, u):
        (q, qd, u) = self._cast(q, qd, u)
        H = jax.hessian(self.lagrangian, argnums=1)(q, qd)
        mixed = jax.jacfwd(jax.grad(self.lagrangian, argnums=1), argnums=0)(q, qd)
        dL_dq = jax.grad(self.lagrangian, argnums=0)(q, qd)
        rhs = (_apply(self.input_map, q, u) - mv(mixed, qd) + dL_dq - _apply(self.damping, q, qd)
               + self._prior_force(q, qd, u))
        return cho_solve(cholesky(0.5 * (H + H.T)), rhs)


class HamiltonianNet(_PhysicsModel):
    """Hamiltonian network, eq. 7, on x = (q, p).

    H(q, p) = ½ pᵀ M⁻¹(q) p + V(q), M⁻¹ = Lc Lcᵀ from the Cholesky network (Fig. 2, eps > 0).
        q̇ = ∂H/∂p = M⁻¹ p,
        ṗ = -∂H/∂q - D(q) ∂H/∂p + A(q) u = -∂H/∂q - D(q) q̇ + A(q) u.
    Eq. 7's block matrix multiplies D by ∂H/∂p, i.e. by the velocity q̇, which is the
    dissipative force of eq. 4 (F_d = D q̇); D is not applied to p.
    """

    @property
    def state_kind(self) -> str:
        """ "momentum" (x = (q, p), eq. 9), or "velocity" (x = (q, q̇), momenta p = M̂ q̇ from
        the network's own mass matrix, :mod:`learn._velocity`)."""
        return self.config.state_kind

    def _kinetic_and_potential(self, q, p):
        Lc = self.mass.factor(q)
        w = Lc.T @ p
        return 0.5 * w @ w + self.potential(q), Lc

    def vector_field(self, x, u):
        """ẋ in the model's state: eq. 7 on (q, p), or (q̇, q̈) on (q, q̇) (:meth:`qdd`)."""
        if self.config.state_kind == "velocity":
            (x, u) = self._cast(x, u)
            n = self.config.n
            return jnp.concatenate([x[n:], self.qdd(x[:n], x[n:], u)])
        return self.momentum_field(x, u)

    def momentum_field(self, x, u):
        """Eq. 7: (q̇, ṗ) at x = (q, p), whatever the model's state."""
        (x, u) = self._cast(x, u)
        n = self.config.n
        q, p = x[:n], x[n:]
        Lc, _, dT_dq = _mass_terms(self.mass, q, p, tangent=False)
        dH_dq = dT_dq + _potential_grad(self.potential, q)
        qdot = mv(Lc, mtv(Lc, p))
        pdot = (-dH_dq - _apply(self.damping, q, qdot) + _apply(self.input_map, q, u)
                + self._prior_force(q, qdot, u))
        return jnp.concatenate([qdot, pdot])

    def qdd(self, q, qd, u):
        """q̈ at a velocity state, for comparing with Lagrangian models and the truth: the
        momentum p = M(q) q̇ (two triangular solves with the factor of M⁻¹), ṗ from eq. 7, and
        q̈ = d/dt (M⁻¹(q) p) = ∂(M⁻¹p)/∂q · q̇ + M⁻¹ ṗ by one Jacobian-vector product."""
        (q, qd, u) = self._cast(q, qd, u)
        n = self.config.n
        p = cho_solve(self.mass.factor(q), qd)
        pdot = self.momentum_field(jnp.concatenate([q, p]), u)[n:]

        def velocity(qq, pp):
            Lc = self.mass.factor(qq)
            return mv(Lc, mtv(Lc, pp))

        return jax.jvp(velocity, (q, p), (qd, pdot))[1]

    def matrices(self, q) -> dict:
        """Learned {"M_inv", "M", "D", "G", "A"} at one q (M by two triangular solves)."""
        (q,) = self._cast(q)
        Lc = self.mass.factor(q)
        return self._with_prior({
            "M_inv": Lc @ Lc.T,
            "M": cho_inverse(Lc),
            "D": self.damping(q),
            "G": _potential_grad(self.potential, q),
            "A": self.input_map(q),
        }, q)

    def energy(self, x):
        (x,) = self._cast(x)
        n = self.config.n
        return self._kinetic_and_potential(x[:n], x[n:])[0]


class BlackBoxNet(DynamicsModel):
    """Black-box baseline (the paper's FNN): an MLP from [q, v, u] to the state derivative (2n).
    With a linear prior (on x = (q, q̇)): ẋ = (q̇, F₀(q, q̇, u)) + MLP([x, u])."""

    mlp: MLP
    prior: Any = None

    @property
    def state_kind(self) -> str:
        return self.config.state_kind

    def vector_field(self, x, u):
        (x, u) = self._cast(x, u)
        out = self.mlp(jnp.concatenate([x, u]))
        if self.prior is None:
            return out
        n = self.config.n
        q, qd = x[:n], x[n:]
        return out + jnp.concatenate([qd, self.prior(q, qd, u)])


def _physics_parts(config: ModelConfig, key, *, mass_eps):
    n, m, dt = config.n, config.m, config.dtype
    kM, kV, kD, kA = jax.random.split(key, 4)
    act = config.activation
    mass = CholeskyField(n, *config.mass, act, mass_eps, key=kM, dtype=dt)
    if config.mass_init is not None:
        # diag(L) = softplus(b) + eps = sqrt(mass_init) at the bias: b = softplus⁻¹(...)
        b0 = softplus_inverse(math.sqrt(config.mass_init) - mass_eps)
        last = mass.mlp.biases[-1]
        mass = eqx.tree_at(lambda f: f.mlp.biases[-1], mass, last.at[:n].set(b0))
        if config.input_form == "known":
            # with A known, M itself must carry the data's scale (a learned A can follow M's
            # instead): the whole factor starts at that scale, L ≈ sqrt(mass_init) L₀. Only
            # the diagonal moved, the random off-diagonal part dominated M (task 4's M ~ 0.005:
            # a first one-step loss of 4e11) and training stalled.
            s = math.sqrt(config.mass_init)
            W, bias = mass.mlp.weights[-1], mass.mlp.biases[-1]
            mass = eqx.tree_at(lambda f: (f.mlp.weights[-1], f.mlp.biases[-1]), mass,
                               (W * s, bias.at[n:].multiply(s)))
    potential = ScalarField(n, *config.potential, act, key=kV, dtype=dt)
    if config.damping_form == "network":
        damping = CholeskyField(n, *config.damping, act, 0.0, key=kD, dtype=dt)
    elif config.damping_form == "constant":
        damping = ConstantCholesky(n, 0.0, key=kD, dtype=dt)
    else:
        damping = ZeroMatrix((n, n))
    if m == 0:
        input_map = ZeroMatrix((n, 0))
    elif config.input_form == "network":
        input_map = MatrixField(n, n, m, *config.input, act, key=kA, dtype=dt)
    elif config.input_form == "known":
        input_map = KnownMatrix(config.known_input, n, m)
    else:
        input_map = ConstantMatrix(n, m, key=kA, dtype=dt)
    return {"mass": mass, "potential": potential, "damping": damping, "input_map": input_map}


def ensure_dtype(dtype: str) -> None:
    """Let JAX compute in ``dtype``: float64 needs JAX's 64-bit mode, which softpinn.learn turns
    on by itself at its entry points (``make_model``, ``train``, ``load_run``) rather than at
    import, so that importing the package changes no global setting. Arrays made before stay as
    they were; the models, data and programs made after are float64."""
    if dtype == "float64" and not jax.config.jax_enable_x64:
        jax.config.update("jax_enable_x64", True)


def make_model(config: ModelConfig, *, key) -> DynamicsModel:
    """Build a freshly initialised model of ``config.kind`` with parameters in ``config.dtype``."""
    if not isinstance(config, ModelConfig):
        raise UserError(f"config must be a ModelConfig, got {type(config).__name__}")
    ensure_dtype(config.dtype)
    if config.kind == "blackbox":
        n, m = config.n, config.m
        mlp = make_mlp(
            2 * n + m, 2 * n, *config.hidden, config.activation, key=key, dtype=config.dtype
        )
        if config.prior is None:
            return BlackBoxNet(config=config, mlp=mlp)
        return BlackBoxNet(config=config, mlp=zero_last(mlp),
                           prior=LinearPrior(config.prior, n, m))
    cls = {
        "lagrangian": LagrangianNet,
        "lagrangian-hessian": LagrangianHessianNet,
        "hamiltonian": HamiltonianNet,
    }[config.kind]
    parts = _physics_parts(config, key, mass_eps=config.eps)
    if config.prior is None:
        return cls(config=config, **parts)
    return cls(config=config, **quiet_start(parts, config.n, config.eps),
               prior=LinearPrior(config.prior, config.n, config.m))
