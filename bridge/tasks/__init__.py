"""The paper's tasks as resumable stages: a recipe becomes a plan (:mod:`.plan`, each network's
budget a :class:`.budget.ModelBudget`), the plan runs as stages (:mod:`.stages`,
:mod:`.measure_stages`) tied together by :func:`.pipeline.run_task`; the paper's experiment is
:mod:`.experiment`. ``softpinn.bridge.app``'s ``reproduce`` runs them and writes the report."""

from softpinn.bridge.tasks.budget import ModelBudget
from softpinn.bridge.tasks.plan import TASKS, Plan, ReproduceConfig, Variant, make_plan
from softpinn.bridge.tasks.stages import variant_model

__all__ = [
    "TASKS",
    "ModelBudget",
    "Plan",
    "ReproduceConfig",
    "Variant",
    "make_plan",
    "variant_model",
]
