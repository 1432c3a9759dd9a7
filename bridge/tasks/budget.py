"""One network's settings in a task run (:class:`ModelBudget`): its sizes, its training budget
and what it learns from, as the plan (:mod:`.plan`) reads them from the recipe
(:mod:`symbolic.spec._recipe`) and a variant's data adjust them (:func:`.stages.variant_model`).

A budget is a partial ``TrainConfig`` / ``ModelConfig``: a setting the recipe leaves out is None
here and takes learn's own default when the stage builds the configuration, so no default is
written twice."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from softpinn.learn import TrainConfig

#: Settings written to ``plan.json`` (and a stage's record) only where the recipe or the run
#: sets them; the others are always written (``paper_epochs`` too, null where unknown).
OPTIONAL = frozenset({
    "max_step", "loss", "loss_weight", "accel_labels", "accel_space", "test_with",
    "damping_form", "known_input", "momenta", "mass_init", "equal_steps", "patience",
    "overfit", "test_samples",
})

#: TrainConfig's own defaults, by field (what a setting left None here trains with)
_TRAIN_DEFAULTS = {f.name: f.default for f in dataclasses.fields(TrainConfig)}


@dataclass(frozen=True)
class ModelBudget:
    """A network of a task run. Sizes are ``(width, depth)``; ``epochs`` AdamW epochs,
    ``lbfgs`` L-BFGS iterations after them, ``lr`` the peak learning rate; ``paper_epochs`` the
    paper's epochs (Table III; None for a spec of one's own); ``substeps`` RK4 steps per data
    interval and ``input_hold`` the input between samples (eq. 8/9's integration).

    The optional settings (None: not set, learn's default): ``max_step`` this network's own
    longest RK4 step [s] (a variant's model holds the sub-steps it gives instead); the loss
    (``loss``, ``loss_weight`` = λ of eqs. 8/9, ``accel_labels``, ``accel_space`` of eq. 10,
    ``test_with``); how the network is built (``damping_form``, ``known_input``: this spec's
    own A(q), ``momenta``, ``mass_init`` = "data": M or M⁻¹ starts at the data's scale); and
    the full run's stopping rules (``equal_steps``: as many optimizer steps on fewer samples,
    applied by a variant's model, ``patience``, ``overfit``, ``test_samples``)."""

    mass: tuple[int, int]
    potential: tuple[int, int]
    damping: tuple[int, int]
    input: tuple[int, int]
    hidden: tuple[int, int]
    epochs: int
    lbfgs: int
    lr: float
    paper_epochs: int | None
    substeps: int
    input_hold: str
    max_step: float | None = None
    loss: str | None = None
    loss_weight: float | None = None
    accel_labels: str | None = None
    accel_space: str | None = None
    test_with: str | None = None
    damping_form: str | None = None
    known_input: bool | None = None
    momenta: str | None = None
    mass_init: str | None = None
    equal_steps: bool | None = None
    patience: int | None = None
    overfit: float | None = None
    test_samples: int | None = None

    def to_dict(self) -> dict[str, Any]:
        """The budget as ``plan.json`` and the stage records write it: every setting, the
        optional ones where set, in the order of the fields."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)
                if f.name not in OPTIONAL or getattr(self, f.name) is not None}

    def train_settings(self) -> dict[str, Any]:
        """The ``TrainConfig`` fields this budget sets beyond the budget itself (loss, momenta,
        stopping rules): only those set, so the others keep ``TrainConfig``'s defaults."""
        out: dict[str, Any] = {}
        for name in ("loss", "accel_labels", "accel_space", "test_with", "momenta"):
            if getattr(self, name) is not None:
                out[name] = str(getattr(self, name))
        if self.loss_weight is not None:
            out["loss_weight"] = float(self.loss_weight)
        for name in ("patience", "overfit", "test_samples"):
            if getattr(self, name) is not None:
                out[name] = getattr(self, name)
        return out

    def trained_with(self, name: str) -> Any:
        """The ``TrainConfig`` setting ``name`` (``loss``, ``momenta``, ...) a run of this budget
        trains with: the budget's own, or ``TrainConfig``'s default where it sets none."""
        value = getattr(self, name)
        return value if value is not None else _TRAIN_DEFAULTS[name]

    def integration(self) -> dict[str, Any]:
        """How the network steps a data interval (a stage's settings and the floor's)."""
        return {"substeps": int(self.substeps), "input_hold": str(self.input_hold)}
