"""Reports: paper-shaped tables in Markdown, CSV and LaTeX (:mod:`.tables`), figures
(:mod:`.plots`), and a task run's ``report.md`` (:mod:`.task`)."""

from softpinn.bridge.report.task import show_report, write_task_report

__all__ = ["show_report", "write_task_report"]
