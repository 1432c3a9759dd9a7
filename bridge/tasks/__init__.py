"""The paper's tasks end to end (``softpinn reproduce``): a recipe becomes a plan
(:mod:`.plan`), the plan runs as resumable stages (:mod:`.stages`), and :func:`reproduce`
(:mod:`.pipeline`) ties them together and writes the report."""

from softpinn.bridge.tasks.pipeline import (
    ReproduceResult,
    machine_description,
    notebook_run,
    reproduce,
)
from softpinn.bridge.tasks.plan import TASKS, Plan, ReproduceConfig, Variant, make_plan
from softpinn.bridge.tasks.stages import variant_model

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
