"""The baseline kinds by name (:mod:`learn._baselines`, :mod:`learn._lagged_arx`,
:mod:`learn._output_error`): fit one, or rebuild one from its ``to_dict()`` JSON."""

from __future__ import annotations

from collections.abc import Mapping

from softpinn.errors import UserError
from softpinn.learn._baselines import ARX, FORMAT, LinearSecondOrder, NoMotion
from softpinn.learn._lagged_arx import LaggedARX
from softpinn.learn._output_error import LinearRolloutFit

__all__ = ["BASELINE_KINDS", "baseline_from_dict", "fit_baseline"]

_CLASSES = {c.kind: c for c in (ARX, LaggedARX, LinearSecondOrder, LinearRolloutFit, NoMotion)}
#: The baseline kinds, as ``to_dict()["kind"]`` names them.
BASELINE_KINDS = tuple(sorted(_CLASSES))


def baseline_from_dict(d: Mapping):
    """The baseline a :meth:`to_dict` dict describes."""
    kind = d.get("kind") if isinstance(d, Mapping) else None
    if kind not in _CLASSES:
        raise UserError(f"baseline kind must be one of {list(BASELINE_KINDS)}, got {kind!r}")
    if d.get("format", FORMAT) != FORMAT:
        raise UserError(f"baseline {kind}: format {d.get('format')!r} is not {FORMAT}")
    return _CLASSES[kind].from_dict(d)


def fit_baseline(kind: str, data, traj_ids=None, **options):
    """Fit the baseline ``kind`` (one of :data:`BASELINE_KINDS`) on ``data``."""
    if kind not in _CLASSES:
        raise UserError(f"baseline kind must be one of {list(BASELINE_KINDS)}, got {kind!r}")
    return _CLASSES[kind].fit(data, traj_ids, **options)
