"""``ExactModel``: the exact PCC equations of a spec as pure JAX functions of ONE state.

Every CasADi Function of :func:`softpinn.symbolic.model._functions` (M, M^-1, G, D, A, C, C qd,
forward and inverse dynamics, energies, momentum, the Hamiltonian form (eq. 7) and the ODE of
eq. 4) is replayed in ``jax.numpy`` (:mod:`.translate`); the methods take one state
(``q`` of shape (n,)) and compose with ``jax.jit``, ``jax.vmap`` and ``jax.grad``. Values are
float64 when ``jax_enable_x64`` is on and the inputs are float64; float32 inputs give float32.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import jax.numpy as jnp

from softpinn.bridge.exact.errors import TranslationError
from softpinn.bridge.exact.translate import Program, translate
from softpinn.symbolic import ModelSpec, functions, load_spec

#: outputs that are 1 x 1 in CasADi and scalars here
_SCALARS = frozenset({"energy", "kinetic", "potential"})


class ExactModel:
    """The exact model of a spec in JAX (eqs. 4, 7, 18-24 through the symbolic derivation).

    ``model.qdd(q, qd, u)`` is the forward dynamics at one state; ``jax.vmap(model.qdd)`` the
    batched one. :meth:`program` gives the underlying translated Function of any key of
    :data:`softpinn.symbolic.SIGNATURES`.
    """

    def __init__(self, model: str | Path | ModelSpec, order: int | None = None):
        self.spec: ModelSpec = load_spec(model)
        self.order = order
        self.n: int = self.spec.n
        self.m: int = self.spec.m
        self.functions = functions(self.spec, order)
        self._programs: dict[str, Program] = {}

    def program(self, key: str) -> Program:
        """The translated Function ``key`` (translated on first use, then cached)."""
        if key not in self.functions:
            raise TranslationError(f"key: expected one of {sorted(self.functions)}, got {key!r}")
        if key not in self._programs:
            self._programs[key] = translate(self.functions[key])
        return self._programs[key]

    def _call(self, key: str, *args):
        outs = self.program(key)(*args)
        if key in _SCALARS:
            return outs[0].reshape(())
        return outs[0] if len(outs) == 1 else outs

    def _u(self, u, like):
        if u is None:
            return jnp.zeros((self.m,), jnp.asarray(like).dtype)
        return u

    def M(self, q):
        """Mass matrix M(q) (eqs. 18-20), (n, n)."""
        return self._call("M", q)

    def M_inv(self, q):
        """M(q)^-1 (Cholesky solve), (n, n)."""
        return self._call("M_inv", q)

    def G(self, q):
        """Generalized potential force dV/dq (eqs. 21-24), (n,)."""
        return self._call("G", q)

    def D(self, q):
        """Damping matrix, (n, n)."""
        return self._call("D", q)

    def A(self, q):
        """Input matrix A(q), (n, m)."""
        return self._call("A", q).reshape(self.n, self.m)

    def C(self, q, qd):
        """Coriolis matrix (Christoffel symbols of M), (n, n)."""
        return self._call("C", q, qd)

    def Cqd(self, q, qd):
        """C(q, qd) qd, (n,)."""
        return self._call("Cqd", q, qd)

    def qdd(self, q, qd, u=None):
        """Forward dynamics: qdd solving M qdd + C qd + G + D qd = A u (eq. 4), (n,)."""
        return self._call("forward", q, qd, self._u(u, q))

    def tau(self, q, qd, qdd):
        """Inverse dynamics M qdd + C qd + G + D qd, (n,)."""
        return self._call("inverse", q, qd, qdd)

    def energy(self, q, qd):
        """Total energy (kinetic + gravitational + elastic), a scalar."""
        return self._call("energy", q, qd)

    def kinetic(self, q, qd):
        return self._call("kinetic", q, qd)

    def potential(self, q):
        return self._call("potential", q)

    def momentum(self, q, qd):
        """p = M(q) qd, (n,)."""
        return self._call("momentum", q, qd)

    def hamiltonian(self, q, p, u=None):
        """(qdot, pdot) of the Hamiltonian form (eq. 7) with damping and input."""
        return self._call("hamiltonian", q, p, self._u(u, q))

    def ode(self, x, u=None):
        """xdot = [qd; qdd] for x = [q; qd], (2n,)."""
        return self._call("ode", x, self._u(u, x))

    def __repr__(self) -> str:
        return f"ExactModel({self.spec.name!r}, n={self.n}, m={self.m})"


@lru_cache(maxsize=16)
def _cached(spec: ModelSpec, order: int | None) -> ExactModel:
    return ExactModel(spec, order)


def jax_model(model: str | Path | ModelSpec, order: int | None = None) -> ExactModel:
    """The :class:`ExactModel` of a spec, a preset name or a spec path (cached per spec)."""
    return _cached(load_spec(model), order)


def dynamics(model: str | Path | ModelSpec, order: int | None = None):
    """The true forward dynamics as a plain JAX callable ``qdd(q, qd, u) -> q̈`` of one state
    (eq. 4), for known-actuator and hybrid (residual) models in :mod:`softpinn.learn`."""
    em = jax_model(model, order)
    program = em.program("forward")

    def qdd(q, qd, u=None):
        return program(q, qd, em._u(u, q))[0]

    return qdd


__all__ = ["ExactModel", "dynamics", "jax_model"]
