"""The paper's tasks end to end (``softpinn reproduce``): a recipe becomes a plan
(:mod:`.plan`), the plan runs as resumable stages (:mod:`.stages`), and :func:`reproduce`
(:mod:`.pipeline`) ties them together and writes the report."""

from .pipeline import ReproduceResult, machine_description, notebook_run, reproduce
from .plan import TASKS, Plan, ReproduceConfig, Variant, make_plan
from .stages import variant_model

__all__ = [
    "TASKS",
    "Plan",
    "ReproduceConfig",
    "ReproduceResult",
    "Variant",
    "machine_description",
    "make_plan",
    "notebook_run",
    "reproduce",
    "variant_model",
]
