"""The ``report.md`` writers: a task run's (:mod:`.task`, its matrices' section in
:mod:`.task_analysis`), the experiment's (:mod:`.experiment`) and the challenges'
(:mod:`.challenges`); the verdict at a task report's top (:mod:`.verdict`); a report shown in a
notebook (:mod:`.show`)."""

from softpinn.bridge.report.challenges import write_challenges_report
from softpinn.bridge.report.experiment import write_experiment_report
from softpinn.bridge.report.show import show_report
from softpinn.bridge.report.task import write_task_report

__all__ = ["show_report", "write_challenges_report", "write_experiment_report",
           "write_task_report"]
