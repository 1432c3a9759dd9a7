"""The application layer (above :mod:`bridge.report`, below :mod:`bridge.cli`): the studies
``softpinn reproduce`` runs, as a :class:`.study.Study` protocol and a registry
(:mod:`.studies`), and :func:`.runner.reproduce`, which dispatches through it."""

from softpinn.bridge.app.runner import (
    ReproduceResult,
    machine_description,
    notebook_run,
    reproduce,
)
from softpinn.bridge.app.studies import REGISTRY, study_for
from softpinn.bridge.app.study import Study, StudyRun, Written

__all__ = [
    "REGISTRY",
    "ReproduceResult",
    "Study",
    "StudyRun",
    "Written",
    "machine_description",
    "notebook_run",
    "reproduce",
    "study_for",
]
