"""The settings of a dynamics network (:class:`ModelConfig`): its kind, sizes, sub-network
layers, damping and input forms, state and dtype, checked where they enter; the networks
themselves are :mod:`learn._models`."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

from softpinn.errors import UserError
from softpinn.learn._known_input import parse_known_input
from softpinn.learn._nets import ACTIVATIONS
from softpinn.learn._prior import parse_prior

__all__ = ["KINDS", "ModelConfig"]

KINDS = ("lagrangian", "lagrangian-hessian", "hamiltonian", "blackbox")
_DAMPING_FORMS = ("network", "constant", "none")
_INPUT_FORMS = ("network", "constant", "known")
_DTYPES = ("float64", "float32")
_STATE_KINDS = ("velocity", "momentum")
_NATURAL_STATE = {
    "lagrangian": "velocity",
    "lagrangian-hessian": "velocity",
    "hamiltonian": "momentum",
}


def _check_layers(name, value):
    try:
        width, depth = (int(v) for v in value)
        ok = len(tuple(value)) == 2 and width >= 1 and depth >= 0
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise UserError(f"{name}: must be (width >= 1, depth >= 0), got {value!r}")
    return (width, depth)


@dataclass(frozen=True)
class ModelConfig:
    """Everything needed to rebuild a model (hashable; JSON round trip with to_dict/from_dict).

    ``kind``: "lagrangian" (structured eq. 6), "lagrangian-hessian" (the literal Hessian form of
    eq. 6, a reference), "hamiltonian" (eq. 7) or "blackbox" (MLP baseline). ``n`` coordinates,
    ``m`` inputs (0: unactuated, no A network). Layer sizes are (width, depth) with depth hidden
    layers. ``eps`` shifts the diagonal of M's (or M⁻¹'s) Cholesky factor (Fig. 2).
    ``mass_init``: None, or the initial diagonal of M (Lagrangian) or M⁻¹ (Hamiltonian): the
    bias of the Cholesky network's diagonal outputs starts where diag(L) = sqrt(mass_init).
    Data whose masses are far from 1 (task4's M⁻¹ ~ 200) otherwise start the optimiser far
    from the data's scale. ``state_kind`` matters for the black box ("velocity":
    x = (q, q̇), "momentum": x = (q, p)); the Lagrangian models fix it (velocity); a
    Hamiltonian network has "momentum" (eq. 9 on p from the data) or "velocity" (trained and
    stepped on (q, q̇) with its momenta p = M̂(q) q̇ from its own mass matrix,
    :mod:`learn._velocity`); ``None`` resolves to the natural one (Hamiltonian: momentum).
    ``input_form``: A(q) as a "network", a learned "constant", or "known": fixed, not learned
    (Section VI-B's known actuator model, which pins the scale and frame of M, D, G), given by
    ``known_input``, JSON text of a constant n x m matrix or of the exact A(q) as an instruction
    program (:mod:`learn._known_input`; :func:`learn._known_input.known_input_text` writes it). The
    text is part of the configuration, so a run's ``config.json`` rebuilds the model on its own.
    ``prior``: None, or JSON text of a fixed linear model (:mod:`learn._prior`) that the model
    starts as and its networks correct; written by ``train`` from the training data's
    least-squares fit (``TrainConfig.prior``).
    """

    kind: str
    n: int
    m: int
    mass: tuple[int, int] = (64, 3)
    potential: tuple[int, int] = (64, 3)
    damping: tuple[int, int] = (16, 2)
    input: tuple[int, int] = (16, 2)
    hidden: tuple[int, int] = (128, 3)
    activation: str = "softplus"
    damping_form: str = "network"
    input_form: str = "network"
    eps: float = 1e-3
    dtype: str = "float64"
    state_kind: str | None = None
    mass_init: float | None = None
    known_input: str | None = None
    prior: str | None = None

    def __post_init__(self):
        set_ = lambda k, v: object.__setattr__(self, k, v)
        if self.kind not in KINDS:
            raise UserError(f"model kind must be one of {list(KINDS)}, got {self.kind!r}")
        for name, low in (("n", 1), ("m", 0)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < low:
                raise UserError(f"model {name} must be an integer >= {low}, got {v!r}")
        for name in ("mass", "potential", "damping", "input", "hidden"):
            set_(name, _check_layers(name, getattr(self, name)))
        if self.activation not in ACTIVATIONS:
            raise UserError(
                f"activation: must be one of {sorted(ACTIVATIONS)}, got {self.activation!r}"
            )
        if self.damping_form not in _DAMPING_FORMS:
            raise UserError(
                f"damping_form: must be one of {list(_DAMPING_FORMS)}, got {self.damping_form!r}"
            )
        if self.input_form not in _INPUT_FORMS:
            raise UserError(
                f"input_form: must be one of {list(_INPUT_FORMS)}, got {self.input_form!r}"
            )
        if self.input_form == "known":
            if self.kind == "blackbox":
                raise UserError("input_form 'known' applies to physics models, not blackbox")
            if self.m == 0:
                raise UserError("input_form 'known' needs inputs (m >= 1); this model has m = 0")
            if not isinstance(self.known_input, str):
                raise UserError("input_form 'known' needs known_input: the known matrix A(q) "
                                "(learn._known_input.known_input_text)")
            parse_known_input(self.known_input, self.n, self.m)
        elif self.known_input is not None:
            raise UserError(f"known_input is given but input_form is {self.input_form!r}; "
                            "use input_form 'known'")
        if self.prior is not None:
            if self.input_form == "known":
                raise UserError("a linear prior and a known input matrix do not go together: "
                                "the prior's M = I would contradict the scale the known A "
                                "pins; use one of them")
            if self.kind == "blackbox" and self.state_kind == "momentum":
                raise UserError("a linear prior needs a black box on (q, q̇) (state_kind "
                                "'velocity'), not on momenta")
            parse_prior(self.prior, self.n, self.m)
        if isinstance(self.eps, bool) or not (
                isinstance(self.eps, int | float) and math.isfinite(self.eps) and self.eps >= 0):
            raise UserError(f"eps: must be a finite number >= 0, got {self.eps!r}")
        set_("eps", float(self.eps))
        if self.mass_init is not None:
            ok = isinstance(self.mass_init, int | float) and not isinstance(self.mass_init, bool)
            if not (ok and math.isfinite(self.mass_init) and self.mass_init > 0):
                raise UserError(f"mass_init: must be a number > 0, got {self.mass_init!r}")
            if math.sqrt(self.mass_init) <= self.eps:
                raise UserError(
                    f"mass_init: must exceed eps² = {self.eps**2:g}, got {self.mass_init!r}"
                )
            set_("mass_init", float(self.mass_init))
        if self.dtype not in _DTYPES:
            raise UserError(f"dtype: must be one of {list(_DTYPES)}, got {self.dtype!r}")
        natural = _NATURAL_STATE.get(self.kind)
        if self.state_kind is None:
            set_("state_kind", natural or "velocity")
        elif self.state_kind not in _STATE_KINDS:
            raise UserError(
                f"state_kind must be one of {list(_STATE_KINDS)}, got {self.state_kind!r}"
            )
        elif natural is not None and self.state_kind != natural and not (
                self.kind == "hamiltonian" and self.state_kind == "velocity"):
            # a Hamiltonian network may also live on (q, q̇): momenta from its own M (velocity.py)
            raise UserError(
                f"state_kind of a {self.kind} model must be {natural!r}, got {self.state_kind!r}"
            )

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (tuples become lists)."""
        return {
            k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(self).items()
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ModelConfig:
        """Rebuild from :meth:`to_dict` output; unknown keys are refused."""
        if not isinstance(d, dict):
            raise UserError(f"model config must be a JSON object, got {type(d).__name__}")
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise UserError(f"unknown model config key(s) {unknown}; expected keys {sorted(known)}")
        missing = sorted(k for k in ("kind", "n", "m") if k not in d)
        if missing:
            raise UserError(f"model config is missing key(s) {missing}")
        kw = {k: tuple(v) if isinstance(v, list) else v for k, v in d.items()}
        return cls(**kw)
