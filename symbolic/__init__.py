"""Ground truth for soft manipulators: PCC model specs, symbolic equations of motion (CasADi),
generated C code, simulation and dataset files. Never imports jax."""

from .errors import UserError
from .spec import ModelSpec, Segment, SpecError, list_presets, load_spec

__all__ = ["ModelSpec", "Segment", "SpecError", "UserError", "list_presets", "load_spec"]
