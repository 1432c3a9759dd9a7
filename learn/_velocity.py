"""Hamiltonian networks trained on velocity data (the paper's third open challenge, Section VI-B).

A Hamiltonian network (eq. 7) lives on x = (q, p), but no robot measures the momenta p. With
``ModelConfig(kind="hamiltonian", state_kind="velocity")`` (``softpinn train --momenta
velocity``) the network's state is (q, q̇) like a Lagrangian network's, and its momenta are
estimated inside the loss with its OWN mass matrix:

    p₀ = M̂(q₀) q̇₀            two triangular solves with the factor Lc of M̂⁻¹ = Lc Lcᵀ,
    (q₁, p₁) = RK4 step of eq. 7 from (q₀, p₀),
    q̇₁ = M̂⁻¹(q₁) p₁ = ∂H/∂p  two products with Lc(q₁),

then the velocity loss of eq. 8 on (q₁, q̇₁) (:func:`learn._losses.pair_errors` does the rest;
:func:`learn._integrate.step` asks the model for these maps through
:func:`integration_coordinates`). The map q̇ ↔ p is a bijection at every q, so a rollout made of
such steps is exactly the rollout of eq. 7 in (q, p) from p₀ = M̂ q̇₀, read out as q̇, and the
prediction, evaluation and analysis code that works on (q, q̇) works unchanged.

What velocity data determine: the q-trajectories of eq. 7 with (M̂⁻¹, V̂, D̂, Â) are those of
(c M̂⁻¹, V̂ / c, D̂ / c, Â / c) for any c > 0 (p scales by 1/c, q̇ = M̂⁻¹ p does not), and more
generally those of any equivalent Lagrangian (Tables I, VIII): the network's M, D, G, A are
determined by (q, q̇) data only up to the same transform P(q) as a Lagrangian network's, while
M⁻¹G, M⁻¹D q̇, M⁻¹A u and q̈ are determined outright. The momenta of the data (where a file
holds them) are what pins the scale in eq. 9.

:func:`resolve_momenta` turns ``TrainConfig.momenta == "auto"`` into a choice for one data set:
"data" when the file holds momenta that were recorded with it (simulated data), "velocity" when
it has none or they were computed from a model's mass matrix (an imported recording, whose
``meta["import"]["momentum"]`` says so).
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp

from softpinn.errors import UserError
from softpinn.learn._linalg import cho_solve, mtv, mv

__all__ = [
    "MOMENTA",
    "integration_coordinates",
    "momenta_from_velocities",
    "velocities_from_momenta",
    "measured_momenta",
    "resolve_momenta",
    "momenta_note",
]

#: ``TrainConfig.momenta``: where a Hamiltonian network's momenta come from.
MOMENTA = ("auto", "data", "velocity")


def momenta_from_velocities(model, x):
    """(q, q̇) -> (q, p) with p = M̂(q) q̇ of the Hamiltonian ``model`` (two triangular solves
    with the factor of M̂⁻¹; no inverse formed)."""
    n = model.config.n
    q, qd = x[:n], x[n:]
    return jnp.concatenate([q, cho_solve(model.mass.factor(q), qd)])


def velocities_from_momenta(model, y):
    """(q, p) -> (q, q̇) with q̇ = M̂⁻¹(q) p = ∂H/∂p (eq. 7's first row)."""
    n = model.config.n
    q, p = y[:n], y[n:]
    Lc = model.mass.factor(q)
    return jnp.concatenate([q, mv(Lc, mtv(Lc, p))])


def integration_coordinates(model):
    """``(encode, field, decode)`` for :func:`learn._integrate.step`: the state a model is
    stepped in, its vector field there, and the way back; None for a model that is stepped in
    its own state. A Hamiltonian network on (q, q̇) is stepped in (q, p) with eq. 7."""
    if getattr(model, "state_kind", None) != "velocity" or model.config.kind != "hamiltonian":
        return None
    return (lambda x: momenta_from_velocities(model, x), model.momentum_field,
            lambda y: velocities_from_momenta(model, y))


def measured_momenta(data) -> bool:
    """Whether a data set holds momenta that came with it (simulated data) rather than none or
    momenta computed from a model's mass matrix (an imported recording)."""
    if getattr(data, "p", None) is None:
        return False
    meta = data.meta if isinstance(data.meta, dict) else {}
    if meta.get("source") == "import":
        return False
    imported = meta.get("import")
    return not (isinstance(imported, dict) and "momentum" in imported)


def momenta_note(data) -> str:
    """Why :func:`measured_momenta` said no, in a few words (for messages)."""
    if getattr(data, "p", None) is None:
        return "the file holds no momenta p"
    return "the file's momenta p were computed from a model's mass matrix (an imported recording)"


def resolve_momenta(config, data):
    """``config`` (a :class:`learn._config.TrainConfig`) with ``momenta`` decided for ``data``:
    a Hamiltonian network's "auto" becomes "data" when :func:`measured_momenta`, else
    "velocity", and the model's state follows ("momentum" or "velocity"). Refuses "data" on a
    file that has no momenta at all. Other models are returned as they are."""
    if config.model.kind != "hamiltonian":
        return config
    choice = config.momenta
    if choice == "auto":
        choice = "data" if measured_momenta(data) else "velocity"
    if choice == "data" and getattr(data, "p", None) is None:
        raise UserError(
            f"momenta: 'data' needs momenta p in the dataset file, and {data.path} has none; "
            "train on its velocities with --momenta velocity (p = M(q) qd with the network's "
            "own mass matrix)"
        )
    state = "momentum" if choice == "data" else "velocity"
    if choice == config.momenta and state == config.model.state_kind:
        return config
    return dataclasses.replace(config, momenta=choice,
                               model=dataclasses.replace(config.model, state_kind=state))
