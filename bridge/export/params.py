"""Numeric parameters of a trained model, read off its Equinox modules into plain numpy.

The exporter never calls the JAX model: it reads the weights of each sub-network
(:mod:`softpinn.learn._nets`) and hands them to :mod:`.layers`, which rebuilds the same
expressions in CasADi. Every field becomes a small dict with a ``kind``; parameters are cast to
float64 (a float32 model exports in float64 from its float32 weights).
"""

from __future__ import annotations

import numpy as np

from softpinn.errors import UserError

__all__ = ["mlp_params", "field_params", "model_params"]


def _f64(a) -> np.ndarray:
    return np.asarray(a, dtype=np.float64)


def mlp_params(mlp) -> dict:
    """``{"weights", "biases", "activation"}`` of a ``learn._nets.MLP``."""
    return {
        "weights": [_f64(W) for W in mlp.weights],
        "biases": [_f64(b) for b in mlp.biases],
        "activation": str(mlp.activation),
    }


def field_params(field) -> dict:
    """The parameters of one sub-network of a physics model (see :func:`.layers.field_expression`).

    Fields are recognised by class name (``CholeskyField``, ``ConstantCholesky``, ``ScalarField``,
    ``MatrixField``, ``ConstantMatrix``, ``KnownMatrix``, ``ZeroMatrix``); anything else (an
    analytic field put in by hand) cannot be exported.
    """
    name = type(field).__name__
    if name == "CholeskyField":
        return {"kind": "cholesky", "mlp": mlp_params(field.mlp), "n": int(field.n),
                "eps": float(field.eps)}
    if name == "ConstantCholesky":
        return {"kind": "constant-cholesky", "raw": _f64(field.raw), "n": int(field.n),
                "eps": float(field.eps)}
    if name == "ScalarField":
        return {"kind": "scalar", "mlp": mlp_params(field.mlp)}
    if name == "MatrixField":
        return {"kind": "matrix", "mlp": mlp_params(field.mlp),
                "shape": tuple(int(s) for s in field.shape)}
    if name == "ConstantMatrix":
        return {"kind": "constant", "value": _f64(field.value)}
    if name == "KnownMatrix":  # a known A(q) (input_form "known"): its constant or program
        return {**field.to_data(), "kind": "known"}
    if name == "ZeroMatrix":
        return {"kind": "zero", "shape": tuple(int(s) for s in field.shape)}
    raise UserError(
        f"model field of type {name} cannot be exported; expected one of the learn._nets fields "
        "(CholeskyField, ConstantCholesky, ScalarField, MatrixField, ConstantMatrix, ZeroMatrix)"
    )


def model_params(model) -> dict:
    """``{"kind", "n", "m", "state_kind", ...fields}`` of a loaded ``learn._models`` model."""
    cfg = model.config
    # a Hamiltonian network is exported as eq. 7 on (q, p), also one trained on (q, q̇) with
    # its own momenta p = M̂ q̇ (learn/_velocity.py): its field is the same
    state = "momentum" if cfg.kind == "hamiltonian" else model.state_kind
    out = {"kind": cfg.kind, "n": int(cfg.n), "m": int(cfg.m), "state_kind": state}
    if getattr(model, "prior", None) is not None:  # the fixed linear force (learn/_prior.py)
        out["prior"] = {k: _f64(v) for k, v in model.prior.to_data().items() if k != "kind"}
    if cfg.kind == "blackbox":
        out["mlp"] = mlp_params(model.mlp)
        return out
    for part in ("mass", "potential", "damping", "input_map"):
        out[part] = field_params(getattr(model, part))
    return out
